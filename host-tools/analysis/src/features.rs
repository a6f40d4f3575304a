//! The 12 accelerometer features of a group, computed by the firmware's own fixed-point code
//! (`sts_twin_core::features`), so that training sees exactly what the firmware will see.

use sts_dataset::GroupData;
use sts_twin_core::features::{DefaultFeatureExtractor, FeatureConfig, FEATURE_COUNT};

/// Quantises an acceleration to the ADC code the firmware would read (round to nearest,
/// clamp to the 16-bit range; NaN reads as 0).
pub fn acc_code(acc_mps2: f64, acc_mps2_per_lsb: f64) -> i16 {
    let code = (acc_mps2 / acc_mps2_per_lsb).round();
    if code.is_nan() {
        0
    } else {
        code.clamp(i16::MIN as f64, i16::MAX as f64) as i16
    }
}

/// Why features could not be computed.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FeatureExtractionError {
    /// The group (after the skipped start) is shorter than the feature window.
    #[error(
        "the group has {samples} samples after the skipped start, fewer than the feature window of {window} samples"
    )]
    TooShort {
        /// Samples in the group after the skipped start.
        samples: usize,
        /// The window.
        window: usize,
    },
    /// The configuration is not valid for the firmware's feature extractor.
    #[error("invalid feature configuration: {0:?}")]
    Config(sts_twin_core::features::FeatureError),
}

/// Features over the group's first `config.window_samples` samples (the paper's t0..tn).
pub fn group_features(
    group: &GroupData,
    config: &FeatureConfig,
) -> Result<[f32; FEATURE_COUNT], FeatureExtractionError> {
    group_features_from(group, config, 0)
}

/// Features over the `config.window_samples` samples starting at sample `start`. The
/// extractor is fed from the group's first sample on, so its sliding state (block alignment,
/// DC references) is the one the firmware has after running through the same signal.
pub fn group_features_from(
    group: &GroupData,
    config: &FeatureConfig,
    start: usize,
) -> Result<[f32; FEATURE_COUNT], FeatureExtractionError> {
    let window = config.window_samples as usize;
    if group.acc_mps2.len() < start.saturating_add(window) {
        return Err(FeatureExtractionError::TooShort { samples: group.acc_mps2.len().saturating_sub(start), window });
    }
    let mut extractor = Box::new(DefaultFeatureExtractor::new(*config).map_err(FeatureExtractionError::Config)?);
    let scale = f64::from(config.acc_mps2_per_lsb);
    for &acc in &group.acc_mps2[..start + window] {
        extractor.push(acc_code(acc, scale));
    }
    Ok(extractor.features().as_array())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantisation_rounds_and_clamps() {
        assert_eq!(acc_code(0.00026, 1e-4), 3);
        assert_eq!(acc_code(-1e9, 1e-4), i16::MIN);
        assert_eq!(acc_code(f64::NAN, 1e-4), 0);
    }

    #[test]
    fn a_40_hz_group_reads_40_hz() {
        let n = 48_000;
        let mut g = GroupData::with_len(n);
        for i in 0..n {
            let t = i as f64 / 8000.0;
            g.acc_mps2[i] = 0.3 * (2.0 * std::f64::consts::PI * 40.0 * t).sin();
        }
        let f = group_features(&g, &FeatureConfig::DEFAULT).unwrap();
        assert!((f[0] - 40.0).abs() < 0.05, "f1 {}", f[0]);
        assert!((f[4] - 0.3 / 2f32.sqrt()).abs() < 1e-3, "f5 {}", f[4]);
        assert!(matches!(
            group_features(&GroupData::with_len(10), &FeatureConfig::DEFAULT),
            Err(FeatureExtractionError::TooShort { .. })
        ));
    }
}
