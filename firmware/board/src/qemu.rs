//! The QEMU board's (mps2-an386) shared-memory map: the 16 MiB PSRAM at `0x2100_0000` is a
//! file the HIL host maps too. It holds the analogue bus ([`sts_twin_core::bus`]) at offset
//! 0, a diagnostics block the firmware fills for the host, and the persistent config store.
//!
//! | PSRAM offset | bytes | what | written by |
//! |---|---|---|---|
//! | `0x0000` | [`sts_twin_core::bus::BUS_BYTES`] | the analogue bus | both |
//! | [`DIAG_OFFSET`] | `4 * DIAG_WORDS` | diagnostics words (`DIAG_*`) | firmware |
//! | [`CONFIG_OFFSET`] | `2 * CONFIG_SLOT_BYTES` | config store ([`crate::config`] A/B records) | firmware |
//!
//! The config store persists across reboots because the host keeps the backing file and
//! hands the same file to the next QEMU; a fresh file (all zero) reads as empty.

/// Address of the PSRAM.
pub const PSRAM_BASE: usize = 0x2100_0000;
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
