//! Shared helpers of the HIL tests.

use sts_twin::hil::{FirmwareVariant, HilConfig};

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
