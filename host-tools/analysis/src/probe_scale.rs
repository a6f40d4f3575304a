//! The capacitance probe's scale, read where the servo follows the command to a small fraction
//! of a percent: the slowest groups of the test. There the error a scale error adds, `(g - 1)`
//! times the motion, in phase with it and the same fraction at every stroke, stands far above
//! the machine's own dynamic error (which grows with the frequency squared from nothing).

use sts_dataset::{Dataset, GroupData, GroupInfo};

/// One slowest group's reading.
#[derive(Clone, Debug, PartialEq)]
pub struct SlowGroup {
    /// Index of the group in the dataset.
    pub index: usize,
    /// Command amplitude, um.
    pub amp_um: f64,
    /// In-phase ratio of the probe's reading to the command over the group's second half.
    pub ratio: f64,
}

/// The probe's scale on the slowest groups.
#[derive(Clone, Debug, PartialEq)]
pub struct ProbeScale {
    /// The pooled in-phase ratio of probe to command (1 = a correct probe).
    pub gain: f64,
    /// The slowest command frequency of the test, Hz.
    pub slowest_freq_hz: f64,
    /// Each slowest group's own ratio.
    pub groups: Vec<SlowGroup>,
}

/// A scale error of the probe smaller than this is left alone: `fit --effect sensor-gain`
/// does not correct it and `diagnose` does not name it. The machine's own in-phase error at
/// 1 Hz is about 0.03% of the motion, and the part of a friction's that is the same at every
/// stroke at most 0.3%.
pub const SCALE_TOLERANCE: f64 = 0.005;

/// How many standard errors the scale error must stand from zero to be named: the groups'
/// spread about the line is not all noise (a force ripple's, position-periodic, once gave
/// 0.7% at 3.0 of them).
pub const SCALE_MIN_T: f64 = 5.0;

/// The probe's scale from a dataset's groups at its lowest command frequency.
pub fn probe_scale(dataset: &Dataset) -> Option<ProbeScale> {
    probe_scale_of(dataset.groups.iter().zip(&dataset.manifest.groups))
}

/// The probe's scale from the groups at the lowest command frequency among `groups` (indices
/// count in their order), over each group's second half (after the start's transient);
/// `None` without motion there.
pub fn probe_scale_of<'a>(groups: impl IntoIterator<Item = (&'a GroupData, &'a GroupInfo)>) -> Option<ProbeScale> {
    let groups: Vec<(&GroupData, &GroupInfo)> = groups.into_iter().collect();
    let slowest_freq_hz = groups.iter().map(|(_, info)| info.freq_hz).fold(f64::INFINITY, f64::min);
    let (mut num, mut den) = (0.0, 0.0);
    let mut slow = Vec::new();
    for (index, (g, info)) in groups.iter().enumerate() {
        if info.freq_hz > slowest_freq_hz {
            continue;
        }
        let half = &g.z_cmd_um[g.len() / 2..];
        let mean = half.iter().sum::<f64>() / half.len().max(1) as f64;
        let (mut n, mut d) = (0.0, 0.0);
        for (c, t) in half.iter().zip(&g.z_tcp_um[g.len() / 2..]) {
            n += (c - mean) * t;
            d += (c - mean) * (c - mean);
        }
        num += n;
        den += d;
        if d > 0.0 && (n / d).is_finite() {
            slow.push(SlowGroup { index, amp_um: info.amp_um, ratio: n / d });
        }
    }
    (den > 0.0 && (num / den).is_finite()).then_some(ProbeScale { gain: num / den, slowest_freq_hz, groups: slow })
}

/// The slowest groups' ratios as `1 + constant + per_inverse_amp / A` (least squares
/// weighted by `A^2`): a scale error is the constant, the same at every stroke; what the
/// machine itself does there (a friction's steps, of about the same size at every stroke)
/// falls with the stroke.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScaleSplit {
    /// The part of the ratio that is the same at every stroke (the scale error).
    pub constant: f64,
    /// Its standard error from the spread of the groups about the line.
    pub constant_se: f64,
    /// The part that falls with the stroke, um.
    pub per_inverse_amp_um: f64,
}

