//! The capacitance probe's scale, read where the servo follows the command closest: the
//! slowest groups of the test. There the error a scale error adds, `(g - 1)` times the motion,
//! in phase with it and the same fraction at every stroke and every frequency, stands beside
//! the machine's own in-phase error, which grows with the frequency squared from nothing (the
//! loop's and the structure's answer to the acceleration). Where the test's second-slowest
//! frequency is near enough to the slowest for that law to hold ([`MAX_FREQ_RATIO`]), the
//! ratios of both are extrapolated to zero frequency: a test that starts at 10 Hz sees the
//! default machine's own 3% there, which is no scale error.

use sts_dataset::{Dataset, GroupData, GroupInfo};
use sts_numerics::lsq::least_squares;

/// One slow group's reading.
#[derive(Clone, Debug, PartialEq)]
pub struct SlowGroup {
    /// Index of the group in the dataset.
    pub index: usize,
    /// Command frequency, Hz.
    pub freq_hz: f64,
    /// Command amplitude, um.
    pub amp_um: f64,
    /// In-phase ratio of the probe's reading to the command over the group's second half.
    pub ratio: f64,
}

/// The probe's scale on the slowest groups.
#[derive(Clone, Debug, PartialEq)]
pub struct ProbeScale {
    /// The pooled in-phase ratio of probe to command at the slowest frequency (1 = a correct
    /// probe).
    pub gain: f64,
    /// The slowest command frequency of the test, Hz.
    pub slowest_freq_hz: f64,
    /// The second-slowest, Hz, where it is within [`MAX_FREQ_RATIO`] of the slowest.
    pub next_freq_hz: Option<f64>,
    /// Each slow group's own ratio (those at both frequencies).
    pub groups: Vec<SlowGroup>,
}

/// The second-slowest frequency joins the reading up to this multiple of the slowest: the
/// machine's in-phase error follows the frequency squared well below the loop's bandwidth
/// (1 and 5 Hz on the paper's grid, 10 and 20 Hz on a test from 10 Hz), not across decades.
pub const MAX_FREQ_RATIO: f64 = 5.0;

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

/// The probe's scale from the groups at the lowest command frequency among `groups` and at the
/// next one up to [`MAX_FREQ_RATIO`] times it (indices count in their order), over each
/// group's second half (after the start's transient); `None` without motion at the slowest.
pub fn probe_scale_of<'a>(groups: impl IntoIterator<Item = (&'a GroupData, &'a GroupInfo)>) -> Option<ProbeScale> {
    let groups: Vec<(&GroupData, &GroupInfo)> = groups.into_iter().collect();
    let slowest_freq_hz = groups.iter().map(|(_, info)| info.freq_hz).fold(f64::INFINITY, f64::min);
    let next_freq_hz = groups
        .iter()
        .map(|(_, info)| info.freq_hz)
        .filter(|&f| f > slowest_freq_hz && f <= MAX_FREQ_RATIO * slowest_freq_hz)
        .fold(None, |lowest: Option<f64>, f| Some(lowest.map_or(f, |l| l.min(f))));
    let (mut num, mut den) = (0.0, 0.0);
    let mut slow = Vec::new();
    for (index, (g, info)) in groups.iter().enumerate() {
        let slowest = info.freq_hz <= slowest_freq_hz;
        if !slowest && Some(info.freq_hz) != next_freq_hz {
            continue;
        }
        let half = &g.z_cmd_um[g.len() / 2..];
        let mean = half.iter().sum::<f64>() / half.len().max(1) as f64;
        let (mut n, mut d) = (0.0, 0.0);
        for (c, t) in half.iter().zip(&g.z_tcp_um[g.len() / 2..]) {
            n += (c - mean) * t;
            d += (c - mean) * (c - mean);
        }
        if slowest {
            num += n;
            den += d;
        }
        if d > 0.0 && (n / d).is_finite() {
            slow.push(SlowGroup { index, freq_hz: info.freq_hz, amp_um: info.amp_um, ratio: n / d });
        }
    }
    // The second frequency serves only with strokes to split at both.
    let at = |f: f64| slow.iter().filter(|g| g.freq_hz == f).count();
    let next_freq_hz = next_freq_hz.filter(|&f| at(f) >= 2 && at(slowest_freq_hz) >= 2);
    slow.retain(|g| g.freq_hz == slowest_freq_hz || Some(g.freq_hz) == next_freq_hz);
    (den > 0.0 && (num / den).is_finite()).then_some(ProbeScale {
        gain: num / den,
        slowest_freq_hz,
        next_freq_hz,
        groups: slow,
    })
}

/// The slow groups' ratios as `1 + constant + per_inverse_amp / A + per_freq2 f^2` (least
/// squares weighted by `A^2`; the last term only with two frequencies): a scale error is the
/// constant, the same at every stroke and frequency; what the machine itself does there
/// falls with the stroke (a friction's steps, of about the same size at every stroke) or grows
/// with the frequency squared (its dynamics).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScaleSplit {
    /// The part of the ratio that is the same at every stroke and frequency (the scale error).
    pub constant: f64,
    /// Its standard error from the spread of the groups about the fit.
    pub constant_se: f64,
    /// The part that falls with the stroke, um.
    pub per_inverse_amp_um: f64,
    /// The part that grows with the frequency squared, 1/Hz^2 (0 with one frequency).
    pub per_freq2_per_hz2: f64,
}

