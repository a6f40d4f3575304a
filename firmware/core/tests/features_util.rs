//! Signal generators and comparison helpers shared by the feature tests (included with
//! `#[path]`); also tests the generators themselves.
#![allow(dead_code)]

use sts_twin_core::features::{FeatureConfig, FeatureExtractor, Features, FEATURE_COUNT, FEATURE_NAMES};

/// Extractor for windows up to 2,048 samples (128 blocks, 128-point FFT).
pub type SmallExtractor = FeatureExtractor<128, 384, 64>;
/// Extractor at the largest capacity, 65,536 samples.
pub type MaxExtractor = FeatureExtractor<4096, 4352, 2048>;

/// SplitMix64: small, seeded, deterministic.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Standard normal (Box-Muller).
    pub fn gaussian(&mut self) -> f64 {
        let u1 = 1.0 - self.uniform();
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

/// One sinusoidal component.
#[derive(Clone, Copy, Debug)]
pub struct Tone {
    pub freq_hz: f64,
    pub amp_mps2: f64,
    pub phase_rad: f64,
}

/// A test signal: tones + DC + white Gaussian noise, sampled and quantised to ADC codes
/// (rounded, saturating at the i16 range).
#[derive(Clone, Debug)]
pub struct Signal {
    pub tones: Vec<Tone>,
    pub dc_mps2: f64,
    pub noise_rms_mps2: f64,
    pub seed: u64,
}

impl Signal {
    pub fn tone(freq_hz: f64, amp_mps2: f64) -> Self {
        Self { tones: vec![Tone { freq_hz, amp_mps2, phase_rad: 0.3 }], dc_mps2: 0.0, noise_rms_mps2: 0.0, seed: 1 }
    }
    pub fn codes(&self, len: usize, cfg: &FeatureConfig) -> Vec<i16> {
        let mut rng = Rng::new(self.seed);
        let fs = cfg.sample_rate_hz as f64;
        let lsb = cfg.acc_mps2_per_lsb as f64;
        (0..len)
            .map(|i| {
                let t = i as f64 / fs;
                let mut a = self.dc_mps2;
                for tone in &self.tones {
                    a += tone.amp_mps2 * (2.0 * std::f64::consts::PI * tone.freq_hz * t + tone.phase_rad).sin();
                }
                if self.noise_rms_mps2 > 0.0 {
                    a += self.noise_rms_mps2 * rng.gaussian();
                }
                (a / lsb).round().clamp(i16::MIN as f64, i16::MAX as f64) as i16
            })
            .collect()
    }
}

/// Feeds `codes` to a fresh extractor and returns its features.
pub fn run<const W: usize, const R: usize, const H: usize>(codes: &[i16], cfg: FeatureConfig) -> Features {
    let mut fx = Box::new(FeatureExtractor::<W, R, H>::new(cfg).expect("valid config"));
    fx.push_slice(codes);
    fx.features()
}

/// `|a - b| <= rel * |b| + abs`.
pub fn close(a: f64, b: f64, rel: f64, abs: f64) -> bool {
    (a - b).abs() <= rel * b.abs() + abs
}

/// Formats fixed-point vs reference features side by side.
pub fn table(fixed: &[f32; FEATURE_COUNT], reference: &[f64; FEATURE_COUNT]) -> String {
    let mut s = String::new();
    for i in 0..FEATURE_COUNT {
        s += &format!("  {:>18}: fixed {:>15.8e}  ref {:>15.8e}\n", FEATURE_NAMES[i], fixed[i], reference[i]);
    }
    s
}

#[test]
fn rng_is_deterministic_and_roughly_normal() {
    let mut a = Rng::new(7);
    let mut b = Rng::new(7);
    let xs: Vec<f64> = (0..20_000).map(|_| a.gaussian()).collect();
    let ys: Vec<f64> = (0..20_000).map(|_| b.gaussian()).collect();
    assert_eq!(xs, ys);
    let mean = xs.iter().sum::<f64>() / xs.len() as f64;
    let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / xs.len() as f64;
    assert!(mean.abs() < 0.03, "mean {mean}");
    assert!((var - 1.0).abs() < 0.05, "var {var}");
}

#[test]
fn signal_saturates_instead_of_wrapping() {
    let cfg = FeatureConfig { acc_mps2_per_lsb: 1e-3, ..FeatureConfig::DEFAULT };
    let codes = Signal::tone(10.0, 100.0).codes(8000, &cfg);
    assert_eq!(*codes.iter().max().unwrap(), i16::MAX);
    assert_eq!(*codes.iter().min().unwrap(), i16::MIN);
}
