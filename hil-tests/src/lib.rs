//! Shared helpers of the HIL tests.

use sts_twin::hil::{FirmwareVariant, HilConfig};
use sts_twin_core::bus::{InputSlot, IN_FLAG_PHASE_VALID};

/// A harness configuration that boots the bring-up application of the board seam (the
/// platform tests check the platform, not the twin).
pub fn bringup_config() -> HilConfig {
    HilConfig { variant: FirmwareVariant::BringUp, ..HilConfig::default() }
}

/// A harness configuration that boots the twin firmware.
pub fn twin_config() -> HilConfig {
    HilConfig::default()
}

/// Runs the HIL tests of one test binary one at a time: each boots a QEMU whose guest spins
/// on the bus, and on a 2-core machine several at once starve the host side of the lockstep
/// (a stalled host is, rightly, counted as an underrun by the firmware). Hold the guard for
/// the whole test.
pub fn serial() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

/// Tick `k` of a recorded-like stream: a 40 Hz motion whose amplitude changes (0.3 Hz), with
/// deterministic pseudo-noise on the accelerometer code.
pub fn tone_input(k: u32) -> InputSlot {
    let t = k as f64 / 8000.0;
    let amp = 4000.0 + 2000.0 * (2.0 * std::f64::consts::PI * 0.3 * t).sin();
    let phase = 2.0 * std::f64::consts::PI * 40.0 * t;
    let noise = ((k.wrapping_mul(2_654_435_761) >> 16) % 9) as f64 - 4.0;
    InputSlot {
        tick: k,
        acc_code: (-amp * phase.sin() + noise).round() as i16,
        flags: IN_FLAG_PHASE_VALID,
        cmd_phase_turns: ((40.0 * t).fract() * 4_294_967_296.0) as u64 as u32,
        cmd_pos_nm: (3000.0 * phase.sin()) as i32,
    }
}
