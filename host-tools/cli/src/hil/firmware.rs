//! Finding (or building) the firmware ELF.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Mutex;

use super::HilError;

/// Environment variable naming a prebuilt firmware ELF; when set the harness never builds.
pub const FIRMWARE_ELF_ENV: &str = "STS_TWIN_FIRMWARE_ELF";
/// The firmware's Rust target.
pub const FIRMWARE_TARGET: &str = "thumbv7em-none-eabihf";

/// The workspace root this library was built in (the firmware sources live there).
fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The firmware ELF: `STS_TWIN_FIRMWARE_ELF` if set, else built (once per process) from
/// the workspace with [`build_firmware`].
pub fn firmware_elf() -> Result<PathBuf, HilError> {
    if let Some(path) = std::env::var_os(FIRMWARE_ELF_ENV) {
        let path = PathBuf::from(path);
        return if path.is_file() { Ok(path) } else { Err(HilError::ElfMissing(path)) };
    }
    static BUILT: Mutex<Option<PathBuf>> = Mutex::new(None);
    let mut built = BUILT.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(path) = built.as_ref() {
        return Ok(path.clone());
    }
    let path = build_firmware(&workspace_root())?;
    *built = Some(path.clone());
    Ok(path)
}

/// Builds the firmware of the workspace at `root`:
/// `cargo build -p sts-twin-firmware --target thumbv7em-none-eabihf --profile firmware`
/// into `<root>/target/fw-build` (its own target directory, so a build nested in
/// `cargo test` never waits on the outer cargo's lock). Returns the ELF's path.
pub fn build_firmware(root: &Path) -> Result<PathBuf, HilError> {
    let target_dir = root.join("target").join("fw-build");
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let args = ["build", "-p", "sts-twin-firmware", "--target", FIRMWARE_TARGET, "--profile", "firmware"];
    let command = format!("cargo {}", args.join(" "));
    let output = Command::new(&cargo)
        .args(args)
        .current_dir(root)
        .env("CARGO_TARGET_DIR", &target_dir)
        // Flags meant for the outer (host) build must not leak into the firmware build.
        .env_remove("RUSTFLAGS")
        .env_remove("CARGO_ENCODED_RUSTFLAGS")
        .env_remove("CARGO_BUILD_TARGET")
        .output()
        .map_err(|e| HilError::io(format!("running `{command}`"), e))?;
    if !output.status.success() {
        let stderr = String::from_utf8_lossy(&output.stderr);
        if stderr.contains("target may not be installed")
            || stderr.contains("can't find crate for `core`")
            || stderr.contains(&format!("{FIRMWARE_TARGET}` not found"))
        {
            return Err(HilError::TargetMissing);
        }
        let tail: Vec<&str> = stderr.lines().rev().take(40).collect();
        let tail: Vec<&str> = tail.into_iter().rev().collect();
        return Err(HilError::Build { command, stderr: tail.join("\n") });
    }
    let elf = target_dir.join(FIRMWARE_TARGET).join("firmware").join("sts-twin-firmware");
    if elf.is_file() {
        Ok(elf)
    } else {
        Err(HilError::ElfMissing(elf))
    }
}
