//! Dominant (f1) and mean (f11) frequency of sinusoids of 1-100 Hz under accelerometer noise,
//! down to 1e-4 m/s^2, over the default 5 s window.
//!
//! Measured (60 random frequencies per row, 40,000-sample window, DC offset 0.02 m/s^2):
//!
//! | amplitude | noise rms | scale (m/s^2/LSB) | max abs f1 error | max abs f11 error |
//! |---|---|---|---|---|
//! | 1e-4 | 5e-5 | 6e-5 | 0.0017 Hz | 0.044 Hz |
//! | 1e-4 | 5e-5 | 1e-4 | 0.0018 Hz | 0.050 Hz |
//! | 1e-4 | 5e-5 | 3e-4 | 0.0030 Hz | 5.5 Hz (quantisation harmonics, see below) |
//! | 1 | 5e-5 | 1e-4 | 0.0006 Hz | 0.0024 Hz |
//! | 40 | 5e-5 | 1.5e-3 | 0.0006 Hz | 0.0005 Hz |
//!
//! At 3e-4 m/s^2/LSB a 1e-4 m/s^2 tone is a third of an LSB and the 5e-5 noise (0.17 LSB)
//! is too small to dither the quantiser: the ADC codes really contain harmonics, which pull
//! the centroid up. f1 stays exact; f11 needs noise of about 0.5 LSB rms or more.

use crate::features_util as util;

use sts_twin_core::features::{FeatureConfig, Features};
use util::{run, Rng, Signal, Tone};

fn features_of(f0: f64, amp: f64, noise: f64, scale: f32, seed: u64, len: usize) -> Features {
    let cfg = FeatureConfig { acc_mps2_per_lsb: scale, ..FeatureConfig::DEFAULT };
    let signal = Signal {
        tones: vec![Tone { freq_hz: f0, amp_mps2: amp, phase_rad: (seed % 628) as f64 / 100.0 }],
        dc_mps2: 0.02,
        noise_rms_mps2: noise,
        seed,
    };
    run::<2500, 2756, 2048>(&signal.codes(len, &cfg), cfg)
}

/// Frequencies 1-100 Hz: both ends, and random ones in between.
fn frequencies(seed: u64, count: usize) -> Vec<f64> {
    let mut rng = Rng::new(seed);
    let mut f = vec![1.0, 100.0];
    f.extend((0..count).map(|_| 1.0 + 99.0 * rng.uniform()));
    f
}

#[test]
fn tiny_tones_in_noise_dominant_and_mean_frequency() {
    for (scale, seed) in [(6e-5f32, 11u64), (1e-4, 12)] {
        for (i, f0) in frequencies(seed, 14).into_iter().enumerate() {
            let f = features_of(f0, 1e-4, 5e-5, scale, seed * 100 + i as u64, 40_000 + 997 * i);
            let (e1, e11) = (f.signal_freq_hz() as f64 - f0, f.mean_freq_hz() as f64 - f0);
            assert!(e1.abs() < 0.01, "scale {scale:e} f0 {f0:.3}: f1 {} (error {e1:.4} Hz)", f.signal_freq_hz());
            assert!(e11.abs() < 0.1, "scale {scale:e} f0 {f0:.3}: f11 {} (error {e11:.4} Hz)", f.mean_freq_hz());
        }
    }
}

#[test]
fn tiny_tones_at_coarse_scale_dominant_frequency() {
    for (i, f0) in frequencies(21, 10).into_iter().enumerate() {
        let f = features_of(f0, 1e-4, 5e-5, 3e-4, 2100 + i as u64, 41_000);
        let e1 = f.signal_freq_hz() as f64 - f0;
        assert!(e1.abs() < 0.01, "f0 {f0:.3}: f1 {} (error {e1:.4} Hz)", f.signal_freq_hz());
    }
}

#[test]
fn large_tones_dominant_and_mean_frequency() {
    for (amp, scale) in [(1.0, 1e-4f32), (40.0, 1.5e-3)] {
        for (i, f0) in frequencies(31, 10).into_iter().enumerate() {
            let f = features_of(f0, amp, 5e-5, scale, 3100 + i as u64, 45_000);
            let (e1, e11) = (f.signal_freq_hz() as f64 - f0, f.mean_freq_hz() as f64 - f0);
            assert!(e1.abs() < 0.005, "amp {amp} f0 {f0:.3}: f1 error {e1:.4} Hz");
            assert!(e11.abs() < 0.02, "amp {amp} f0 {f0:.3}: f11 error {e11:.4} Hz");
        }
    }
}

#[test]
fn two_tones_dominant_is_the_larger_and_centroid_between() {
    let cfg = FeatureConfig::DEFAULT;
    let signal = Signal {
        tones: vec![
            Tone { freq_hz: 12.3, amp_mps2: 0.02, phase_rad: 0.0 },
            Tone { freq_hz: 61.7, amp_mps2: 0.01, phase_rad: 1.0 },
        ],
        dc_mps2: 0.5,
        noise_rms_mps2: 5e-5,
        seed: 5,
    };
    let f = run::<2500, 2756, 2048>(&signal.codes(40_000, &cfg), cfg);
    assert!((f.signal_freq_hz() - 12.3).abs() < 0.005, "f1 {}", f.signal_freq_hz());
    // Power-weighted: (4 * 12.3 * g1 + 1 * 61.7 * g2) / (4 g1 + g2), g the boxcar gains^2.
    let g = |f: f64| {
        let x = std::f64::consts::PI * f / 8000.0;
        ((16.0 * x).sin() / (16.0 * x.sin())).powi(2)
    };
    let expect = (4.0 * 12.3 * g(12.3) + 61.7 * g(61.7)) / (4.0 * g(12.3) + g(61.7));
    assert!((f.mean_freq_hz() as f64 - expect).abs() < 0.05, "f11 {} vs {expect}", f.mean_freq_hz());
}

#[test]
fn white_noise_centroid_is_mid_band() {
    // White noise: the spectrum (after the boxcar's gentle roll-off) spreads over 0..250 Hz.
    let cfg = FeatureConfig::DEFAULT;
    let signal = Signal { tones: vec![], dc_mps2: 0.0, noise_rms_mps2: 1e-2, seed: 9 };
    let f = run::<2500, 2756, 2048>(&signal.codes(40_000, &cfg), cfg);
    assert!(f.mean_freq_hz() > 90.0 && f.mean_freq_hz() < 140.0, "f11 {}", f.mean_freq_hz());
    // Boxcar by 16 keeps 1/16 of white-noise power (band 0..fs/32, gain^2 averaging ~1).
    let ratio = f.total_power_m2ps4() / f.variance_m2ps4();
    assert!(ratio > 0.05 && ratio < 0.075, "f12/f3 {ratio}");
    assert!((f.kurtosis() - 3.0).abs() < 0.1, "kurtosis {}", f.kurtosis());
}
