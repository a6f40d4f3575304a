//! Each group of a dataset as the twin learns from it: its features over the feature window
//! (the firmware's own fixed-point code) and its targets over the last second.

use rayon::prelude::*;
use sts_dataset::{Dataset, GroupInfo};
use sts_twin_core::features::{FeatureConfig, FEATURE_COUNT};

use crate::targets::{self, GroupTargets, PHASE_MIN_AMP_UM};
use crate::{features, resample, AnalysisError};

/// Length of the feature window, s (the paper's t0..tn; the firmware's default window).
pub const FEATURE_WINDOW_S: f64 = 5.0;

/// Seconds at the start of each group left out of the feature window by default: each group
/// of the measurement test starts from rest, and its start transient would dominate the peak
/// and shape features, which the firmware never sees in steady motion (docs/model-format.md).
pub const DEFAULT_SKIP_S: f64 = 0.5;

/// One group's inputs and targets.
#[derive(Clone, Debug)]
pub struct GroupSample {
    /// Index of the group in the dataset.
    pub index: usize,
    /// The manifest entry.
    pub info: GroupInfo,
    /// Features f1..f12 over the feature window.
    pub features: [f32; FEATURE_COUNT],
    /// First sample of the feature window.
    pub feature_start: usize,
    /// The measured dynamic error over the group's last second.
    pub targets: GroupTargets,
}

/// Reads the dataset at `dir` for the twin: resampled to the servo rate when recorded at
/// another (said on standard error).
pub fn read_dataset(dir: &std::path::Path) -> Result<Dataset, AnalysisError> {
    let dataset = sts_dataset::read(dir)?;
    if let std::borrow::Cow::Owned(resampled) = resample::to_servo_rate(&dataset) {
        eprintln!(
            "note: {} is sampled at {} Hz; resampled to the co-processor's servo rate, {} Hz",
            dir.display(),
            dataset.manifest.sample_rate_hz,
            f64::from(sts_twin_core::SERVO_RATE_HZ)
        );
        return Ok(resampled);
    }
    Ok(dataset)
}

/// The feature configuration for a dataset: the firmware's defaults with the dataset's
/// sample rate and, when the manifest states it, its accelerometer scale.
pub fn feature_config_for(dataset: &Dataset, acc_scale_override: Option<f64>) -> FeatureConfig {
    let mut config = FeatureConfig::DEFAULT;
    config.sample_rate_hz = dataset.manifest.sample_rate_hz as f32;
    // 5 s, rounded down to whole 16-sample blocks.
    config.window_samples = ((FEATURE_WINDOW_S * dataset.manifest.sample_rate_hz) as u32 / 16) * 16;
    if let Some(scale) = acc_scale_override.or(dataset.manifest.acc_mps2_per_lsb) {
        config.acc_mps2_per_lsb = scale as f32;
    }
    config
}

/// First sample of a group's feature window: `skip_s` into the group, moved earlier when the
/// group is too short for the skip and the window (never before the group's start).
pub fn feature_start(group_len: usize, config: &FeatureConfig, sample_rate_hz: f64, skip_s: f64) -> usize {
    let skip = (skip_s.max(0.0) * sample_rate_hz).round() as usize;
    skip.min(group_len.saturating_sub(config.window_samples as usize))
}

/// Features and targets of every group with the default skip [`DEFAULT_SKIP_S`] (see
/// [`group_samples_skipping`]).
pub fn group_samples(dataset: &Dataset, config: &FeatureConfig) -> Result<Vec<GroupSample>, AnalysisError> {
    group_samples_skipping(dataset, config, DEFAULT_SKIP_S)
}

/// Features (over the window starting `skip_s` into each group, see [`feature_start`]) and
/// targets (over each group's last second) of every group, in dataset order, computed in
/// parallel; the result does not depend on the thread count. Errors name the group's file.
pub fn group_samples_skipping(
    dataset: &Dataset,
    config: &FeatureConfig,
    skip_s: f64,
) -> Result<Vec<GroupSample>, AnalysisError> {
    let fs = dataset.manifest.sample_rate_hz;
    if fs != f64::from(sts_twin_core::SERVO_RATE_HZ) {
        // Features per sample and terms per tick at another rate would not be what the board
        // computes: the frequencies it reads would be off by the ratio.
        return Err(AnalysisError::SampleRate { sample_rate_hz: fs });
    }
    dataset
        .manifest
        .groups
        .par_iter()
        .zip(dataset.groups.par_iter())
        .enumerate()
        .map(|(index, (info, group))| {
            let start = feature_start(group.len(), config, fs, skip_s);
            let features = features::group_features_from(group, config, start)
                .map_err(|error| AnalysisError::Features { file: info.file.clone(), error })?;
            let targets = targets::group_targets(group, fs, info.freq_hz)
                .map_err(|error| AnalysisError::Targets { file: info.file.clone(), error })?;
            Ok(GroupSample { index, info: info.clone(), features, feature_start: start, targets })
        })
        .collect::<Result<Vec<_>, AnalysisError>>()
        .map(|mut samples| {
            unwrap_phases(&mut samples, PHASE_MIN_AMP_UM);
            samples
        })
}

