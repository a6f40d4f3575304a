//! Every feature against hand-computed values for simple signals.

use crate::features_util as util;

use sts_twin_core::features::*;
use util::{close, run, Signal, SmallExtractor};

/// 1,024-sample window (64 blocks, 64-point FFT: 7.8125 Hz bins at 8 kHz), 1e-3 m/s^2/LSB.
fn cfg() -> FeatureConfig {
    FeatureConfig { window_samples: 1024, acc_mps2_per_lsb: 1e-3, sample_rate_hz: 8000.0 }
}

fn features(codes: &[i16]) -> Features {
    run::<128, 384, 64>(codes, cfg())
}

#[test]
fn constant_signal_with_offset_is_all_zero() {
    for c in [0i16, 1234, -32768, 32767] {
        let f = features(&vec![c; 3000]);
        assert_eq!(f.as_array(), [0.0; FEATURE_COUNT], "constant {c}");
        assert_eq!(f.window_samples_used(), 1024);
    }
}

#[test]
fn square_wave_about_an_offset() {
    // +-A around DC c, period 64 samples (125 Hz): the window holds 16 whole periods.
    let (a, c) = (1000i16, 300i16);
    let codes: Vec<i16> = (0..4096).map(|i| if (i / 32) % 2 == 0 { c + a } else { c - a }).collect();
    let f = features(&codes);
    let s = 1e-3f32;
    let amp = a as f32 * s;
    assert!(close(f.mean_abs_mps2() as f64, amp as f64, 1e-6, 0.0), "f2 {}", f.mean_abs_mps2());
    assert!(close(f.variance_m2ps4() as f64, (amp * amp) as f64, 1e-6, 0.0), "f3");
    assert!(close(f.peak_mps2() as f64, amp as f64, 1e-6, 0.0), "f4");
    assert!(close(f.rms_mps2() as f64, amp as f64, 1e-6, 0.0), "f5");
    assert!(close(f.kurtosis() as f64, 1.0, 1e-6, 0.0), "f6 {}", f.kurtosis());
    assert!(f.skewness().abs() < 1e-6, "f7");
    assert!(close(f.crest_factor() as f64, 1.0, 1e-6, 0.0), "f8");
    assert!(close(f.impulse_factor() as f64, 1.0, 1e-6, 0.0), "f9");
    assert!(close(f.shape_factor() as f64, 1.0, 1e-6, 0.0), "f10");
    // The decimated square [+A, +A, -A, -A] (block means) is a pure 125 Hz tone on bin 16.
    assert!((f.signal_freq_hz() - 125.0).abs() < 1e-3, "f1 {}", f.signal_freq_hz());
    assert!((f.mean_freq_hz() - 125.0).abs() < 1e-3, "f11 {}", f.mean_freq_hz());
    assert!(close(f.total_power_m2ps4() as f64, (amp * amp) as f64, 1e-6, 0.0), "f12");
}

#[test]
fn sinusoid_of_known_amplitude_and_frequency() {
    // 10,000 LSB = 10 m/s^2 at 62.5 Hz (128 samples per period, 8 periods per window).
    let amp = 10.0;
    let f0 = 62.5;
    let codes = Signal::tone(f0, amp).codes(4096, &cfg());
    let f = features(&codes);
    let pi = std::f64::consts::PI;
    let q = 1e-4; // quantisation to 1e-3 m/s^2 on a 10 m/s^2 signal
    assert!(close(f.mean_abs_mps2() as f64, 2.0 * amp / pi, q, 0.0), "f2 {}", f.mean_abs_mps2());
    assert!(close(f.variance_m2ps4() as f64, amp * amp / 2.0, q, 0.0), "f3");
    assert!(close(f.peak_mps2() as f64, amp, q, 0.0), "f4 {}", f.peak_mps2());
    assert!(close(f.rms_mps2() as f64, amp / 2f64.sqrt(), q, 0.0), "f5");
    assert!(close(f.kurtosis() as f64, 1.5, q, 0.0), "f6 {}", f.kurtosis());
    assert!(f.skewness().abs() < q as f32, "f7 {}", f.skewness());
    assert!(close(f.crest_factor() as f64, 2f64.sqrt(), q, 0.0), "f8");
    assert!(close(f.impulse_factor() as f64, pi / 2.0, q, 0.0), "f9");
    assert!(close(f.shape_factor() as f64, pi / (2.0 * 2f64.sqrt()), q, 0.0), "f10");
    // 62.5 Hz is exactly bin 8 of the 64-point FFT at 500 Hz.
    assert!((f.signal_freq_hz() as f64 - f0).abs() < 1e-3, "f1 {}", f.signal_freq_hz());
    assert!((f.mean_freq_hz() as f64 - f0).abs() < 1e-2, "f11 {}", f.mean_freq_hz());
    // Boxcar decimation by 16 attenuates by sin(16 pi f/fs) / (16 sin(pi f/fs)).
    let gain = (16.0 * pi * f0 / 8000.0).sin() / (16.0 * (pi * f0 / 8000.0).sin());
    let expect = (amp * gain).powi(2) / 2.0;
    assert!(close(f.total_power_m2ps4() as f64, expect, 1e-3, 0.0), "f12 {} vs {expect}", f.total_power_m2ps4());
}

