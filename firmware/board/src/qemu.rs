//! The QEMU boards' shared-memory map. Two MPS2 FPGA images run the same firmware image:
//! `mps2-an386` (Cortex-M4F) and `mps2-an500` (Cortex-M7, the STM32H7's core). They differ,
//! for this firmware, only in where the 16 MiB PSRAM sits ([`Mps2Image::psram_base`]); the
//! firmware reads the board's SCC ID at boot to tell them apart. The PSRAM is a file the HIL
//! host maps too. It holds the analogue bus ([`sts_twin_core::bus`]) at offset 0, a
//! diagnostics block the firmware fills for the host, and the persistent config store.
//!
//! | PSRAM offset | bytes | what | written by |
//! |---|---|---|---|
//! | `0x0000` | [`sts_twin_core::bus::BUS_BYTES`] | the analogue bus | both |
//! | [`DIAG_OFFSET`] | `4 * DIAG_WORDS` | diagnostics words (`DIAG_*`) | firmware |
//! | [`CONFIG_OFFSET`] | `2 * CONFIG_SLOT_BYTES` | config store ([`crate::config`] A/B records) | firmware |
//!
//! The config store persists across reboots because the host keeps the backing file and
//! hands the same file to the next QEMU; a fresh file (all zero) reads as empty.

/// The MPS2 FPGA images the firmware runs on under QEMU.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Mps2Image {
    /// AN386: Cortex-M4F, PSRAM at `0x2100_0000`.
    An386,
    /// AN500: Cortex-M7 (the STM32H7's core), PSRAM at `0x6000_0000`.
    An500,
}

/// Address of the serial communication controller's ID register, which names the FPGA image.
pub const SCC_ID_ADDR: usize = 0x4002_FFFC;

impl Mps2Image {
    /// Every image, in the order the tools list them.
    pub const ALL: [Self; 2] = [Self::An386, Self::An500];

    /// The image whose SCC ID register reads `scc_id`; `None` for another board.
    pub const fn from_scc_id(scc_id: u32) -> Option<Self> {
        match scc_id {
            0x4104_3860 => Some(Self::An386),
            0x4104_5000 => Some(Self::An500),
            _ => None,
        }
    }

    /// Address of the PSRAM (the host-shared file).
    pub const fn psram_base(self) -> usize {
        match self {
            Self::An386 => 0x2100_0000,
            Self::An500 => 0x6000_0000,
        }
    }

    /// QEMU's `-machine` name.
    pub const fn qemu_machine(self) -> &'static str {
        match self {
            Self::An386 => "mps2-an386",
            Self::An500 => "mps2-an500",
        }
    }

    /// The processor core.
    pub const fn core(self) -> &'static str {
        match self {
            Self::An386 => "Cortex-M4F",
            Self::An500 => "Cortex-M7",
        }
    }
}

/// Size of the PSRAM (and of the host's backing file).
pub const PSRAM_BYTES: usize = 16 * 1024 * 1024;

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

/// The CMSDK timer clock of the board.
pub const TIMER_CLOCK_HZ: u32 = 25_000_000;
/// The servo rate.
pub const SERVO_RATE_HZ: u32 = sts_twin_core::SERVO_RATE_HZ;
/// Timer counts per servo period.
pub const SERVO_PERIOD_COUNTS: u32 = TIMER_CLOCK_HZ / SERVO_RATE_HZ;

/// Polls of `HOST_SEQ` before a tick gives up waiting (an underrun). A poll is a handful
/// of guest instructions; QEMU runs 16 million of them in roughly a second of host time
/// (measured 0.1 to 0.15 us a poll), far beyond any healthy host step, so an underrun
/// means a stalled host, not a slow one.
pub const BUS_SPIN_BOUND: u32 = 16_000_000;

const _: () = assert!(sts_twin_core::bus::BUS_BYTES <= DIAG_OFFSET);
const _: () = assert!(DIAG_OFFSET + 4 * DIAG_WORDS <= CONFIG_OFFSET);
const _: () = assert!(CONFIG_OFFSET + 2 * CONFIG_SLOT_BYTES <= PSRAM_BYTES);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_image_is_known_by_its_scc_id_and_has_its_own_psram() {
        assert_eq!(Mps2Image::from_scc_id(0x4104_3860), Some(Mps2Image::An386));
        assert_eq!(Mps2Image::from_scc_id(0x4104_5000), Some(Mps2Image::An500));
        assert_eq!(Mps2Image::from_scc_id(0x4104_5050), None);
        assert_ne!(Mps2Image::An386.psram_base(), Mps2Image::An500.psram_base());
        for image in Mps2Image::ALL {
            // The PSRAM must not meet the linker's RAM (memory.x: 4 MiB at 0x2000_0000).
            assert!(image.psram_base() >= 0x2040_0000);
            assert!(image.qemu_machine().starts_with("mps2-an"));
        }
    }
}
