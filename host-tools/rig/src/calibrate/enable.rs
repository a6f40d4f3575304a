//! The test a lab makes before a cut: switch compensation on with the axis at rest and see
//! that the tool does not move. The co-processor's compensation and the controller's
//! analogue feedforward are switched on together; the pulses the controller adds and the
//! probe's reading before and after tell whether the offset is right.

use serde::Serialize;
use sts_twin_core::wire::Request;

use super::rest::RestRig;
use crate::RigError;
use sts_twin_core::SERVO_RATE_HZ;

/// Settings of the enable check.
#[derive(Clone, Debug)]
pub struct EnableConfig {
    /// Time at rest before the first average (the axis settles from earlier motion), s.
    pub settle_s: f64,
    /// Averaging window before and after, s.
    pub window_s: f64,
    /// The servo rate, Hz.
    pub sample_rate_hz: f64,
}

impl Default for EnableConfig {
    fn default() -> Self {
        Self { settle_s: 0.25, window_s: 0.1, sample_rate_hz: f64::from(SERVO_RATE_HZ) }
    }
}

/// What switching compensation on did.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct EnableCheck {
    /// The offset in force in the co-processor, V.
    pub offset_v: f64,
    /// Size of one motion pulse, nm.
    pub pulse_nm: f64,
    /// Largest number of pulses the controller added on any tick after switching on.
    pub added_pulses_max: i64,
    /// Mean pulses added over the last window.
    pub added_pulses_mean: f64,
    /// Probe reading after minus before, nm.
    pub tcp_move_nm: f64,
    /// True TCP position after minus before, nm, where the plant knows it (a simulation; a
    /// lab's plant gives the probe's move).
    pub tcp_true_move_nm: f64,
}

impl EnableCheck {
    /// Less than one motion pulse, by the controller's count and by the probe.
    pub fn passed(&self) -> bool {
        self.added_pulses_max < 1 && self.tcp_move_nm.abs() < self.pulse_nm
    }
}

/// Runs the check on `rig` with the co-processor's parameters as they are (a program, if
/// any, stays; with none the prediction is zero). `enable_ramp_ticks` is the co-processor's
/// ramp, waited out before the last average. Compensation is switched off again at the end.
pub fn enable_check(
    rig: &mut RestRig<'_>,
    pulse_nm: f64,
    enable_ramp_ticks: u32,
    config: &EnableConfig,
) -> Result<EnableCheck, RigError> {
    if !(config.settle_s >= 0.0 && config.window_s > 0.0 && config.sample_rate_hz > 0.0) {
        return Err(RigError::EnableTimes);
    }
    let offset_v = f64::from(rig.status()?.params.offset_v);
    let settle_ticks = (config.settle_s * config.sample_rate_hz).round() as u32;
    let window_ticks = ((config.window_s * config.sample_rate_hz).round() as u32).max(1);
    rig.request("switching compensation off", Request::SetEnabled(false))?;
    // Switched on at rest on purpose: the supervisor would hold the gain at zero.
    let supervisor = crate::supervisor_off(rig.parts().0)?;
    rig.analog_enabled = false;
    let before = rig.average(settle_ticks, window_ticks)?;
    rig.analog_enabled = true;
    rig.request("switching compensation on", Request::SetEnabled(true))?;
    let mut added_pulses_max = 0;
    for _ in 0..u64::from(enable_ramp_ticks) + u64::from(settle_ticks) {
        let (machine, _) = rig.step()?;
        added_pulses_max = added_pulses_max.max(machine.ain_pulses.abs());
    }
    let after = rig.average(0, window_ticks)?;
    added_pulses_max = added_pulses_max.max(after.ain_pulses_max);
    rig.request("switching compensation off", Request::SetEnabled(false))?;
    crate::restore_supervisor(rig.parts().0, supervisor)?;
    Ok(EnableCheck {
        offset_v,
        pulse_nm,
        added_pulses_max,
        added_pulses_mean: after.ain_pulses,
        tcp_move_nm: (after.z_tcp_um - before.z_tcp_um) * 1e3,
        tcp_true_move_nm: (after.z_tcp_true_um - before.z_tcp_true_um) * 1e3,
    })
}
