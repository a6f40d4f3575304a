//! Least-squares fit of a sinusoid of known frequency: the amplitude and phase of a signal's
//! component at the command frequency.

use std::f64::consts::PI;

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

/// Fits `y(t) ~ a sin(wt) + b cos(wt) + c` by linear least squares (3x3 normal equations).
/// Returns `None` for fewer than three samples or a singular system (e.g. `freq_hz = 0`).
pub fn fit_sine(t_s: &[f64], y: &[f64], freq_hz: f64) -> Option<SineFit> {
    let n = t_s.len().min(y.len());
    if n < 3 || !(freq_hz.is_finite() && freq_hz > 0.0) {
        return None;
    }
    let w = 2.0 * PI * freq_hz;
    // Normal equations of the basis (s, c, 1).
    let (mut ss, mut sc, mut s1, mut cc, mut c1) = (0.0, 0.0, 0.0, 0.0, 0.0);
    let (mut ys, mut yc, mut y1) = (0.0, 0.0, 0.0);
    for i in 0..n {
        let (s, c) = (w * t_s[i]).sin_cos();
        ss += s * s;
        sc += s * c;
        s1 += s;
        cc += c * c;
        c1 += c;
        ys += y[i] * s;
        yc += y[i] * c;
        y1 += y[i];
    }
    let m = [[ss, sc, s1], [sc, cc, c1], [s1, c1, n as f64]];
    let [a, b, c] = solve3(m, [ys, yc, y1])?;
    let mut sq = 0.0;
    for i in 0..n {
        let (s, co) = (w * t_s[i]).sin_cos();
        let r = y[i] - (a * s + b * co + c);
        sq += r * r;
    }
    // a sin + b cos = amp sin(wt + phase) with amp cos(phase) = a, amp sin(phase) = b.
    Some(SineFit { amp: a.hypot(b), phase_rad: b.atan2(a), offset: c, residual_rms: (sq / n as f64).sqrt() })
}

/// Solves a 3x3 system by Cramer's rule; `None` if singular.
fn solve3(m: [[f64; 3]; 3], r: [f64; 3]) -> Option<[f64; 3]> {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(m);
    if !d.is_finite() || d.abs() < 1e-12 * (m[0][0] * m[1][1] * m[2][2]).abs().max(1e-300) {
        return None;
    }
    let mut out = [0.0; 3];
    for (k, value) in out.iter_mut().enumerate() {
        let mut mk = m;
        for row in 0..3 {
            mk[row][k] = r[row];
        }
        *value = det(mk) / d;
    }
    Some(out)
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