impl ProbeScale {
    /// The groups at the slowest frequency.
    pub fn slowest_groups(&self) -> impl Iterator<Item = &SlowGroup> {
        self.groups.iter().filter(|g| g.freq_hz == self.slowest_freq_hz)
    }

    /// The split of the ratios, with at least three groups of two strokes or more (and two
    /// more with a second frequency).
    pub fn split(&self) -> Option<ScaleSplit> {
        let n = self.groups.len();
        let columns = if self.next_freq_hz.is_some() { 3 } else { 2 };
        if n < columns + 1 {
            return None;
        }
        // Weighted by the stroke squared: a disturbance of a given size (a ripple's, the
        // noise's) moves a group's ratio by that size over its stroke. Rows scaled by the
        // stroke: `A (ratio - 1) ~ A c + d + A f^2 e`.
        let row = |g: &SlowGroup| [g.amp_um, 1.0, g.amp_um * g.freq_hz * g.freq_hz];
        let y: Vec<f64> = self.groups.iter().map(|g| g.amp_um * (g.ratio - 1.0)).collect();
        let fit = if columns == 3 {
            least_squares(&self.groups.iter().map(row).collect::<Vec<_>>(), &y)?
        } else {
            let two: Vec<[f64; 2]> = self.groups.iter().map(|g| [row(g)[0], row(g)[1]]).collect();
            least_squares(&two, &y)?
        };
        let b = &fit.coefficients;
        Some(ScaleSplit {
            constant: b[0],
            constant_se: fit.standard_errors[0],
            per_inverse_amp_um: b[1],
            per_freq2_per_hz2: if columns == 3 { b[2] } else { 0.0 },
        })
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

    /// Six strokes (2-12 um) at each of `freqs_hz`, sampled at `fs` Hz, whose probe reads
    /// `ratio(freq_hz, amp_um)` times the command.
    fn groups_reading(fs: f64, freqs_hz: &[f64], ratio: impl Fn(f64, f64) -> f64) -> Vec<(GroupData, GroupInfo)> {
        let ratio = &ratio;
        freqs_hz
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
                        g.z_tcp_um[k] = z * ratio(freq_hz, amp_um);
                    }
                    (g, GroupInfo::new("", freq_hz, amp_um, 0.0))
                })
            })
            .collect()
    }

    /// Groups at 1 and 20 Hz whose probe reads `1 + scale + machine_um / A` of a 1 Hz
    /// command of stroke A (the 20 Hz ones read nonsense: only the slowest count).
    fn groups(scale: f64, machine_um: f64) -> Vec<(GroupData, GroupInfo)> {
        groups_reading(
            1000.0,
            &[1.0, 20.0],
            |freq_hz, amp_um| {
                if freq_hz > 1.0 {
                    3.0
                } else {
                    1.0 + scale + machine_um / amp_um
                }
            },
        )
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

    /// Groups at 10, 20 and 30 Hz whose probe reads `1 + scale + c f^2` of the command: the
    /// machine's own in-phase error, 3% at 10 Hz, grows with the frequency squared.
    fn groups_from_10_hz(scale: f64) -> Vec<(GroupData, GroupInfo)> {
        groups_reading(4000.0, &[10.0, 20.0, 30.0], |freq_hz, _| 1.0 + scale + 0.03 * (freq_hz / 10.0f64).powi(2))
    }

    #[test]
    fn the_machines_own_error_at_a_test_from_10_hz_is_no_scale() {
        let scale = scale_of(&groups_from_10_hz(0.0));
        assert_eq!((scale.slowest_freq_hz, scale.next_freq_hz), (10.0, Some(20.0)));
        assert_eq!(scale.groups.len(), 12, "the 30 Hz groups stay out");
        // The slowest groups alone read 3%, far above the tolerance.
        assert!((scale.gain - 1.03).abs() < 1e-3, "{scale:?}");
        let split = scale.split().expect("two frequencies, six strokes");
        assert!(split.constant.abs() < 1e-6, "{split:?}");
        assert!(scale.scale_error().is_none());
        // A 4% scale error beside it is read as 4%.
        let scale = scale_of(&groups_from_10_hz(-0.04));
        let split = scale.scale_error().expect("a 4% scale error");
        assert!((split.constant + 0.04).abs() < 1e-6, "{split:?}");
        assert!((scale.correction() - 0.96).abs() < 1e-6);
    }

    #[test]
    fn a_machine_error_that_falls_with_the_stroke_is_not_a_scale() {
        // A friction-like 20 nm at every stroke, 0.3% in common: not a scale error.
        let scale = scale_of(&groups(0.003, 0.02));
        assert!(scale.split().is_some());
        assert!(scale.scale_error().is_none());
    }
}