#[test]
fn single_impulse() {
    // 1,024 zeros, a 1,000 LSB spike at the start of block 96, zeros to t = 2,048: the
    // window [1024, 2048) holds the spike at position 512.
    let n = 1024.0f64;
    let h = 1000.0f64;
    let mut codes = vec![0i16; 2048];
    codes[1536] = 1000;
    let f = features(&codes);
    let s = 1e-3;
    // f2 by its definition: blocks up to the spike's are referenced to 0 (|h - 0| = h);
    // the 31 later blocks to trunc(256 h / n) / 256 = 250/256 LSB.
    let mean_abs = (h + 31.0 * 16.0 * 250.0 / 256.0) / n;
    assert!(close(f.mean_abs_mps2() as f64, mean_abs * s, 1e-6, 0.0), "f2 {} vs {}", f.mean_abs_mps2(), mean_abs * s);
    let m2 = h * h * (n - 1.0) / (n * n);
    assert!(close(f.variance_m2ps4() as f64, m2 * s * s, 1e-6, 0.0), "f3");
    let peak = h * (1.0 - 1.0 / n);
    assert!(close(f.peak_mps2() as f64, peak * s, 1e-6, 0.0), "f4");
    assert!(close(f.rms_mps2() as f64, m2.sqrt() * s, 1e-6, 0.0), "f5");
    let kurt = (n * n - 3.0 * n + 3.0) / (n - 1.0);
    let skew = (n - 2.0) / (n - 1.0).sqrt();
    assert!(close(f.kurtosis() as f64, kurt, 1e-6, 0.0), "f6 {}", f.kurtosis());
    assert!(close(f.skewness() as f64, skew, 1e-6, 0.0), "f7 {}", f.skewness());
    assert!(close(f.crest_factor() as f64, (n - 1.0).sqrt(), 1e-6, 0.0), "f8");
    assert!(close(f.impulse_factor() as f64, peak / mean_abs, 1e-6, 0.0), "f9");
    assert!(close(f.shape_factor() as f64, m2.sqrt() / mean_abs, 1e-6, 0.0), "f10");
    // Decimated: one block sum of h among 64 blocks; variance of the block means.
    let nd = 64.0;
    let var_y = (h / 16.0).powi(2) * (nd - 1.0) / (nd * nd);
    assert!(close(f.total_power_m2ps4() as f64, var_y * s * s, 1e-6, 0.0), "f12");
    // An impulse has a flat spectrum: no bin stands out of the noise floor, so the
    // centroid falls back to the plain one, near the middle of 0..250 Hz.
    assert!(f.mean_freq_hz() > 100.0 && f.mean_freq_hz() < 150.0, "f11 {}", f.mean_freq_hz());
}

#[test]
fn growing_window_uses_the_samples_so_far() {
    // 100 samples of a 1 LSB / -1 LSB alternation: n = 100, variance 1 LSB^2.
    let codes: Vec<i16> = (0..100).map(|i| if i % 2 == 0 { 1 } else { -1 }).collect();
    let f = features(&codes);
    assert_eq!(f.window_samples_used(), 100);
    assert!(close(f.variance_m2ps4() as f64, 1e-6, 1e-6, 0.0));
    assert!(close(f.mean_abs_mps2() as f64, 1e-3, 1e-6, 0.0), "f2 {}", f.mean_abs_mps2());
}

#[test]
fn too_short_windows_give_zeros_not_nan() {
    let f = features(&[]);
    assert_eq!(f.as_array(), [0.0; FEATURE_COUNT]);
    let f = features(&[5000]);
    assert_eq!(f.as_array(), [0.0; FEATURE_COUNT]);
    // Two samples: time-domain features exist, no complete block yet so no spectrum.
    let f = features(&[100, -100]);
    assert!(close(f.variance_m2ps4() as f64, 0.01, 1e-6, 0.0));
    assert!(close(f.kurtosis() as f64, 1.0, 1e-6, 0.0));
    assert_eq!(f.signal_freq_hz(), 0.0);
    assert_eq!(f.total_power_m2ps4(), 0.0);
    assert!(f.as_array().iter().all(|v| v.is_finite()));
}

