//! Does the dynamic error repeat from one command period to the next?
//!
//! A machine driven by a periodic command settles into a periodic error: whatever of it does
//! not repeat is measurement noise, or motion the command does not cause (a limit cycle such
//! as friction hunting, vibration from outside). No twin fed with the command can predict that
//! part, so it bounds the waveform error any model can reach. The estimate needs nothing but
//! the dataset's columns: the error against itself one period later,
//! `d(t) = e(t + T) - e(t)`, whose RMS is `sqrt(2)` times the non-repeating part's for
//! independent noise.

use rayon::prelude::*;
use serde::Serialize;
use sts_dataset::{Dataset, GroupData};

use crate::samples::GroupSample;

/// A group's non-repeating part is flagged when it exceeds this factor times the floor (the
/// lower quartile of all groups: the measurement's own noise where the machine repeats
/// itself, robust to up to three quarters of the groups not repeating).
pub const NOT_REPEATING_RATIO: f64 = 2.0;

/// Nor below this, um: on noiseless (simulated) data the floor is rounding, and a nanometre
/// that does not repeat is nothing a machinist acts on.
pub const NOT_REPEATING_MIN_UM: f64 = 0.002;

/// Periods tried for a lag that falls on a whole number of samples.
const MAX_PERIODS: usize = 8;

/// RMS of the part of `error_um` (sampled at `sample_rate_hz`, steady motion of a command at
/// `freq_hz`) that does not repeat from one period to the next, um. The lag is the number of
/// whole periods (1 to 8) closest to a whole number of samples; a fractional remainder is
/// interpolated linearly and its smoothing of white noise taken out. `None` when the series
/// is shorter than twice the lag or the frequency is unusable.
///
/// ```
/// # use sts_analysis::repeat::non_repeating_rms_um;
/// // A 10 Hz error at 8 kHz repeats exactly: nothing is left.
/// let e: Vec<f64> = (0..8000).map(|k| (std::f64::consts::TAU * 10.0 * k as f64 / 8000.0).sin()).collect();
/// assert!(non_repeating_rms_um(&e, 10.0, 8000.0).unwrap() < 1e-12);
/// ```
pub fn non_repeating_rms_um(error_um: &[f64], freq_hz: f64, sample_rate_hz: f64) -> Option<f64> {
    if !(freq_hz.is_finite() && freq_hz > 0.0 && sample_rate_hz.is_finite() && sample_rate_hz > 0.0) {
        return None;
    }
    let period = sample_rate_hz / freq_hz;
    // The number of periods whose length is closest to whole samples (the fewest on a tie).
    let lag = (1..=MAX_PERIODS)
        .map(|m| m as f64 * period)
        .min_by(|a, b| (a - a.round()).abs().total_cmp(&(b - b.round()).abs()))?;
    let whole = lag.floor() as usize;
    let frac = lag - lag.floor();
    let (whole, frac) = if frac < 1e-6 {
        (whole, 0.0)
    } else if frac > 1.0 - 1e-6 {
        (whole + 1, 0.0)
    } else {
        (whole, frac)
    };
    let span = whole + usize::from(frac > 0.0);
    if whole == 0 || error_um.len() < 2 * span {
        return None;
    }
    let n = error_um.len() - span;
    let sum_sq: f64 = (0..n)
        .map(|k| {
            let later =
                (1.0 - frac) * error_um[k + whole] + if frac > 0.0 { frac * error_um[k + whole + 1] } else { 0.0 };
            (later - error_um[k]).powi(2)
        })
        .sum();
    // Variance of the difference per unit of white-noise variance.
    let noise_gain = 1.0 + (1.0 - frac).powi(2) + frac.powi(2);
    Some((sum_sq / n as f64 / noise_gain).sqrt())
}

/// [`non_repeating_rms_um`] of a group's dynamic error (`z_tcp_um - z_cmd_um`) in steady
/// motion: from its feature window's start to its end. `less_um`, where given, is a series
/// over the whole group taken out of the error first (a twin's terms that do not repeat with
/// the command, such as a drift, whose own change would otherwise count as the floor).
pub fn group_non_repeating_um(
    group: &GroupData,
    sample: &GroupSample,
    sample_rate_hz: f64,
    less_um: Option<&[f64]>,
) -> Option<f64> {
    let error_um: Vec<f64> = (sample.feature_start..group.len())
        .map(|k| group.z_tcp_um[k] - group.z_cmd_um[k] - less_um.map_or(0.0, |l| l[k]))
        .collect();
    non_repeating_rms_um(&error_um, sample.info.freq_hz, sample_rate_hz)
}

