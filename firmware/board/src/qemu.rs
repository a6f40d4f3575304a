//! The QEMU boards the firmware runs on, and their shared-memory map, defined once for the
//! firmware and the HIL host. Three boards: the MPS2 FPGA images `mps2-an386` (Cortex-M4F)
//! and `mps2-an500` (Cortex-M7, the STM32H7's core), which run one Arm image and tell each
//! other apart by the SCC ID register, and `virt` (RV32IMAC), which runs the RISC-V image.
//! Each board maps a file the HIL host maps too (the shared region, [`SHARED_BYTES`] at
//! [`QemuBoard::shared_base`]): the MPS2 boards' 16 MiB PSRAM, the upper half of `virt`'s
//! 32 MiB RAM (the lower half holds the firmware; QEMU's device tree lies in the RAM's top
//! 2 MiB, beyond the part of the region used). The region holds the analogue bus
//! ([`sts_twin_core::bus`]) at offset 0, a diagnostics block the firmware fills for the host,
//! and the persistent config store.
//!
//! | region offset | bytes | what | written by |
//! |---|---|---|---|
//! | `0x0000` | [`sts_twin_core::bus::BUS_BYTES`] | the analogue bus | both |
//! | [`DIAG_OFFSET`] | `4 * DIAG_WORDS` | diagnostics words (`DIAG_*`) | firmware |
//! | [`CONFIG_OFFSET`] | `2 * CONFIG_SLOT_BYTES` | config store ([`crate::config`] A/B records) | firmware |
//!
//! The config store persists across reboots because the host keeps the backing file and
//! hands the same file to the next QEMU; a fresh file (all zero) reads as empty.

/// The QEMU boards the firmware runs on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum QemuBoard {
    /// MPS2 AN386: Cortex-M4F, PSRAM at `0x2100_0000`, CMSDK TIMER0 at 25 MHz.
    An386,
    /// MPS2 AN500: Cortex-M7 (the STM32H7's core), PSRAM at `0x6000_0000`, as the AN386
    /// otherwise.
    An500,
    /// RISC-V `virt` (RV32IMAC, no FPU): RAM at `0x8000_0000`, its upper half shared; the
    /// goldfish RTC's alarm (1 ns) as the tick.
    RiscvVirt,
}

/// Address of the serial communication controller's ID register, which names the MPS2 image.
pub const SCC_ID_ADDR: usize = 0x4002_FFFC;

impl QemuBoard {
    /// Every board, in the order the tools list them.
    pub const ALL: [Self; 3] = [Self::An386, Self::An500, Self::RiscvVirt];

    /// The MPS2 image whose SCC ID register reads `scc_id`; `None` for another board.
    pub const fn from_scc_id(scc_id: u32) -> Option<Self> {
        match scc_id {
            0x4104_3860 => Some(Self::An386),
            0x4104_5000 => Some(Self::An500),
            _ => None,
        }
    }

    /// The board's name in the tools (`--board`).
    pub const fn name(self) -> &'static str {
        match self {
            Self::An386 => "mps2-an386",
            Self::An500 => "mps2-an500",
            Self::RiscvVirt => "riscv-virt",
        }
    }

    /// The board named `name` ([`QemuBoard::name`]).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|b| b.name() == name)
    }

    /// The QEMU program that emulates it.
    pub const fn qemu_program(self) -> &'static str {
        match self {
            Self::An386 | Self::An500 => "qemu-system-arm",
            Self::RiscvVirt => "qemu-system-riscv32",
        }
    }

    /// QEMU's `-machine` name.
    pub const fn qemu_machine(self) -> &'static str {
        match self {
            Self::An386 => "mps2-an386",
            Self::An500 => "mps2-an500",
            Self::RiscvVirt => "virt",
        }
    }

    /// The processor core.
    pub const fn core(self) -> &'static str {
        match self {
            Self::An386 => "Cortex-M4F",
            Self::An500 => "Cortex-M7",
            Self::RiscvVirt => "RV32IMAC",
        }
    }

    /// The Rust target of its firmware image.
    pub const fn rust_target(self) -> &'static str {
        match self {
            Self::An386 | Self::An500 => "thumbv7em-none-eabihf",
            Self::RiscvVirt => "riscv32imac-unknown-none-elf",
        }
    }

    /// Guest address of the shared region.
    pub const fn shared_base(self) -> usize {
        match self {
            Self::An386 => 0x2100_0000,
            Self::An500 => 0x6000_0000,
            Self::RiscvVirt => 0x8100_0000,
        }
    }

    /// Size of the file behind the memory QEMU maps from it (`memory-backend-file`).
    pub const fn backing_file_bytes(self) -> usize {
        match self {
            Self::An386 | Self::An500 => 16 * 1024 * 1024,
            Self::RiscvVirt => 32 * 1024 * 1024,
        }
    }

    /// Byte offset of the shared region in the backing file.
    pub const fn shared_file_offset(self) -> usize {
        match self {
            Self::An386 | Self::An500 => 0,
            Self::RiscvVirt => 16 * 1024 * 1024,
        }
    }

    /// The clock of the servo tick's timer: the CMSDK timer's 25 MHz, the RTC's nanoseconds.
    pub const fn timer_clock_hz(self) -> u32 {
        match self {
            Self::An386 | Self::An500 => 25_000_000,
            Self::RiscvVirt => 1_000_000_000,
        }
    }

    /// Timer counts per servo period.
    pub const fn servo_period_counts(self) -> u32 {
        self.timer_clock_hz() / SERVO_RATE_HZ
    }

    /// Nanoseconds per timer count.
    pub const fn count_ns(self) -> u32 {
        1_000_000_000 / self.timer_clock_hz()
    }
}

/// Size of the shared region (within every board's backing file).
pub const SHARED_BYTES: usize = 1024 * 1024;