/// Puts the measured phases on one branch: the cut (at +-180 degrees as measured) moves into
/// the widest gap between the phases of the groups whose amplitude is at least `min_amp_um`,
/// on the side that moves fewer of them by 360 degrees. Otherwise an error nearly opposite
/// to the command (a probe that reads a few percent short, say) splits into phases near +180
/// and near -180, which no smooth formula fits. Nothing changes when the cut already lies in
/// the widest gap.
pub fn unwrap_phases(samples: &mut [GroupSample], min_amp_um: f64) {
    let phases: Vec<f64> =
        samples.iter().filter(|s| s.targets.de_amp_um >= min_amp_um).map(|s| s.targets.de_phase_deg).collect();
    if let Some(branch) = Branch::of(phases) {
        for s in samples.iter_mut() {
            s.targets.de_phase_deg = branch.put(s.targets.de_phase_deg);
        }
    }
}

/// A branch of the phase other than (-180, 180]: phases beyond `cut_deg` on the side
/// `shift_above` move by 360 degrees.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Branch {
    cut_deg: f64,
    shift_above: bool,
}

impl Branch {
    /// The branch for `phases` (in (-180, 180]); `None` when the usual one serves.
    fn of(mut phases: Vec<f64>) -> Option<Branch> {
        if phases.len() < 2 {
            return None;
        }
        phases.sort_by(f64::total_cmp);
        // The gap across +-180 first: on a tie it wins and nothing moves.
        let across = phases[0] + 360.0 - phases[phases.len() - 1];
        let (mut widest, mut cut_deg) = (across, None);
        for pair in phases.windows(2) {
            if pair[1] - pair[0] > widest {
                widest = pair[1] - pair[0];
                cut_deg = Some(0.5 * (pair[0] + pair[1]));
            }
        }
        let cut_deg = cut_deg?;
        let above = phases.iter().filter(|&&p| p > cut_deg).count();
        Some(Branch { cut_deg, shift_above: above <= phases.len() - above })
    }

    fn put(self, phase_deg: f64) -> f64 {
        if self.shift_above && phase_deg > self.cut_deg {
            phase_deg - 360.0
        } else if !self.shift_above && phase_deg < self.cut_deg {
            phase_deg + 360.0
        } else {
            phase_deg
        }
    }
}

/// The training table as CSV: one row per group with its file, command, features f1..f12
/// (labels as in the formulas) and targets, for inspection or `sts-twin regress`.
pub fn training_table_csv(samples: &[GroupSample]) -> String {
    use std::fmt::Write as _;
    let mut out = String::from("file,freq_hz,amp_um");
    for label in sts_twin_core::features::FEATURE_LABELS {
        out.push(',');
        out.push_str(label);
    }
    out.push_str(",de_amp_um,de_phase_deg\n");
    for s in samples {
        let _ = write!(out, "{},{},{}", s.info.file, s.info.freq_hz, s.info.amp_um);
        for f in s.features {
            let _ = write!(out, ",{f}");
        }
        let _ = writeln!(out, ",{},{}", s.targets.de_amp_um, s.targets.de_phase_deg);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::Branch;

    #[test]
    fn phases_around_180_degrees_stay_together() {
        // An error nearly opposite to the command: 170..180 and -180..-165, plus a few
        // groups near -120. The widest gap is between -120 and 170 degrees.
        let phases = vec![171.0, 178.0, -179.0, -172.0, -166.0, -125.0, -118.0];
        let branch = Branch::of(phases.clone()).expect("a new branch");
        let put: Vec<f64> = phases.iter().map(|&p| branch.put(p)).collect();
        // The two above the cut move down (fewer than the five below).
        assert_eq!(put, vec![-189.0, -182.0, -179.0, -172.0, -166.0, -125.0, -118.0]);
        // Spread around 0: the usual branch, nothing moves.
        assert_eq!(Branch::of(vec![-40.0, -10.0, 5.0, 60.0]), None);
        // A lone phase: nothing to keep together.
        assert_eq!(Branch::of(vec![179.0]), None);
    }
}
