//! Sine fitting: the amplitude and phase of a signal's component at a known frequency.
//!
//! The measurement test's figures use it on the last second of each group (the paper's
//! `t_{n+1}..t_k` window): amplitudes of the encoder and TCP, their phase lag behind the
//! command, and the amplitude of the dynamic error `z_tcp - z_cmd`.

/// A fitted `offset + amp * sin(2 pi f t + phase)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SineFit {
    /// Amplitude.
    pub amp: f64,
    /// Phase, radians.
    pub phase_rad: f64,
    /// Mean.
    pub offset: f64,
}

/// Least-squares fit of `offset + a sin(wt) + b cos(wt)` to `(t_s, y)`.
pub fn fit_sine(t_s: &[f64], y: &[f64], freq_hz: f64) -> SineFit {
    let w = 2.0 * std::f64::consts::PI * freq_hz;
    // Normal equations of the 3x3 system.
    let mut m = [[0.0f64; 3]; 3];
    let mut r = [0.0f64; 3];
    for (&t, &v) in t_s.iter().zip(y) {
        let basis = [(w * t).sin(), (w * t).cos(), 1.0];
        for i in 0..3 {
            r[i] += basis[i] * v;
            for j in 0..3 {
                m[i][j] += basis[i] * basis[j];
            }
        }
    }
    let x = solve3(m, r);
    SineFit { amp: x[0].hypot(x[1]), phase_rad: x[1].atan2(x[0]), offset: x[2] }
}

#[allow(clippy::needless_range_loop)]
fn solve3(mut m: [[f64; 3]; 3], mut r: [f64; 3]) -> [f64; 3] {
    for col in 0..3 {
        let pivot = (col..3).max_by(|&a, &b| m[a][col].abs().total_cmp(&m[b][col].abs())).unwrap_or(col);
        m.swap(col, pivot);
        r.swap(col, pivot);
        let d = m[col][col];
        if d.abs() < 1e-300 {
            return [0.0; 3];
        }
        for row in 0..3 {
            if row != col {
                let f = m[row][col] / d;
                for k in 0..3 {
                    m[row][k] -= f * m[col][k];
                }
                r[row] -= f * r[col];
            }
        }
    }
    [r[0] / m[0][0], r[1] / m[1][1], r[2] / m[2][2]]
}

/// Phase lag of `signal` behind `reference`, degrees in (-180, 180].
pub fn lag_deg(reference: &SineFit, signal: &SineFit) -> f64 {
    let mut d = (reference.phase_rad - signal.phase_rad).to_degrees();
    while d > 180.0 {
        d -= 360.0;
    }
    while d <= -180.0 {
        d += 360.0;
    }
    d
}

/// The figures of one group over a window: what the paper reports per group.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroupFigures {
    /// Encoder amplitude, um.
    pub enc_amp_um: f64,
    /// Encoder phase lag behind the command, degrees.
    pub enc_lag_deg: f64,
    /// TCP (probe) amplitude, um.
    pub tcp_amp_um: f64,
    /// TCP phase lag behind the command, degrees.
    pub tcp_lag_deg: f64,
    /// Amplitude of the tracking error `z_enc - z_cmd` at the command frequency, um.
    pub tracking_error_um: f64,
    /// Amplitude of the total dynamic error `z_tcp - z_cmd` at the command frequency, um.
    pub dynamic_error_um: f64,
}

/// Figures of a group over `[from_s, to_s)` of its time column.
pub fn group_figures(group: &sts_dataset::GroupData, freq_hz: f64, from_s: f64, to_s: f64) -> GroupFigures {
    let range: Vec<usize> = (0..group.len()).filter(|&i| group.t_s[i] >= from_s && group.t_s[i] < to_s).collect();
    let pick = |v: &[f64]| range.iter().map(|&i| v[i]).collect::<Vec<f64>>();
    let t = pick(&group.t_s);
    let cmd = fit_sine(&t, &pick(&group.z_cmd_um), freq_hz);
    let enc = fit_sine(&t, &pick(&group.z_enc_um), freq_hz);
    let tcp = fit_sine(&t, &pick(&group.z_tcp_um), freq_hz);
    let te: Vec<f64> = range.iter().map(|&i| group.z_enc_um[i] - group.z_cmd_um[i]).collect();
    let de: Vec<f64> = range.iter().map(|&i| group.z_tcp_um[i] - group.z_cmd_um[i]).collect();
    GroupFigures {
        enc_amp_um: enc.amp,
        enc_lag_deg: lag_deg(&cmd, &enc),
        tcp_amp_um: tcp.amp,
        tcp_lag_deg: lag_deg(&cmd, &tcp),
        tracking_error_um: fit_sine(&t, &te, freq_hz).amp,
        dynamic_error_um: fit_sine(&t, &de, freq_hz).amp,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_amplitude_and_phase() {
        let t: Vec<f64> = (0..8000).map(|i| i as f64 / 8000.0).collect();
        let y: Vec<f64> = t.iter().map(|t| 0.5 + 3.0 * (2.0 * std::f64::consts::PI * 7.0 * t - 0.2).sin()).collect();
        let f = fit_sine(&t, &y, 7.0);
        assert!((f.amp - 3.0).abs() < 1e-9 && (f.phase_rad + 0.2).abs() < 1e-9 && (f.offset - 0.5).abs() < 1e-9);
    }
}