/// The RMS of per-group RMS values (`(file, rms)`, um) over the groups whose files are not in
/// `skip`, um: a twin's error where the machine repeats itself, the groups that do not (a
/// hunting axis) left out. `None` where no group is left out or none is left.
pub fn rms_without<'a>(groups: impl IntoIterator<Item = (&'a str, f64)>, skip: &[String]) -> Option<f64> {
    let (mut sum_sq, mut kept, mut left_out) = (0.0, 0usize, 0usize);
    for (file, rms_um) in groups {
        if skip.iter().any(|s| s == file) {
            left_out += 1;
        } else {
            sum_sq += rms_um * rms_um;
            kept += 1;
        }
    }
    (left_out > 0 && kept > 0).then(|| (sum_sq / kept as f64).sqrt())
}

/// The non-repeating part over a dataset's groups.
#[derive(Clone, Debug, Serialize)]
pub struct Repeatability {
    /// Per group in dataset order: the non-repeating RMS, um (`None`: too short).
    pub group_rms_um: Vec<Option<f64>>,
    /// Its lower quartile over the groups, um: the measurement's floor where the machine
    /// repeats itself (the probe's noise on a good machine).
    pub floor_um: f64,
    /// Positions of the groups whose non-repeating part exceeds [`NOT_REPEATING_RATIO`] x
    /// the floor and [`NOT_REPEATING_MIN_UM`].
    pub not_repeating: Vec<usize>,
}

impl Repeatability {
    /// [`Repeatability::floor_um`], or 0 where no group was long enough to tell.
    pub fn known_floor_um(&self) -> f64 {
        if self.floor_um.is_finite() {
            self.floor_um
        } else {
            0.0
        }
    }

    /// The non-repeating part of each sampled group's dynamic error (`z_tcp_um - z_cmd_um`)
    /// in steady motion, from its feature window's start to its end; positions follow
    /// `samples`.
    pub fn of_samples(dataset: &Dataset, samples: &[GroupSample]) -> Self {
        let fs = dataset.manifest.sample_rate_hz;
        Self::from_groups(
            samples.par_iter().map(|s| group_non_repeating_um(&dataset.groups[s.index], s, fs, None)).collect(),
        )
    }

    /// Summarises per-group values (see [`non_repeating_rms_um`]).
    pub fn from_groups(group_rms_um: Vec<Option<f64>>) -> Self {
        let mut known: Vec<f64> = group_rms_um.iter().flatten().copied().collect();
        known.sort_by(f64::total_cmp);
        // The lower quartile, linearly interpolated between order statistics.
        let floor_um = match known.len() {
            0 => f64::NAN,
            n => {
                let pos = 0.25 * (n - 1) as f64;
                let (lo, frac) = (pos.floor() as usize, pos - pos.floor());
                known[lo] + frac * (known[(lo + 1).min(n - 1)] - known[lo])
            }
        };
        let not_repeating = group_rms_um
            .iter()
            .enumerate()
            .filter(|(_, v)| v.is_some_and(|v| v > NOT_REPEATING_MIN_UM && v > NOT_REPEATING_RATIO * floor_um))
            .map(|(i, _)| i)
            .collect();
        Self { group_rms_um, floor_um, not_repeating }
    }

    /// One paragraph for a person when some groups do not repeat, naming them by frequency and
    /// amplitude (`label(i)` gives group `i`'s `(freq_hz, amp_um)`).
    pub fn describe(&self, label: impl Fn(usize) -> (f64, f64)) -> Option<String> {
        if self.not_repeating.is_empty() {
            return None;
        }
        let places = group_places(&self.not_repeating, label);
        let values: Vec<f64> = self.not_repeating.iter().filter_map(|&i| self.group_rms_um[i]).collect();
        let lo = values.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        Some(format!(
            "the error does not repeat from one period to the next in {} group{} ({}: {} nm RMS, against a floor of {:.1} nm, the lower quartile of all groups): \
             the axis moves by itself there (a limit cycle such as friction hunting where friction falls with velocity, or vibration from outside). \
             No twin driven by the command can predict that part; those groups' waveform error cannot fall below it.",
            self.not_repeating.len(),
            if self.not_repeating.len() == 1 { "" } else { "s" },
            places,
            range_text(format!("{:.1}", lo * 1e3), format!("{:.1}", hi * 1e3)),
            self.floor_um * 1e3
        ))
    }
}

/// Groups named by command frequency for a person: "1 Hz at 7-11 um, 5 Hz at 3 um"
/// (`label(i)` gives group `i`'s `(freq_hz, amp_um)`).
pub fn group_places(groups: &[usize], label: impl Fn(usize) -> (f64, f64)) -> String {
    let mut by_freq: Vec<(f64, f64, f64)> = Vec::new();
    for &i in groups {
        let (freq_hz, amp_um) = label(i);
        match by_freq.iter_mut().find(|(f, _, _)| *f == freq_hz) {
            Some(entry) => {
                entry.1 = entry.1.min(amp_um);
                entry.2 = entry.2.max(amp_um);
            }
            None => by_freq.push((freq_hz, amp_um, amp_um)),
        }
    }
    let places: Vec<String> = by_freq
        .iter()
        .map(|&(f, lo, hi)| if lo == hi { format!("{f} Hz at {lo} um") } else { format!("{f} Hz at {lo}-{hi} um") })
        .collect();
    places.join(", ")
}

