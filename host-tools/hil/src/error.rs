//! Errors of the HIL harness.

use std::path::PathBuf;
use std::process::ExitStatus;

/// Everything that can go wrong between the host and the firmware under QEMU.
#[derive(Debug, thiserror::Error)]
pub enum HilError {
    /// The board's QEMU is not installed (or not where its environment variable points).
    #[error("`{program}` not found: install QEMU for {arch} (Debian/Ubuntu: `sudo apt-get install {package}`) or point {env} at it")]
    QemuMissing {
        /// The program that was looked for.
        program: String,
        /// The architecture it emulates.
        arch: &'static str,
        /// The Debian package that has it.
        package: &'static str,
        /// The environment variable that names it.
        env: &'static str,
    },
    /// No such firmware image is built for the board (the bring-up app is Arm-only).
    #[error("there is no {variant} firmware for {board}")]
    NoSuchFirmware {
        /// Which application.
        variant: &'static str,
        /// The board's name.
        board: &'static str,
    },
    /// A bus file laid out for one board was given to another.
    #[error("the bus file is laid out for {file}, not for {board}")]
    BoardMismatch {
        /// The bus file's board.
        file: &'static str,
        /// The board being started.
        board: &'static str,
    },
    /// No firmware ELF: its environment variable is not set and the default place has none.
    #[error("no {variant} firmware ELF: {env} is not set and {path} does not exist; build the firmware with `{command}` at the repository root (or set {env} to an ELF)")]
    FirmwareNotBuilt {
        /// Which application (twin, bring-up).
        variant: &'static str,
        /// The environment variable that was not set.
        env: &'static str,
        /// The default place that was looked at.
        path: PathBuf,
        /// The command that builds it.
        command: &'static str,
    },
    /// The firmware ELF is not where it should be.
    #[error("firmware ELF not found at {0}")]
    ElfMissing(PathBuf),
    /// An I/O error, with what was being done.
    #[error("{what}: {source}")]
    Io {
        /// What the harness was doing.
        what: String,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// QEMU ended while the harness still needed it.
    #[error("QEMU exited ({status}) while {during}; last firmware log lines:\n{log_tail}")]
    QemuExited {
        /// QEMU's exit status.
        status: ExitStatus,
        /// What the harness was waiting for.
        during: String,
        /// The last decoded log lines and QEMU's stderr.
        log_tail: String,
    },
    /// Something did not happen in time.
    #[error("timed out after {seconds:.1} s waiting for {what}")]
    Timeout {
        /// What the harness waited for.
        what: String,
        /// How long it waited.
        seconds: f64,
    },
    /// The firmware answered something unexpected.
    #[error("protocol error: {0}")]
    Protocol(String),
    /// The defmt table of the ELF could not be read.
    #[error("cannot read the defmt table of {path}: {reason}")]
    Defmt {
        /// The ELF.
        path: PathBuf,
        /// Why.
        reason: String,
    },
}

impl HilError {
    pub(crate) fn io(what: impl Into<String>, source: std::io::Error) -> Self {
        Self::Io { what: what.into(), source }
    }
}
