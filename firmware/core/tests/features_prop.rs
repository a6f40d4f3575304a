//! Property tests: the fixed-point features agree with the f64 reference over random
//! signals (tones 1-100 Hz of 1e-4..50 m/s^2, noise, DC offset, ADC saturation, silence,
//! mixtures) and over arbitrary code sequences.
//!
//! Tolerances (measured maxima over 20,000 random cases in parentheses):
//! - f2..f10, f12: relative 2e-6 (2.4e-7): f32 rounding of exactly computed integers.
//! - f11: relative 5e-5 plus 1e-4 bins (4.1e-6 relative): integer FFT rounding.
//! - f1: 2e-3 bins (7e-5 bins), unless the reference spectrum has a near-tie: then the
//!   fixed-point peak must lie on a bin whose reference power is within 0.1% of the peak.

use crate::features_util as util;
use crate::reference;

use proptest::prelude::*;
use reference::{features_f64_detail, ReferenceFeatures};
use sts_twin_core::features::*;
use util::{close, run, table, Signal, Tone};

const REL_TIME_DOMAIN: f64 = 2e-6;
const ABS_DIMENSIONLESS: f64 = 1e-9;
const REL_MEAN_FREQ: f64 = 5e-5;
const ABS_MEAN_FREQ_BINS: f64 = 1e-4;
const ABS_SIGNAL_FREQ_BINS: f64 = 2e-3;

/// Checks one case; returns a description of the first disagreement.
fn agree(fixed: &Features, reference: &ReferenceFeatures) -> Result<(), String> {
    let f = fixed.as_array();
    let r = &reference.values;
    let bin = reference.bin_hz;
    let detail = || table(&f, r);
    for (i, v) in f.iter().enumerate() {
        if !v.is_finite() {
            return Err(format!("{} not finite\n{}", FEATURE_NAMES[i], detail()));
        }
    }
    for i in [
        MEAN_ABS_MPS2,
        VARIANCE_M2PS4,
        PEAK_MPS2,
        RMS_MPS2,
        KURTOSIS,
        SKEWNESS,
        CREST_FACTOR,
        IMPULSE_FACTOR,
        SHAPE_FACTOR,
        TOTAL_POWER_M2PS4,
    ] {
        // Absolute floor only for the dimensionless ones, where a symmetric signal gives
        // exactly 0 in fixed point and ~1e-16 in f64.
        let abs = if matches!(i, KURTOSIS | SKEWNESS) { ABS_DIMENSIONLESS } else { 0.0 };
        if !close(f[i] as f64, r[i], REL_TIME_DOMAIN, abs) {
            return Err(format!("{} differs\n{}", FEATURE_NAMES[i], detail()));
        }
    }
    if !close(f[MEAN_FREQ_HZ] as f64, r[MEAN_FREQ_HZ], REL_MEAN_FREQ, ABS_MEAN_FREQ_BINS * bin) {
        return Err(format!("mean_freq_hz differs\n{}", detail()));
    }
    let f1 = f[SIGNAL_FREQ_HZ] as f64;
    if !close(f1, r[SIGNAL_FREQ_HZ], 0.0, ABS_SIGNAL_FREQ_BINS * bin) {
        let k = (f1 / bin).round() as usize;
        let peak = reference.power.get(reference.peak_bin).copied().unwrap_or(0.0);
        let at_fixed = reference.power.get(k).copied().unwrap_or(0.0);
        if !(at_fixed >= 0.999 * peak && peak > 0.0) {
            return Err(format!("signal_freq_hz differs (bin {k} has {at_fixed:e} vs peak {peak:e})\n{}", detail()));
        }
    }
    Ok(())
}

/// A random test signal and configuration.
#[derive(Clone, Debug)]
struct Case {
    cfg: FeatureConfig,
    signal: Signal,
    len: usize,
}

prop_compose! {
    fn tone()(freq_hz in 1.0f64..100.0, log_amp in -4.0f64..1.699, phase_rad in 0.0f64..6.3) -> Tone {
        Tone { freq_hz, amp_mps2: 10f64.powf(log_amp), phase_rad }
    }
}

