//! The training targets of a group: amplitude and phase of the total dynamic error
//! (capacitance minus command) over the group's last second, relative to the command.

use sts_dataset::GroupData;

use crate::sine::{fit_sine, wrap_deg, SineFit};

/// Smallest measured dynamic-error amplitude whose phase trains and scores the phase model, um.
pub const PHASE_MIN_AMP_UM: f64 = 0.02;

/// Whether a group's measured phase means something: its dynamic error's amplitude is at
/// least [`PHASE_MIN_AMP_UM`] and the sine at the command frequency holds more of the error
/// than everything else in it (the rest's RMS below the sine's, `amp / sqrt(2)`). Where a
/// position-periodic ripple or friction's steps dominate a slow group, the fundamental's phase
/// is whatever their leakage gives it, and a phase formula trained on it fits no group well.
pub fn phase_is_measured(targets: &GroupTargets) -> bool {
    targets.de_amp_um >= PHASE_MIN_AMP_UM && targets.de.residual_rms < targets.de_amp_um / std::f64::consts::SQRT_2
}

/// Seconds at the end of a group over which the targets are measured.
pub const TARGET_WINDOW_S: f64 = 1.0;

/// The measured dynamic error of one group.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroupTargets {
    /// Command frequency, Hz.
    pub freq_hz: f64,
    /// The command's own fit over the target window.
    pub cmd: SineFit,
    /// Dynamic-error amplitude at the command frequency, um.
    pub de_amp_um: f64,
    /// Dynamic-error phase relative to the command phase, degrees: in (-180, 180] as measured,
    /// then on the dataset's branch ([`crate::unwrap_phases`]).
    pub de_phase_deg: f64,
    /// The dynamic error's fit (phase relative to t = 0).
    pub de: SineFit,
    /// First sample index of the target window.
    pub window_start: usize,
}

/// Why targets could not be computed.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum TargetError {
    /// Too few samples for the window.
    #[error("the group has {samples} samples, fewer than the {needed} of a {window_s} s target window")]
    TooShort {
        /// Samples in the group.
        samples: usize,
        /// Samples needed.
        needed: usize,
        /// The window, s.
        window_s: f64,
    },
    /// The command has no component at the frequency (or the fit is singular).
    #[error("the command has no sinusoid at {freq_hz} Hz to measure the phase against")]
    NoCommand {
        /// The frequency.
        freq_hz: f64,
    },
}

/// Measures the targets of `group` (sampled at `sample_rate_hz`, command at `freq_hz`).
pub fn group_targets(group: &GroupData, sample_rate_hz: f64, freq_hz: f64) -> Result<GroupTargets, TargetError> {
    let n = group.len();
    let needed = (TARGET_WINDOW_S * sample_rate_hz).round() as usize;
    if n < needed.max(3) {
        return Err(TargetError::TooShort { samples: n, needed, window_s: TARGET_WINDOW_S });
    }
    let start = n - needed;
    let t = &group.t_s[start..];
    let cmd = fit_sine(t, &group.z_cmd_um[start..], freq_hz)
        .filter(|f| f.amp > 0.0)
        .ok_or(TargetError::NoCommand { freq_hz })?;
    let de_samples: Vec<f64> =
        group.z_tcp_um[start..].iter().zip(&group.z_cmd_um[start..]).map(|(tcp, c)| tcp - c).collect();
    let de = fit_sine(t, &de_samples, freq_hz).ok_or(TargetError::NoCommand { freq_hz })?;
    Ok(GroupTargets {
        freq_hz,
        cmd,
        de_amp_um: de.amp,
        de_phase_deg: wrap_deg((de.phase_rad - cmd.phase_rad).to_degrees()),
        de,
        window_start: start,
    })
}

/// The command phase (radians) at every sample of `t_s`, from the command's fit.
pub fn command_phase_rad(cmd: &SineFit, freq_hz: f64, t_s: f64) -> f64 {
    2.0 * std::f64::consts::PI * freq_hz * t_s + cmd.phase_rad
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// A 2 Hz group whose error is a fundamental of `fund_um` plus a 9th harmonic of `ripple_um`.
    fn slow_group(fund_um: f64, ripple_um: f64) -> GroupTargets {
        let n = 8000 * 3;
        let mut g = GroupData::with_len(n);
        for i in 0..n {
            let t = i as f64 / 8000.0;
            g.t_s[i] = t;
            g.z_cmd_um[i] = 5.0 * (2.0 * PI * 2.0 * t).sin();
            g.z_tcp_um[i] =
                g.z_cmd_um[i] + fund_um * (2.0 * PI * 2.0 * t + 0.5).sin() + ripple_um * (2.0 * PI * 18.0 * t).sin();
        }
        group_targets(&g, 8000.0, 2.0).unwrap()
    }

    #[test]
    fn a_phase_is_measured_where_the_fundamental_holds_the_error() {
        assert!(phase_is_measured(&slow_group(0.1, 0.05)));
        // The same fundamental under a ripple that holds most of the error.
        assert!(!phase_is_measured(&slow_group(0.1, 0.2)));
        // Too small to have a phase.
        assert!(!phase_is_measured(&slow_group(0.01, 0.0)));
    }

    #[test]
    fn measures_amplitude_and_phase_relative_to_the_command() {
        let n = 8000 * 6;
        let mut g = GroupData::with_len(n);
        for i in 0..n {
            let t = i as f64 / 8000.0;
            g.t_s[i] = t;
            g.z_cmd_um[i] = 5.0 * (2.0 * PI * 30.0 * t + 0.2).sin();
            // TCP = cmd + DE with DE = 2 um at +40 degrees from the command.
            g.z_tcp_um[i] = g.z_cmd_um[i] + 2.0 * (2.0 * PI * 30.0 * t + 0.2 + 40f64.to_radians()).sin();
        }
        let targets = group_targets(&g, 8000.0, 30.0).unwrap();
        assert!((targets.de_amp_um - 2.0).abs() < 1e-9);
        assert!((targets.de_phase_deg - 40.0).abs() < 1e-7);
        assert_eq!(targets.window_start, n - 8000);
        let short = GroupData::with_len(100);
        assert!(matches!(group_targets(&short, 8000.0, 30.0), Err(TargetError::TooShort { .. })));
        assert!(matches!(group_targets(&GroupData::with_len(9000), 8000.0, 30.0), Err(TargetError::NoCommand { .. })));
    }
}