#[test]
fn config_validation_names_the_problem() {
    let base = cfg();
    let cap = SmallExtractor::new(base).unwrap().state().config().window_samples;
    assert_eq!(cap, 1024);
    let err = |c: FeatureConfig| SmallExtractor::new(c).err();
    assert_eq!(err(FeatureConfig { window_samples: 0, ..base }), Some(FeatureError::WindowZero));
    assert_eq!(
        err(FeatureConfig { window_samples: 2064, ..base }),
        Some(FeatureError::WindowTooLong { window_samples: 2064, max_samples: 2048 })
    );
    assert_eq!(
        err(FeatureConfig { window_samples: 112, ..base }),
        Some(FeatureError::WindowTooShort { window_samples: 112, min_samples: 128 })
    );
    assert_eq!(
        err(FeatureConfig { window_samples: 1000, ..base }),
        Some(FeatureError::WindowNotWholeBlocks { window_samples: 1000 })
    );
    for bad in [0.0, -1e-3, f32::NAN, f32::INFINITY, 1e-10, 1e4] {
        assert_eq!(err(FeatureConfig { acc_mps2_per_lsb: bad, ..base }), Some(FeatureError::BadScale), "{bad}");
    }
    for bad in [0.0, -8000.0, f32::NAN, f32::INFINITY, 2e6] {
        assert_eq!(err(FeatureConfig { sample_rate_hz: bad, ..base }), Some(FeatureError::BadSampleRate), "{bad}");
    }
    assert!(SmallExtractor::new(FeatureConfig { window_samples: 2048, ..base }).is_ok());
    assert_eq!(FeatureConfig::DEFAULT.validate(40_000), Ok(()));
    assert!(FeatureError::WindowZero.to_string().contains("window_samples"));
}

#[test]
fn reconfigure_keeps_old_config_on_error_and_restarts_window() {
    let mut fx = Box::new(SmallExtractor::new(cfg()).unwrap());
    fx.push_slice(&vec![100; 500]);
    assert_eq!(
        fx.reconfigure(FeatureConfig { window_samples: 7, ..cfg() }),
        Err(FeatureError::WindowTooShort { window_samples: 7, min_samples: 128 })
    );
    assert_eq!(fx.config().window_samples, 1024);
    assert_eq!(fx.features().window_samples_used(), 500);
    fx.reconfigure(FeatureConfig { window_samples: 256, ..cfg() }).unwrap();
    assert_eq!(fx.features(), Features::default());
    let codes = Signal::tone(125.0, 1.0).codes(1000, &cfg());
    fx.push_slice(&codes);
    let fresh = run::<128, 384, 64>(&codes, FeatureConfig { window_samples: 256, ..cfg() });
    assert_eq!(fx.features(), fresh);
}

#[test]
fn names_labels_and_indices_agree() {
    assert_eq!(FEATURE_COUNT, 12);
    assert_eq!(feature_index("f1"), Some(SIGNAL_FREQ_HZ));
    assert_eq!(feature_index("f12"), Some(TOTAL_POWER_M2PS4));
    assert_eq!(feature_index("rms_mps2"), Some(RMS_MPS2));
    assert_eq!(feature_index("f13"), None);
    let values: [f32; 12] = core::array::from_fn(|i| i as f32 + 0.5);
    let f = Features::from_array(values, 10);
    let by_accessor = [
        f.signal_freq_hz(),
        f.mean_abs_mps2(),
        f.variance_m2ps4(),
        f.peak_mps2(),
        f.rms_mps2(),
        f.kurtosis(),
        f.skewness(),
        f.crest_factor(),
        f.impulse_factor(),
        f.shape_factor(),
        f.mean_freq_hz(),
        f.total_power_m2ps4(),
    ];
    assert_eq!(by_accessor, values);
    for (i, name) in FEATURE_NAMES.iter().enumerate() {
        assert_eq!(feature_index(name), Some(i));
        assert_eq!(feature_index(FEATURE_LABELS[i]), Some(i));
        assert_eq!(f.get(i), Some(values[i]));
    }
    assert_eq!(f.get(12), None);
}

#[test]
fn sqrt_f32_is_correctly_rounded() {
    let mut rng = util::Rng::new(3);
    let specials = [0.0f32, -0.0, 1.0, 2.0, 4.0, f32::MAX, f32::MIN_POSITIVE, 1e-45, 1e-40, 3.0, 0.5, f32::INFINITY];
    for x in specials {
        assert_eq!(sqrt_f32(x).to_bits(), x.sqrt().to_bits(), "{x:e}");
    }
    assert!(sqrt_f32(-1.0).is_nan() && sqrt_f32(f32::NAN).is_nan());
    for _ in 0..200_000 {
        let bits = (rng.next_u64() as u32) & 0x7fff_ffff;
        let x = f32::from_bits(bits);
        if x.is_finite() {
            assert_eq!(sqrt_f32(x).to_bits(), x.sqrt().to_bits(), "{x:e}");
        }
    }
    // Integers as produced by the moment code.
    for _ in 0..100_000 {
        let x = (rng.next_u64() >> (rng.next_u64() % 64)) as f32;
        assert_eq!(sqrt_f32(x).to_bits(), x.sqrt().to_bits(), "{x:e}");
    }
}
