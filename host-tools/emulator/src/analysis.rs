//! The paper's figures of a group, from the sine fit of `sts_analysis` over a window (the
//! paper's `t_{n+1}..t_k`, the last second): amplitudes of the encoder and TCP, their phase
//! lag behind the command, and the amplitudes of the tracking and dynamic errors.

use sts_analysis::sine::{fit_sine, wrap_deg, SineFit};

/// Phase lag of `signal` behind `reference`, degrees in (-180, 180].
pub fn lag_deg(reference: &SineFit, signal: &SineFit) -> f64 {
    wrap_deg((reference.phase_rad - signal.phase_rad).to_degrees())
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

/// Figures of a group over `[from_s, to_s)` of its time column; `None` where the window holds
/// fewer than three samples or `freq_hz` is not a frequency.
pub fn group_figures(group: &sts_dataset::GroupData, freq_hz: f64, from_s: f64, to_s: f64) -> Option<GroupFigures> {
    let range: Vec<usize> = (0..group.len()).filter(|&i| group.t_s[i] >= from_s && group.t_s[i] < to_s).collect();
    let pick = |v: &[f64]| range.iter().map(|&i| v[i]).collect::<Vec<f64>>();
    let t = pick(&group.t_s);
    let cmd = fit_sine(&t, &pick(&group.z_cmd_um), freq_hz)?;
    let enc = fit_sine(&t, &pick(&group.z_enc_um), freq_hz)?;
    let tcp = fit_sine(&t, &pick(&group.z_tcp_um), freq_hz)?;
    let te: Vec<f64> = range.iter().map(|&i| group.z_enc_um[i] - group.z_cmd_um[i]).collect();
    let de: Vec<f64> = range.iter().map(|&i| group.z_tcp_um[i] - group.z_cmd_um[i]).collect();
    Some(GroupFigures {
        enc_amp_um: enc.amp,
        enc_lag_deg: lag_deg(&cmd, &enc),
        tcp_amp_um: tcp.amp,
        tcp_lag_deg: lag_deg(&cmd, &tcp),
        tracking_error_um: fit_sine(&t, &te, freq_hz)?.amp,
        dynamic_error_um: fit_sine(&t, &de, freq_hz)?.amp,
    })
}