/// A range of two values as already formatted, `lo-hi`, or the one value where both read the
/// same (for people: `0.58`, not `0.58-0.58`).
pub fn range_text(lo: String, hi: String) -> String {
    if lo == hi {
        lo
    } else {
        format!("{lo}-{hi}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn the_rms_without_some_groups_leaves_them_out_and_needs_one_left_out_and_one_kept() {
        let groups = [("a.csv", 3.0), ("b.csv", 40.0), ("c.csv", 4.0)];
        let skip = |files: &[&str]| files.iter().map(|f| f.to_string()).collect::<Vec<_>>();
        let rms = rms_without(groups, &skip(&["b.csv"])).expect("one left out");
        assert!((rms - 12.5f64.sqrt()).abs() < 1e-12, "{rms}");
        assert_eq!(rms_without(groups, &skip(&[])), None);
        assert_eq!(rms_without(groups, &skip(&["x.csv"])), None);
        assert_eq!(rms_without(groups, &skip(&["a.csv", "b.csv", "c.csv"])), None);
    }
    use std::f64::consts::TAU;

    fn noise(n: usize, rms: f64, seed: u64) -> Vec<f64> {
        // Uniform noise of the given RMS.
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n).map(|_| rms * 3f64.sqrt() * (2.0 * rng.random::<f64>() - 1.0)).collect()
    }

    #[test]
    fn a_periodic_error_with_noise_leaves_the_noise() {
        // 35 Hz at 8 kHz is 228.57 samples: seven periods are 1600 samples exactly.
        let n = 40_000;
        let w = noise(n, 0.005, 1);
        let e: Vec<f64> = (0..n).map(|k| 3.0 * (TAU * 35.0 * k as f64 / 8000.0).sin() + w[k]).collect();
        let r = non_repeating_rms_um(&e, 35.0, 8000.0).unwrap();
        assert!((r - 0.005).abs() < 0.0002, "{r}");
    }

    #[test]
    fn a_fractional_lag_is_interpolated_without_biasing_the_noise() {
        // 8000 / 33.3 periods: no whole number of samples within 8 periods.
        let n = 40_000;
        let w = noise(n, 0.005, 2);
        let e: Vec<f64> = (0..n).map(|k| 0.5 * (TAU * 33.3 * k as f64 / 8000.0).sin() + w[k]).collect();
        let r = non_repeating_rms_um(&e, 33.3, 8000.0).unwrap();
        // The interpolation's own error on a 0.5 um sine at 33 Hz is far below the noise.
        assert!((r - 0.005).abs() < 0.0003, "{r}");
    }

    #[test]
    fn motion_not_locked_to_the_command_shows() {
        // A 21.7 Hz oscillation beside a 1 Hz command does not repeat with the command.
        let n = 48_000;
        let e: Vec<f64> = (0..n)
            .map(|k| {
                let t = k as f64 / 8000.0;
                5.0 * (TAU * t).sin() + 0.2 * (TAU * 21.7 * t).sin()
            })
            .collect();
        let r = non_repeating_rms_um(&e, 1.0, 8000.0).unwrap();
        assert!(r > 0.1, "{r}");
    }

    #[test]
    fn too_short_or_unusable_series_give_none() {
        assert_eq!(non_repeating_rms_um(&[0.0; 100], 1.0, 8000.0), None);
        assert_eq!(non_repeating_rms_um(&[0.0; 100_000], 0.0, 8000.0), None);
        assert_eq!(non_repeating_rms_um(&[0.0; 100_000], f64::NAN, 8000.0), None);
    }

    #[test]
    fn the_summary_flags_groups_above_twice_the_median_and_names_them() {
        let rms = vec![Some(0.005), Some(0.005), Some(0.004), Some(0.005), None, Some(0.05), Some(0.16)];
        let r = Repeatability::from_groups(rms);
        assert!((r.floor_um - 0.005).abs() < 1e-12);
        assert_eq!(r.not_repeating, vec![5, 6]);
        let text = r.describe(|i| (1.0, i as f64 + 4.0)).unwrap();
        assert!(text.contains("2 groups (1 Hz at 9-10 um: 50.0-160.0 nm RMS, against a floor of 5.0 nm"), "{text}");
        let calm = Repeatability::from_groups(vec![Some(0.005); 4]);
        assert!(calm.not_repeating.is_empty() && calm.describe(|_| (1.0, 1.0)).is_none());
        // Noiseless data: a floor of rounding flags nothing below a nanometre or two.
        let exact = Repeatability::from_groups(vec![Some(0.0), Some(0.0), Some(1e-9), Some(0.0015), Some(0.0)]);
        assert!(exact.not_repeating.is_empty(), "{exact:?}");
    }
}