impl ProbeScale {
    /// The split of the ratios, with at least three groups of two strokes or more.
    pub fn split(&self) -> Option<ScaleSplit> {
        let n = self.groups.len();
        if n < 3 {
            return None;
        }
        // Weighted by the stroke squared: a disturbance of a given size (a ripple's, the
        // noise's) moves a group's ratio by that size over its stroke.
        let x: Vec<f64> = self.groups.iter().map(|g| 1.0 / g.amp_um).collect();
        let y: Vec<f64> = self.groups.iter().map(|g| g.ratio - 1.0).collect();
        let w: Vec<f64> = self.groups.iter().map(|g| g.amp_um * g.amp_um).collect();
        let sum_w: f64 = w.iter().sum();
        let mean_x = w.iter().zip(&x).map(|(w, x)| w * x).sum::<f64>() / sum_w;
        let mean_y = w.iter().zip(&y).map(|(w, y)| w * y).sum::<f64>() / sum_w;
        let sxx: f64 = w.iter().zip(&x).map(|(w, v)| w * (v - mean_x).powi(2)).sum();
        if sxx.is_nan() || sxx <= 0.0 {
            return None;
        }
        let sxy: f64 = w.iter().zip(x.iter().zip(&y)).map(|(w, (a, b))| w * (a - mean_x) * (b - mean_y)).sum();
        let slope = sxy / sxx;
        let constant = mean_y - slope * mean_x;
        let sse: f64 = w.iter().zip(x.iter().zip(&y)).map(|(w, (a, b))| w * (b - constant - slope * a).powi(2)).sum();
        let sigma2 = sse / (n - 2).max(1) as f64;
        let constant_se = (sigma2 * (1.0 / sum_w + mean_x * mean_x / sxx)).sqrt();
        Some(ScaleSplit { constant, constant_se, per_inverse_amp_um: slope })
    }
}

impl ProbeScale {
    /// The scale error when the ratios show one: the part of them that is the same at every
    /// stroke is at least [`SCALE_TOLERANCE`] and [`SCALE_MIN_T`] standard errors from zero.
    /// (`diagnose` also asks it to hold a share of the error there: a friction's in-phase
    /// part can fit the same line.)
    pub fn scale_error(&self) -> Option<ScaleSplit> {
        self.split().filter(|s| s.constant.abs() >= SCALE_TOLERANCE && s.constant.abs() >= SCALE_MIN_T * s.constant_se)
    }

    /// The gain to divide the readings by: one plus the part of the ratios that is the same at
    /// every stroke, or the pooled ratio with too few strokes to split.
    pub fn correction(&self) -> f64 {
        self.split().map_or(self.gain, |s| 1.0 + s.constant)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Groups at 1 and 20 Hz whose probe reads `1 + scale + machine_um / A` of a 1 Hz
    /// command of stroke A (the 20 Hz ones read nonsense: only the slowest count).
    fn groups(scale: f64, machine_um: f64) -> Vec<(GroupData, GroupInfo)> {
        let fs = 1000.0;
        [1.0, 20.0]
            .iter()
            .flat_map(|&freq_hz| {
                (1..=6).map(move |a| {
                    let amp_um = a as f64 * 2.0;
                    let mut g = GroupData::with_len(2000);
                    for k in 0..2000 {
                        let t = k as f64 / fs;
                        let z = amp_um * (std::f64::consts::TAU * freq_hz * t).sin();
                        g.t_s[k] = t;
                        g.z_cmd_um[k] = z;
                        g.z_tcp_um[k] = if freq_hz > 1.0 { 3.0 * z } else { z * (1.0 + scale + machine_um / amp_um) };
                    }
                    let info = GroupInfo { file: String::new(), freq_hz, amp_um, start_s: 0.0 };
                    (g, info)
                })
            })
            .collect()
    }

    fn scale_of(groups: &[(GroupData, GroupInfo)]) -> ProbeScale {
        probe_scale_of(groups.iter().map(|(g, i)| (g, i))).expect("motion")
    }

    #[test]
    fn the_scale_is_the_part_of_the_ratio_that_every_stroke_shares() {
        let scale = scale_of(&groups(-0.06, 0.02));
        assert_eq!(scale.slowest_freq_hz, 1.0);
        assert_eq!(scale.groups.len(), 6);
        let split = scale.scale_error().expect("a 6% scale error");
        assert!((split.constant + 0.06).abs() < 1e-9, "{split:?}");
        assert!((split.per_inverse_amp_um - 0.02).abs() < 1e-9, "{split:?}");
        assert!((scale.correction() - 0.94).abs() < 1e-9);
        // The pooled ratio mixes in the machine's part.
        assert!(scale.gain > 0.94);
    }

    #[test]
    fn a_machine_error_that_falls_with_the_stroke_is_not_a_scale() {
        // A friction-like 20 nm at every stroke, 0.3% in common: not a scale error.
        let scale = scale_of(&groups(0.003, 0.02));
        assert!(scale.split().is_some());
        assert!(scale.scale_error().is_none());
    }
}