/// Byte offset of the diagnostics block.
pub const DIAG_OFFSET: usize = 0x4000;
/// Words in the diagnostics block.
pub const DIAG_WORDS: usize = 17;
/// Diagnostics word: [`DIAG_MAGIC_VALUE`] once the firmware has booted.
pub const DIAG_MAGIC: usize = 0;
/// Diagnostics word: servo period in timer counts.
pub const DIAG_PERIOD_COUNTS: usize = 1;
/// Diagnostics word: timer counts from the tick edge to the input wait, last tick.
pub const DIAG_ENTRY_LAST: usize = 2;
/// Diagnostics word: largest `DIAG_ENTRY_LAST`.
pub const DIAG_ENTRY_MAX: usize = 3;
/// Diagnostics word: timer counts from input arrival to handler end, last served tick.
pub const DIAG_BUSY_LAST: usize = 4;
/// Diagnostics word: largest `DIAG_BUSY_LAST`.
pub const DIAG_BUSY_MAX: usize = 5;
/// Diagnostics word: sum of `DIAG_BUSY_LAST`, low 32 bits.
pub const DIAG_BUSY_SUM_LO: usize = 6;
/// Diagnostics word: sum of `DIAG_BUSY_LAST`, high 32 bits.
pub const DIAG_BUSY_SUM_HI: usize = 7;
/// Diagnostics word: model work requests.
pub const DIAG_MODEL_REQUESTS: usize = 8;
/// Diagnostics word: model work runs.
pub const DIAG_MODEL_RUNS: usize = 9;
/// Diagnostics word: control bytes received.
pub const DIAG_CONTROL_RX_BYTES: usize = 10;
/// Diagnostics word: control bytes dropped (receive queue full).
pub const DIAG_CONTROL_RX_DROPPED: usize = 11;
/// Diagnostics word: input faults.
pub const DIAG_INPUT_FAULTS: usize = 12;
/// Diagnostics word: timer counts from input arrival to the very end of the servo handler
/// (after publishing the counters), of the previous served tick (published one tick late).
pub const DIAG_HANDLER_LAST: usize = 13;
/// Diagnostics word: largest `DIAG_HANDLER_LAST`.
pub const DIAG_HANDLER_MAX: usize = 14;
/// Diagnostics word: a running FNV-1a hash of (ticks served, timer counts into the period)
/// at each completion of model work: where the background finished, relative to the
/// ticks. Under `-icount` it must not depend on the host's pace (docs/firmware.md).
pub const DIAG_MODEL_TIMING_HASH: usize = 15;
/// Diagnostics word: timer counts of one evaluation of the built-in paper program
/// (Eqs. 2-3) on typical features, measured at boot before the tick starts (the mean of 16).
pub const DIAG_PAPER_EVAL_COUNTS: usize = 16;
/// Value of [`DIAG_MAGIC`]: "DIAG".
pub const DIAG_MAGIC_VALUE: u32 = 0x4741_4944;

/// Byte offset of the config store.
pub const CONFIG_OFFSET: usize = 0x1_0000;
/// Bytes per config slot (two slots).
pub const CONFIG_SLOT_BYTES: usize = 32 * 1024;

/// The servo rate.
pub const SERVO_RATE_HZ: u32 = sts_twin_core::SERVO_RATE_HZ;

/// Polls of `HOST_SEQ` before a tick gives up waiting (an underrun). A poll is a handful
/// of guest instructions; QEMU runs 16 million of them in roughly a second of host time
/// (measured 0.1 to 0.15 us a poll), far beyond any healthy host step, so an underrun
/// means a stalled host, not a slow one.
pub const BUS_SPIN_BOUND: u32 = 16_000_000;

const _: () = assert!(sts_twin_core::bus::BUS_BYTES <= DIAG_OFFSET);
const _: () = assert!(DIAG_OFFSET + 4 * DIAG_WORDS <= CONFIG_OFFSET);
const _: () = assert!(CONFIG_OFFSET + 2 * CONFIG_SLOT_BYTES <= SHARED_BYTES);
// Every board's region lies inside its backing file (and, on `virt`, below the device tree).
const _: () = {
    let mut i = 0;
    while i < QemuBoard::ALL.len() {
        let b = QemuBoard::ALL[i];
        assert!(b.shared_file_offset() + SHARED_BYTES <= b.backing_file_bytes() - 2 * 1024 * 1024);
        assert!(b.timer_clock_hz().is_multiple_of(SERVO_RATE_HZ));
        i += 1;
    }
};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_board_is_known_by_its_name_and_has_its_own_shared_region() {
        assert_eq!(QemuBoard::from_scc_id(0x4104_3860), Some(QemuBoard::An386));
        assert_eq!(QemuBoard::from_scc_id(0x4104_5000), Some(QemuBoard::An500));
        assert_eq!(QemuBoard::from_scc_id(0x4104_5050), None);
        assert_ne!(QemuBoard::An386.shared_base(), QemuBoard::An500.shared_base());
        for board in QemuBoard::ALL {
            assert_eq!(QemuBoard::from_name(board.name()), Some(board));
            assert_eq!(board.servo_period_counts() * SERVO_RATE_HZ, board.timer_clock_hz());
        }
        // The PSRAM must not meet the Arm linker's RAM (memory.x: 4 MiB at 0x2000_0000).
        assert!(QemuBoard::An386.shared_base() >= 0x2040_0000);
        // On virt the region is the RAM's upper half: RAM starts at 0x8000_0000.
        let virt = QemuBoard::RiscvVirt;
        assert_eq!(virt.shared_base(), 0x8000_0000 + virt.shared_file_offset());
        assert_eq!(virt.shared_file_offset() * 2, virt.backing_file_bytes());
    }
}
