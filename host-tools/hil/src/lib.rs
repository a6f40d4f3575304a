//! Hardware-in-the-loop: the real firmware ELF under QEMU (`mps2-an386`), driven tick by
//! tick through the virtual analogue bus in shared memory, with the control link on a
//! loopback TCP socket and the firmware's defmt logs decoded from QEMU's stdout.
//!
//! ```no_run
//! use sts_hil::{Hil, HilConfig};
//! use sts_twin_core::bus::InputSlot;
//!
//! let mut hil = Hil::start(HilConfig::default())?;          // the ELF from `cargo xtask firmware`
//! let out = hil.step(InputSlot { acc_code: 100, ..Default::default() })?;
//! assert_eq!(out.tick, 0);
//! hil.shutdown()?;                                            // also done on drop
//! # Ok::<(), sts_hil::HilError>(())
//! ```
//!
//! QEMU never outlives its harness: [`Hil`] kills it on drop (also when unwinding from a
//! panic), a signal handler kills every QEMU of the process on SIGINT/SIGTERM/SIGHUP, and
//! QEMU gets `PR_SET_PDEATHSIG(SIGKILL)` so that it dies with the process even when the
//! process is SIGKILLed. The bus file is unlinked as soon as it is created (QEMU opens it
//! through `/proc/self/fd`), so nothing is left in `/dev/shm` either.
#![deny(missing_docs)]

mod bench;
mod bus;
mod error;
mod firmware;
mod harness;
mod link;
mod log;
mod process;

pub use bench::{
    bench_inputs, bench_instructions, bench_instructions_prepared, bench_throughput, InstructionReport,
    ThroughputReport, INSTRUCTION_BENCH_SHIFT,
};
pub use bus::{BusCounters, BusFile, Diagnostics};
pub use error::HilError;
pub use firmware::{
    firmware_elf, firmware_elf_of, FirmwareVariant, BRINGUP_ELF_ENV, FIRMWARE_ELF_ENV, FIRMWARE_TARGET,
};
pub use harness::{Hil, HilConfig};
pub use link::ControlPort;
pub use log::LogLine;
pub use process::{install_signal_cleanup, live_qemu_pids, QEMU_ENV};

/// The board crate, re-exported: the bus access, the QEMU memory map and the bring-up
/// application (whose [`sts_twin_board::bringup::reference_outputs`] the tests compare to).
pub use sts_twin_board as board;
