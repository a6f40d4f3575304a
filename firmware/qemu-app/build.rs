//! Puts memory.x (workspace root) and device.x (this crate) on the linker search path and
//! adds the linker scripts of cortex-m-rt and defmt.
use std::path::PathBuf;

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let out = PathBuf::from(std::env::var("OUT_DIR").unwrap());
    let memory_x = manifest.join("../../memory.x");
    std::fs::copy(&memory_x, out.join("memory.x")).expect("memory.x at the workspace root");
    std::fs::copy(manifest.join("device.x"), out.join("device.x")).expect("device.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", memory_x.display());
    println!("cargo:rerun-if-changed=device.x");
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
}
