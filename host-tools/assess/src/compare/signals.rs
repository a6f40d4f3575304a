//! Where the residual sits: its spectrum and its dependence on the motion.

use std::f64::consts::PI;

use sts_dataset::Dataset;

use super::{Binned, GroupComparison, GroupWaves, Line};
use sts_analysis::GroupSample;

/// Highest frequency of the residual spectrum, Hz.
pub const SPECTRUM_MAX_HZ: usize = 400;

/// Amplitude spectrum of a window (assumed 1 s long, so bins are 1 Hz apart) at 0..=400 Hz,
/// by the Goertzel recurrence (only the bins needed).
pub fn amplitude_spectrum(y: &[f64]) -> Vec<f64> {
    let n = y.len();
    if n == 0 {
        return vec![0.0; SPECTRUM_MAX_HZ + 1];
    }
    // Bin k of an n-sample window is k cycles per window.
    (0..=SPECTRUM_MAX_HZ)
        .map(|k| {
            let w = 2.0 * PI * k as f64 / n as f64;
            let coeff = 2.0 * w.cos();
            let (mut s1, mut s2) = (0.0, 0.0);
            for &v in y {
                let s0 = v + coeff * s1 - s2;
                s2 = s1;
                s1 = s0;
            }
            let power = s1 * s1 + s2 * s2 - coeff * s1 * s2;
            let scale = if k == 0 { 1.0 } else { 2.0 };
            scale * power.max(0.0).sqrt() / n as f64
        })
        .collect()
}

/// The strongest residual lines that are not harmonics of their group's command frequency
/// (nor DC), averaged over groups: bins within 1 Hz of a harmonic are left out per group.
pub fn other_lines(groups: &[GroupComparison], spectra: &[Vec<f64>], _sample_rate_hz: f64, count: usize) -> Vec<Line> {
    let bins = SPECTRUM_MAX_HZ + 1;
    let mut sum = vec![0.0; bins];
    let mut used = vec![0usize; bins];
    for (g, spec) in groups.iter().zip(spectra) {
        for (k, &a) in spec.iter().enumerate().take(bins).skip(1) {
            let order = k as f64 / g.freq_hz;
            let near_harmonic = (order - order.round()).abs() * g.freq_hz <= 1.0 && order.round() >= 1.0;
            if !near_harmonic {
                sum[k] += a;
                used[k] += 1;
            }
        }
    }
    let mean: Vec<f64> = sum.iter().zip(&used).map(|(s, &u)| if u > 0 { s / u as f64 } else { 0.0 }).collect();
    // Local maxima, strongest first.
    let mut peaks: Vec<(usize, f64)> = (1..bins - 1)
        .filter(|&k| mean[k] > 0.0 && mean[k] >= mean[k - 1] && mean[k] >= mean[k + 1])
        .map(|k| (k, mean[k]))
        .collect();
    peaks.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    peaks.truncate(count);
    peaks.into_iter().map(|(k, a)| Line { freq_hz: k as f64, amp_um: a }).collect()
}

fn bin_index(x: f64, lo: f64, hi: f64, bins: usize) -> Option<usize> {
    if !x.is_finite() || hi <= lo {
        return None;
    }
    let f = ((x - lo) / (hi - lo) * bins as f64).floor();
    if f < 0.0 {
        Some(0)
    } else {
        Some((f as usize).min(bins - 1))
    }
}

struct Acc {
    sq: Vec<f64>,
    sum: Vec<f64>,
    n: Vec<usize>,
}

impl Acc {
    fn new(bins: usize) -> Self {
        Self { sq: vec![0.0; bins], sum: vec![0.0; bins], n: vec![0; bins] }
    }
    fn add(&mut self, bin: Option<usize>, r: f64) {
        if let Some(b) = bin {
            self.sq[b] += r * r;
            self.sum[b] += r;
            self.n[b] += 1;
        }
    }
    fn finish(self, signal: &str, lo: f64, hi: f64) -> Binned {
        let bins = self.n.len();
        let width = (hi - lo) / bins as f64;
        Binned {
            signal: signal.to_string(),
            centres: (0..bins).map(|b| lo + (b as f64 + 0.5) * width).collect(),
            rms_um: self
                .sq
                .iter()
                .zip(&self.n)
                .map(|(s, &n)| if n > 0 { (s / n as f64).sqrt() } else { 0.0 })
                .collect(),
            mean_um: self.sum.iter().zip(&self.n).map(|(s, &n)| if n > 0 { s / n as f64 } else { 0.0 }).collect(),
        }
    }
}

/// Residual binned against the command's position, velocity and acceleration (each
/// normalised by its peak `A`, `A w`, `A w^2`, so groups of every size share the axis), and
/// against the X acceleration when the dataset has it.
pub fn binned_residuals(dataset: &Dataset, samples: &[GroupSample], waves: &[GroupWaves], bins: usize) -> Vec<Binned> {
    let mut pos = Acc::new(bins);
    let mut vel = Acc::new(bins);
    let mut acc = Acc::new(bins);
    let mut xacc = Acc::new(bins);
    let mut has_x = false;
    let x_peak = dataset
        .groups
        .iter()
        .filter_map(|g| g.x_acc_mps2.as_ref())
        .flat_map(|v| v.iter().copied())
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(1e-9);
    for (s, w) in samples.iter().zip(waves) {
        let group = &dataset.groups[s.index];
        let start = s.targets.window_start;
        let omega = 2.0 * PI * s.targets.freq_hz;
        for (j, (m, p)) in w.measured_um.iter().zip(&w.predicted_um).enumerate() {
            let k = start + j;
            let r = m - p;
            let theta = omega * group.t_s[k] + s.targets.cmd.phase_rad;
            pos.add(bin_index(theta.sin(), -1.0, 1.0, bins), r);
            vel.add(bin_index(theta.cos(), -1.0, 1.0, bins), r);
            acc.add(bin_index(-theta.sin(), -1.0, 1.0, bins), r);
            if let Some(x) = &group.x_acc_mps2 {
                has_x = true;
                xacc.add(bin_index(x[k], -x_peak, x_peak, bins), r);
            }
        }
    }
    let mut out = vec![
        pos.finish("command position / amplitude", -1.0, 1.0),
        vel.finish("command velocity / peak velocity", -1.0, 1.0),
        acc.finish("command acceleration / peak acceleration", -1.0, 1.0),
    ];
    if has_x {
        out.push(xacc.finish("X acceleration, m/s^2", -x_peak, x_peak));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spectrum_finds_a_line() {
        let y: Vec<f64> = (0..8000).map(|i| 0.2 * (2.0 * PI * 37.0 * i as f64 / 8000.0).sin() + 0.05).collect();
        let s = amplitude_spectrum(&y);
        assert!((s[37] - 0.2).abs() < 1e-9, "{}", s[37]);
        assert!((s[0] - 0.05).abs() < 1e-9);
        assert!(s[36] < 1e-9 && s[100] < 1e-9);
    }
}
