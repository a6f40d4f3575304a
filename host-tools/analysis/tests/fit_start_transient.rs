//! The start transient: a group recorded from rest (the measurement test's default) holds a
//! transient in its first instants that dominates the peak-based features. Skipping the
//! default 0.5 s gives the features of steady motion (a group recorded after a lead-in),
//! which is what the firmware computes while machining.

use sts_analysis::features::group_features_from;
use sts_analysis::{feature_config_for, feature_start, DEFAULT_SKIP_S};
use sts_emulator::measure::{simulate_group, MeasureConfig};
use sts_twin_core::features::FEATURE_NAMES;

/// Amplitude-type features that must match steady motion closely (index, name).
const STEADY: [usize; 8] = [1, 2, 3, 4, 7, 8, 9, 11];

#[test]
fn skipping_the_start_gives_the_features_of_steady_motion() {
    let from_rest = MeasureConfig { freqs_hz: vec![20.0, 35.0], amps_um: vec![10.0], ..MeasureConfig::default() };
    let steady = MeasureConfig { lead_in_s: 2.0, ..from_rest.clone() };
    let data = sts_dataset::Dataset { manifest: from_rest.manifest(), groups: Vec::new() };
    let config = feature_config_for(&data, None);
    let fs = data.manifest.sample_rate_hz;
    for index in 0..2 {
        let rest = simulate_group(&from_rest, index).unwrap();
        let lead = simulate_group(&steady, index).unwrap();
        let reference = group_features_from(&lead, &config, 0).unwrap();
        let unskipped = group_features_from(&rest, &config, 0).unwrap();
        let start = feature_start(rest.len(), &config, fs, DEFAULT_SKIP_S);
        assert_eq!(start, 4000);
        let skipped = group_features_from(&rest, &config, start).unwrap();
        let rel = |a: f32, b: f32| ((a - b) / b).abs();
        // The transient inflates the crest factor (f8) of the whole window...
        assert!(
            rel(unskipped[7], reference[7]) > 0.3,
            "crest factor from rest {} vs steady {}",
            unskipped[7],
            reference[7]
        );
        // ... and the skipped window reads steady motion within noise.
        for i in STEADY {
            assert!(
                rel(skipped[i], reference[i]) < 0.005,
                "{}: skipped {} vs steady {}",
                FEATURE_NAMES[i],
                skipped[i],
                reference[i]
            );
        }
        assert!(rel(skipped[0], reference[0]) < 1e-3, "frequency {} vs {}", skipped[0], reference[0]);
    }
}

#[test]
fn a_short_group_moves_the_window_back_but_never_before_the_start() {
    let config = sts_twin_core::features::FeatureConfig::DEFAULT;
    let window = config.window_samples as usize;
    assert_eq!(feature_start(window + 10_000, &config, 8000.0, 0.5), 4000);
    assert_eq!(feature_start(window + 1000, &config, 8000.0, 0.5), 1000);
    assert_eq!(feature_start(window, &config, 8000.0, 0.5), 0);
    assert_eq!(feature_start(10, &config, 8000.0, 0.5), 0);
}
