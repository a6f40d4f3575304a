//! The non-repeating part of the error on emulator data: a friction whose Stribeck zone takes
//! more damping than the servo gives makes the slide hunt at 1 Hz and large strokes (the
//! hidden-effect suite's friction draw of seed 0), and `diagnose` says so; the same machine
//! without the friction repeats itself down to the probe's noise.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sts_analysis::repeat::Repeatability;
use sts_analysis::{feature_config_for, group_samples};
use sts_emulator::{EffectSpec, MeasureConfig};

fn repeatability(effects: Vec<EffectSpec>) -> (Repeatability, Vec<f64>) {
    let config = MeasureConfig {
        effects,
        seed: 100,
        freqs_hz: vec![1.0],
        amps_um: vec![1.0, 4.0, 9.0, 11.0],
        ..MeasureConfig::default()
    };
    let data = sts_emulator::measure::run(&config, &|_| {}).expect("measurement");
    let samples = group_samples(&data, &feature_config_for(&data, None)).expect("samples");
    (Repeatability::of_samples(&data, &samples), config.amps_um)
}

#[test]
fn a_hunting_axis_is_flagged_and_a_calm_one_is_not() {
    // The suite's draw (2.0 N Coulomb, 3.3 N static, Stribeck velocity 72 um/s).
    let mut rng = ChaCha8Rng::seed_from_u64(0x5eed_0000);
    let hunting = EffectSpec::random("coulomb-friction".parse().expect("an effect"), &mut rng).expect("effect");
    let (r, amps) = repeatability(vec![hunting]);
    let flagged: Vec<f64> = r.not_repeating.iter().map(|&i| amps[i]).collect();
    assert!(flagged.contains(&9.0) && flagged.contains(&11.0) && !flagged.contains(&1.0), "{r:?}");
    let text = r.describe(|i| (1.0, amps[i])).expect("a description");
    assert!(text.contains("does not repeat") && text.contains("1 Hz at 9-11 um"), "{text}");

    let (calm, _) = repeatability(Vec::new());
    assert!(calm.not_repeating.is_empty(), "{calm:?}");
    // The probe's noise (5 nm RMS on the default machine) is what is left.
    assert!((calm.floor_um - 0.005).abs() < 0.0005, "{calm:?}");
}