prop_compose! {
    /// `window_blocks` in 8..=max_blocks; the scale puts the sum of amplitudes at 1/2 to
    /// 1/2000 of full scale (so some cases saturate the ADC).
    fn case(max_blocks: u32, max_len: usize)(
        window_blocks in 8u32..=max_blocks,
        len in 0usize..=max_len,
        tones in prop::collection::vec(tone(), 0..4),
        noise in prop_oneof![Just(0.0), -5.0f64..-1.0],
        dc_fraction in prop_oneof![Just(0.0), -1.0f64..1.0],
        log_headroom in -0.3f64..3.3,
        seed in any::<u64>(),
    ) -> Case {
        let noise_rms_mps2 = if noise == 0.0 { 0.0 } else { 10f64.powf(noise) };
        let total = tones.iter().map(|t| t.amp_mps2).sum::<f64>() + 3.0 * noise_rms_mps2;
        let scale = if total > 0.0 { (total * 10f64.powf(log_headroom) / 32767.0).clamp(1e-9, 1e3) } else { 1e-4 };
        let cfg = FeatureConfig { window_samples: window_blocks * 16, acc_mps2_per_lsb: scale as f32, sample_rate_hz: 8000.0 };
        Case { cfg, signal: Signal { tones, dc_mps2: dc_fraction * total, noise_rms_mps2, seed }, len }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    /// Windows up to 2,048 samples, signals up to 3,000 samples (growing and sliding).
    #[test]
    fn fixed_point_matches_reference_short_windows(case in case(128, 3000)) {
        let codes = case.signal.codes(case.len, &case.cfg);
        let fixed = run::<128, 384, 64>(&codes, case.cfg);
        let reference = features_f64_detail(&codes, &case.cfg).unwrap();
        prop_assert!(agree(&fixed, &reference).is_ok(), "{}", agree(&fixed, &reference).unwrap_err());
    }

    /// Arbitrary code sequences (no structure at all): same agreement, nothing panics.
    #[test]
    fn arbitrary_codes_match_reference(
        codes in prop::collection::vec(any::<i16>(), 0..2500),
        window_blocks in 8u32..=128,
    ) {
        let cfg = FeatureConfig { window_samples: window_blocks * 16, ..FeatureConfig::DEFAULT };
        let fixed = run::<128, 384, 64>(&codes, cfg);
        let reference = features_f64_detail(&codes, &cfg).unwrap();
        prop_assert!(agree(&fixed, &reference).is_ok(), "{}", agree(&fixed, &reference).unwrap_err());
    }

    /// Sequences built from runs of extreme and small codes (saturation-like inputs).
    #[test]
    fn extreme_runs_match_reference(
        runs in prop::collection::vec(
            (prop_oneof![Just(i16::MIN), Just(i16::MAX), Just(0i16), Just(-1i16), Just(1i16), any::<i16>()], 1usize..200),
            0..30,
        ),
    ) {
        let codes: Vec<i16> = runs.iter().flat_map(|&(c, n)| std::iter::repeat_n(c, n)).collect();
        let cfg = FeatureConfig { window_samples: 1024, ..FeatureConfig::DEFAULT };
        let fixed = run::<128, 384, 64>(&codes, cfg);
        let reference = features_f64_detail(&codes, &cfg).unwrap();
        prop_assert!(agree(&fixed, &reference).is_ok(), "{}", agree(&fixed, &reference).unwrap_err());
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 6, ..ProptestConfig::default() })]

    /// The default 40,000-sample window (4,096-point FFT), sliding.
    #[test]
    fn fixed_point_matches_reference_full_window(case in case(2500, 48_000), extra in 40_000usize..48_000) {
        let cfg = FeatureConfig { window_samples: 40_000, ..case.cfg };
        let codes = case.signal.codes(extra, &cfg);
        let fixed = run::<2500, 2756, 2048>(&codes, cfg);
        let reference = features_f64_detail(&codes, &cfg).unwrap();
        prop_assert!(agree(&fixed, &reference).is_ok(), "{}", agree(&fixed, &reference).unwrap_err());
    }
}
