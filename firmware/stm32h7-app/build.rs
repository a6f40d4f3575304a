//! Links the STM32H743ZI memory map: copies `memory-stm32h743zi.x` to `memory.x` in the
//! build's output directory, where cortex-m-rt's `link.x` (`INCLUDE memory.x`) finds it, and
//! adds the linker scripts of cortex-m-rt and defmt.
//!
//! The linker looks in its working directory before the search path. This crate is its own
//! workspace, so that is this directory, which has no `memory.x`: the repository root's (the
//! QEMU board's) is not in the way.
use std::path::PathBuf;

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let out = PathBuf::from(std::env::var("OUT_DIR").unwrap());
    std::fs::copy(manifest.join("memory-stm32h743zi.x"), out.join("memory.x")).expect("memory-stm32h743zi.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory-stm32h743zi.x");
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
}
