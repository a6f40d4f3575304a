//! Finding the firmware ELF. The harness never builds it: `cargo xtask firmware` at the
//! repository root does (the firmware apps are workspaces of their own).

use std::path::{Path, PathBuf};

use super::HilError;

/// Environment variable naming a prebuilt firmware ELF, used instead of the default place.
pub const FIRMWARE_ELF_ENV: &str = "STS_TWIN_FIRMWARE_ELF";
/// Environment variable naming a prebuilt bring-up firmware ELF (the platform tests' app).
pub const BRINGUP_ELF_ENV: &str = "STS_TWIN_BRINGUP_ELF";

/// The command that builds the firmware ELFs into their default places, at the repository
/// root.
const BUILD_COMMAND: &str = "cargo xtask firmware";

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

    fn describe(self) -> &'static str {
        match self {
            Self::Twin => "twin",
            Self::BringUp => "bring-up",
        }
    }

    /// Where `cargo xtask firmware` puts this variant's ELF, relative to the repository root
    /// (the same paths as the xtask crate's `QEMU_TWIN.elf` / `QEMU_BRINGUP.elf`).
    pub fn default_elf_relative(self) -> &'static str {
        match self {
            Self::Twin => "firmware/target/thumbv7em-none-eabihf/firmware/sts-twin-firmware",
            Self::BringUp => "firmware/target/bringup/thumbv7em-none-eabihf/firmware/sts-twin-firmware",
        }
    }

    /// [`Self::default_elf_relative`] in the repository this library was built in.
    pub fn default_elf(self) -> PathBuf {
        repo_root().join(self.default_elf_relative())
    }
}

/// The firmware's Rust target.
pub const FIRMWARE_TARGET: &str = "thumbv7em-none-eabihf";

/// The repository root this library was built in (it lives in `<root>/host-tools/cli`).
fn repo_root() -> PathBuf {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    manifest.ancestors().nth(2).unwrap_or(manifest).to_path_buf()
}

/// The twin's ELF; see [`firmware_elf_of`].
pub fn firmware_elf() -> Result<PathBuf, HilError> {
    firmware_elf_of(FirmwareVariant::Twin)
}

/// The ELF of `variant`: the file its environment variable (`STS_TWIN_FIRMWARE_ELF`,
/// `STS_TWIN_BRINGUP_ELF`) names if set, else [`FirmwareVariant::default_elf`] if it
/// exists, else [`HilError::FirmwareNotBuilt`], which says how to build it.
pub fn firmware_elf_of(variant: FirmwareVariant) -> Result<PathBuf, HilError> {
    if let Some(path) = std::env::var_os(variant.env()) {
        let path = PathBuf::from(path);
        return if path.is_file() { Ok(path) } else { Err(HilError::ElfMissing(path)) };
    }
    let path = variant.default_elf();
    if path.is_file() {
        Ok(path)
    } else {
        Err(HilError::FirmwareNotBuilt {
            variant: variant.describe(),
            env: variant.env(),
            path,
            command: BUILD_COMMAND,
        })
    }
}
