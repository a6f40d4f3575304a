//! Finding the firmware ELF. The harness never builds it: `cargo xtask firmware` at the
//! repository root does (the firmware apps are workspaces of their own).

use std::path::{Path, PathBuf};

use sts_twin_board::qemu::QemuBoard;

use super::HilError;

/// Environment variable naming a prebuilt firmware ELF (the Arm twin), used instead of the
/// default place.
pub const FIRMWARE_ELF_ENV: &str = "STS_TWIN_FIRMWARE_ELF";
/// Environment variable naming a prebuilt bring-up firmware ELF (the platform tests' app).
pub const BRINGUP_ELF_ENV: &str = "STS_TWIN_BRINGUP_ELF";
/// Environment variable naming a prebuilt RISC-V twin ELF (QEMU `virt`).
pub const RISCV_FIRMWARE_ELF_ENV: &str = "STS_TWIN_RISCV_FIRMWARE_ELF";

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
    /// Built for the Arm boards only.
    BringUp,
}

impl FirmwareVariant {
    /// The environment variable naming this variant's ELF for `board`; `None` where it is
    /// not built.
    pub fn env(self, board: QemuBoard) -> Option<&'static str> {
        match (self, is_riscv(board)) {
            (Self::Twin, false) => Some(FIRMWARE_ELF_ENV),
            (Self::BringUp, false) => Some(BRINGUP_ELF_ENV),
            (Self::Twin, true) => Some(RISCV_FIRMWARE_ELF_ENV),
            (Self::BringUp, true) => None,
        }
    }

    fn describe(self) -> &'static str {
        match self {
            Self::Twin => "twin",
            Self::BringUp => "bring-up",
        }
    }

    /// Where `cargo xtask firmware` puts this variant's ELF for `board`, relative to the
    /// repository root (the xtask crate's `QEMU_TWIN.elf`, `QEMU_BRINGUP.elf`,
    /// `RISCV_VIRT_TWIN.elf`); `None` where it is not built.
    pub fn default_elf_relative(self, board: QemuBoard) -> Option<&'static str> {
        match (self, is_riscv(board)) {
            (Self::Twin, false) => Some("firmware/target/thumbv7em-none-eabihf/firmware/sts-twin-firmware"),
            (Self::BringUp, false) => Some("firmware/target/bringup/thumbv7em-none-eabihf/firmware/sts-twin-firmware"),
            (Self::Twin, true) => Some("firmware/target/riscv32imac-unknown-none-elf/firmware/sts-twin-firmware-riscv"),
            (Self::BringUp, true) => None,
        }
    }

    /// [`Self::default_elf_relative`] in the repository this library was built in.
    pub fn default_elf(self, board: QemuBoard) -> Option<PathBuf> {
        self.default_elf_relative(board).map(|p| repo_root().join(p))
    }
}

fn is_riscv(board: QemuBoard) -> bool {
    board == QemuBoard::RiscvVirt
}

/// The Arm firmware's Rust target (every board's: [`QemuBoard::rust_target`]).
pub const FIRMWARE_TARGET: &str = "thumbv7em-none-eabihf";

/// The repository root this library was built in (it lives in `<root>/host-tools/cli`).
fn repo_root() -> PathBuf {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    manifest.ancestors().nth(2).unwrap_or(manifest).to_path_buf()
}

/// The twin's ELF for the Arm boards; see [`firmware_elf_of`].
pub fn firmware_elf() -> Result<PathBuf, HilError> {
    firmware_elf_of(QemuBoard::An386, FirmwareVariant::Twin)
}

/// The ELF of `variant` for `board`: the file its environment variable
/// (`STS_TWIN_FIRMWARE_ELF`, `STS_TWIN_BRINGUP_ELF`, `STS_TWIN_RISCV_FIRMWARE_ELF`) names if
/// set, else [`FirmwareVariant::default_elf`] if it exists, else
/// [`HilError::FirmwareNotBuilt`], which says how to build it.
pub fn firmware_elf_of(board: QemuBoard, variant: FirmwareVariant) -> Result<PathBuf, HilError> {
    let (Some(env), Some(path)) = (variant.env(board), variant.default_elf(board)) else {
        return Err(HilError::NoSuchFirmware { variant: variant.describe(), board: board.name() });
    };
    if let Some(path) = std::env::var_os(env) {
        let path = PathBuf::from(path);
        return if path.is_file() { Ok(path) } else { Err(HilError::ElfMissing(path)) };
    }
    if path.is_file() {
        Ok(path)
    } else {
        Err(HilError::FirmwareNotBuilt { variant: variant.describe(), env, path, command: BUILD_COMMAND })
    }
}
