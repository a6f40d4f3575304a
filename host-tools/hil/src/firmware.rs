//! Finding (or building) the firmware ELF.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Mutex;

use super::HilError;

/// Environment variable naming a prebuilt firmware ELF; when set the harness never builds.
pub const FIRMWARE_ELF_ENV: &str = "STS_TWIN_FIRMWARE_ELF";
/// Environment variable naming a prebuilt bring-up firmware ELF (the platform tests' app).
pub const BRINGUP_ELF_ENV: &str = "STS_TWIN_BRINGUP_ELF";

/// Which application the firmware runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FirmwareVariant {
    /// The twin (the product).
    #[default]
    Twin,
    /// The bring-up application of the board seam (feature `bringup`), for platform tests.
    BringUp,
}

impl FirmwareVariant {
    fn env(self) -> &'static str {
        match self {
            Self::Twin => FIRMWARE_ELF_ENV,
            Self::BringUp => BRINGUP_ELF_ENV,
        }
    }
}

/// The firmware's Rust target.
pub const FIRMWARE_TARGET: &str = "thumbv7em-none-eabihf";

/// The workspace root this library was built in (the firmware sources live there).
fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The firmware ELF: `STS_TWIN_FIRMWARE_ELF` if set, else built (once per process) from
/// the workspace with [`build_firmware`].
pub fn firmware_elf() -> Result<PathBuf, HilError> {
    firmware_elf_of(FirmwareVariant::Twin)
}

/// The ELF of `variant`: its environment override (`STS_TWIN_FIRMWARE_ELF`,
/// `STS_TWIN_BRINGUP_ELF`) if set, else built once per process.
pub fn firmware_elf_of(variant: FirmwareVariant) -> Result<PathBuf, HilError> {
    if let Some(path) = std::env::var_os(variant.env()) {
        let path = PathBuf::from(path);
        return if path.is_file() { Ok(path) } else { Err(HilError::ElfMissing(path)) };
    }
    static BUILT: Mutex<[Option<PathBuf>; 2]> = Mutex::new([None, None]);
    let mut built = BUILT.lock().unwrap_or_else(|e| e.into_inner());
    let slot = &mut built[variant as usize];
    if let Some(path) = slot.as_ref() {
        return Ok(path.clone());
    }
    let path = build_firmware_variant(&workspace_root(), variant)?;
    *slot = Some(path.clone());
    Ok(path)
}

/// Builds the firmware of the workspace at `root`:
/// `cargo build -p sts-twin-firmware --target thumbv7em-none-eabihf --profile firmware`
/// into `<root>/target/fw-build` (its own target directory, so a build nested in
/// `cargo test` never waits on the outer cargo's lock). Returns the ELF's path.
pub fn build_firmware(root: &Path) -> Result<PathBuf, HilError> {
    build_firmware_variant(root, FirmwareVariant::Twin)
}

/// Builds `variant` of the firmware (the bring-up one with `--features bringup`, into
/// `<root>/target/fw-build-bringup`).
pub fn build_firmware_variant(root: &Path, variant: FirmwareVariant) -> Result<PathBuf, HilError> {
    let (dir, features) = match variant {
        FirmwareVariant::Twin => ("fw-build", ""),
        FirmwareVariant::BringUp => ("fw-build-bringup", "bringup"),
    };
    let target_dir = root.join("target").join(dir);
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let mut args = vec!["build", "-p", "sts-twin-firmware", "--target", FIRMWARE_TARGET, "--profile", "firmware"];
    if !features.is_empty() {
        args.extend(["--features", features]);
    }
    let command = format!("cargo {}", args.join(" "));
    let output = Command::new(&cargo)
        .args(&args)
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
