//! Least-squares fit of a sinusoid of known frequency: the amplitude and phase of a signal's
//! component at the command frequency.

use std::f64::consts::PI;

use sts_numerics::lsq::least_squares;

/// A sinusoid `amp * sin(2 pi f t + phase_rad) + offset` fitted to samples.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SineFit {
    /// Amplitude (same unit as the samples).
    pub amp: f64,
    /// Phase at `t = 0`, radians, in (-pi, pi].
    pub phase_rad: f64,
    /// Mean of the samples.
    pub offset: f64,
    /// RMS of the samples minus the fitted sinusoid.
    pub residual_rms: f64,
}

/// Fits `y(t) ~ a sin(wt) + b cos(wt) + c` by linear least squares ([`least_squares`]).
/// Returns `None` for fewer than three samples or a singular system (e.g. `freq_hz = 0`).
pub fn fit_sine(t_s: &[f64], y: &[f64], freq_hz: f64) -> Option<SineFit> {
    let n = t_s.len().min(y.len());
    if n < 3 || !(freq_hz.is_finite() && freq_hz > 0.0) {
        return None;
    }
    let w = 2.0 * PI * freq_hz;
    let rows: Vec<[f64; 3]> = t_s[..n]
        .iter()
        .map(|&t| {
            let (s, c) = (w * t).sin_cos();
            [s, c, 1.0]
        })
        .collect();
    let fit = least_squares(&rows, &y[..n])?;
    let [a, b, c] = [fit.coefficients[0], fit.coefficients[1], fit.coefficients[2]];
    // a sin + b cos = amp sin(wt + phase) with amp cos(phase) = a, amp sin(phase) = b.
    Some(SineFit { amp: a.hypot(b), phase_rad: b.atan2(a), offset: c, residual_rms: fit.residual_rms })
}

/// Amplitude of the component at `freq_hz` of `y` sampled at `t_s` (least squares on whole data).
pub fn line_amp(t_s: &[f64], y: &[f64], freq_hz: f64) -> f64 {
    let w = 2.0 * PI * freq_hz;
    let (mut a, mut b) = (0.0, 0.0);
    for (t, v) in t_s.iter().zip(y) {
        let (s, c) = (w * t).sin_cos();
        a += v * s;
        b += v * c;
    }
    let n = t_s.len().max(1) as f64;
    2.0 * (a / n).hypot(b / n)
}

/// Wraps an angle in degrees to (-180, 180].
pub fn wrap_deg(angle_deg: f64) -> f64 {
    let wrapped = angle_deg.rem_euclid(360.0);
    if wrapped > 180.0 {
        wrapped - 360.0
    } else {
        wrapped
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_amplitude_phase_and_offset() {
        let t: Vec<f64> = (0..8000).map(|i| i as f64 / 8000.0).collect();
        let y: Vec<f64> = t.iter().map(|&t| 2.5 * (2.0 * PI * 30.0 * t + 0.7).sin() + 0.3).collect();
        let fit = fit_sine(&t, &y, 30.0).unwrap();
        assert!((fit.amp - 2.5).abs() < 1e-9);
        assert!((fit.phase_rad - 0.7).abs() < 1e-9);
        assert!((fit.offset - 0.3).abs() < 1e-9);
        assert!(fit.residual_rms < 1e-9);
        assert!(fit_sine(&t, &y, 0.0).is_none());
        assert!(fit_sine(&t[..2], &y[..2], 30.0).is_none());
    }

    #[test]
    fn line_amplitude_of_a_sine() {
        let t: Vec<f64> = (0..8000).map(|i| i as f64 / 8000.0).collect();
        let y: Vec<f64> =
            t.iter().map(|t| 0.3 * (2.0 * PI * 15.0 * t + 0.4).sin() + 0.1 * (2.0 * PI * 45.0 * t).sin()).collect();
        assert!((line_amp(&t, &y, 15.0) - 0.3).abs() < 1e-9);
        assert!((line_amp(&t, &y, 45.0) - 0.1).abs() < 1e-9);
        assert!(line_amp(&t, &y, 30.0) < 1e-9);
    }

    #[test]
    fn wraps_degrees() {
        assert_eq!(wrap_deg(190.0), -170.0);
        assert_eq!(wrap_deg(-180.0), 180.0);
        assert_eq!(wrap_deg(45.0), 45.0);
    }
}
