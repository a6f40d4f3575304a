#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

mod bench;
mod bus;
mod error;
mod firmware;
mod harness;
mod link;
mod log;
mod placement;
mod process;

pub use bench::{
    bench_inputs, bench_instructions, bench_instructions_prepared, bench_throughput, InstructionReport,
    ThroughputReport, INSTRUCTION_BENCH_SHIFT,
};
pub use bus::{BusCounters, BusFile, Diagnostics};
pub use error::HilError;
pub use firmware::{
    firmware_elf, firmware_elf_of, FirmwareVariant, BRINGUP_ELF_ENV, FIRMWARE_ELF_ENV, FIRMWARE_TARGET,
    RISCV_FIRMWARE_ELF_ENV,
};
pub use harness::{Hil, HilConfig};
pub use link::ControlPort;
pub use log::LogLine;
pub use placement::QemuPlacement;
pub use process::{install_signal_cleanup, live_qemu_pids, QEMU_ENV, QEMU_RISCV32_ENV};

/// The board crate, re-exported: the bus access, the QEMU memory map and the bring-up
/// application (whose [`sts_twin_board::bringup::reference_outputs`] the tests compare to).
pub use sts_twin_board as board;
