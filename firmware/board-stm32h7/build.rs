//! Links the STM32H743ZI memory map, not the QEMU one.
//!
//! cortex-m-rt's `link.x` says `INCLUDE memory.x`, and the linker looks in its working
//! directory first, which for a workspace member is the workspace root, where the QEMU
//! board's memory.x lives. So this script copies cortex-m-rt's generated `link.x` to
//! `link-stm32h7.x` with the include renamed to `memory-stm32h743zi.x` (this crate's), and
//! links with that.
use std::path::{Path, PathBuf};

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let out = PathBuf::from(std::env::var("OUT_DIR").unwrap());
    let link_x = find_cortex_m_rt_link_x(&out)
        .expect("cortex-m-rt's generated link.x not found next to this build script's output directory");
    let text = std::fs::read_to_string(&link_x).unwrap();
    assert!(text.contains("INCLUDE memory.x"), "{} has no `INCLUDE memory.x`", link_x.display());
    let text = text.replace("INCLUDE memory.x", "INCLUDE memory-stm32h743zi.x");
    std::fs::write(out.join("link-stm32h7.x"), text).unwrap();
    std::fs::copy(manifest.join("memory-stm32h743zi.x"), out.join("memory-stm32h743zi.x")).unwrap();
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory-stm32h743zi.x");
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink-stm32h7.x");
    println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    let level = std::env::var("DEFMT_LOG").unwrap_or_else(|_| "info".into());
    println!("cargo:rustc-env=DEFMT_LOG={level}");
    println!("cargo:rerun-if-env-changed=DEFMT_LOG");
}

/// `<target>/<triple>/<profile>/build/cortex-m-rt-*/out/link.x` (its build script runs
/// before this one: cortex-m-rt is a `links` dependency). All candidates of one target
/// directory are generated for the same target; the newest wins.
fn find_cortex_m_rt_link_x(out: &Path) -> Option<PathBuf> {
    let build_dir = out.parent()?.parent()?;
    std::fs::read_dir(build_dir)
        .ok()?
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with("cortex-m-rt-"))
        .map(|e| e.path().join("out").join("link.x"))
        .filter(|p| p.is_file())
        .max_by_key(|p| std::fs::metadata(p).and_then(|m| m.modified()).ok())
}
