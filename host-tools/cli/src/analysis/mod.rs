//! Turning a dataset into what the twin learns from: per-group features (the firmware's own
//! fixed-point code) and targets (the measured dynamic error's amplitude and phase).

pub mod features;
pub mod sine;
pub mod targets;

use rayon::prelude::*;
use sts_dataset::{Dataset, GroupInfo};
use sts_twin_core::features::{FeatureConfig, FEATURE_COUNT};

use targets::GroupTargets;

/// One group's inputs and targets.
#[derive(Clone, Debug)]
pub struct GroupSample {
    /// Index of the group in the dataset.
    pub index: usize,
    /// The manifest entry.
    pub info: GroupInfo,
    /// Features f1..f12 over the group's first window.
    pub features: [f32; FEATURE_COUNT],
    /// The measured dynamic error over the group's last second.
    pub targets: GroupTargets,
}

/// The feature configuration for a dataset: the firmware's defaults with the dataset's
/// sample rate and, when the manifest states it, its accelerometer scale.
pub fn feature_config_for(dataset: &Dataset, acc_scale_override: Option<f64>) -> FeatureConfig {
    let mut config = FeatureConfig::DEFAULT;
    config.sample_rate_hz = dataset.manifest.sample_rate_hz as f32;
    // 5 s, rounded down to whole 16-sample blocks.
    config.window_samples = ((5.0 * dataset.manifest.sample_rate_hz) as u32 / 16) * 16;
    if let Some(scale) = acc_scale_override.or(dataset.manifest.acc_mps2_per_lsb) {
        config.acc_mps2_per_lsb = scale as f32;
    }
    config
}

/// Features and targets of every group, in dataset order (computed in parallel; the result
/// does not depend on the thread count). Errors name the group's file.
pub fn group_samples(dataset: &Dataset, config: &FeatureConfig) -> anyhow::Result<Vec<GroupSample>> {
    let fs = dataset.manifest.sample_rate_hz;
    dataset
        .manifest
        .groups
        .par_iter()
        .zip(dataset.groups.par_iter())
        .enumerate()
        .map(|(index, (info, group))| {
            let features = features::group_features(group, config).map_err(|e| anyhow::anyhow!("{}: {e}", info.file))?;
            let targets = targets::group_targets(group, fs, info.freq_hz).map_err(|e| anyhow::anyhow!("{}: {e}", info.file))?;
            Ok(GroupSample { index, info: info.clone(), features, targets })
        })
        .collect()
}
