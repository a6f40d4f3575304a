//! Accuracy survey of the fixed-point features (not a timing benchmark): prints
//! 1. dominant/mean frequency errors for sinusoids of 1-100 Hz under noise, and
//! 2. the largest relative differences from the f64 reference over random signals.
//!
//! `cargo bench -p sts-twin-core --bench features_accuracy` (about a minute).

#[path = "../tests/support/reference.rs"]
mod reference;
#[path = "../tests/features_util.rs"]
mod util;

use reference::features_f64_detail;
use sts_twin_core::features::{FeatureConfig, FEATURE_COUNT, FEATURE_NAMES, MEAN_FREQ_HZ, SIGNAL_FREQ_HZ};
use util::{run, Rng, Signal, Tone};

fn frequency_survey() {
    println!("## Frequency accuracy, 40,000-sample window, DC 0.02 m/s^2, 60 random f0 in 1..100 Hz per row");
    println!("| amplitude m/s^2 | noise rms m/s^2 | scale m/s^2/LSB | max abs f1 error Hz | max rel f1 error | max abs f11 error Hz | max rel f11 error |");
    println!("|---|---|---|---|---|---|---|");
    let rows: [(f64, f64, f32); 7] = [
        (1e-4, 5e-5, 6e-5),
        (1e-4, 5e-5, 1e-4),
        (1e-4, 5e-5, 2e-4),
        (1e-4, 5e-5, 3e-4),
        (1e-4, 1e-4, 3e-4),
        (1.0, 5e-5, 1e-4),
        (40.0, 5e-5, 1.5e-3),
    ];
    let mut rng = Rng::new(42);
    for (amp, noise, scale) in rows {
        let cfg = FeatureConfig { acc_mps2_per_lsb: scale, ..FeatureConfig::DEFAULT };
        let (mut e1, mut r1, mut e11, mut r11) = (0f64, 0f64, 0f64, 0f64);
        for i in 0..60 {
            let f0 = 1.0 + 99.0 * rng.uniform();
            let signal = Signal {
                tones: vec![Tone { freq_hz: f0, amp_mps2: amp, phase_rad: std::f64::consts::TAU * rng.uniform() }],
                dc_mps2: 0.02,
                noise_rms_mps2: noise,
                seed: i,
            };
            let len = 40_000 + (rng.next_u64() % 4000) as usize;
            let f = run::<2500, 2756, 2048>(&signal.codes(len, &cfg), cfg);
            let d1 = (f.signal_freq_hz() as f64 - f0).abs();
            let d11 = (f.mean_freq_hz() as f64 - f0).abs();
            e1 = e1.max(d1);
            r1 = r1.max(d1 / f0);
            e11 = e11.max(d11);
            r11 = r11.max(d11 / f0);
        }
        println!("| {amp:e} | {noise:e} | {scale:e} | {e1:.4} | {r1:.1e} | {e11:.4} | {r11:.1e} |");
    }
}

fn reference_survey(cases: u64) {
    println!(
        "\n## Fixed point vs f64 reference, {cases} random cases (windows 128..2048 samples, 0..3000 samples pushed)"
    );
    let mut rng = Rng::new(1);
    let mut max_rel = [0f64; FEATURE_COUNT];
    let mut max_f1_bins = 0f64;
    let mut ties = 0;
    for case in 0..cases {
        let window_blocks = 8 + (rng.next_u64() % 121) as u32;
        let len = (rng.next_u64() % 3000) as usize;
        let mut tones = Vec::new();
        let mut total = 0.0;
        for _ in 0..rng.next_u64() % 4 {
            let amp = 10f64.powf(-4.0 + rng.uniform() * (50f64.log10() + 4.0));
            total += amp;
            tones.push(Tone { freq_hz: 1.0 + 99.0 * rng.uniform(), amp_mps2: amp, phase_rad: 6.3 * rng.uniform() });
        }
        let noise = if rng.uniform() < 0.5 { 0.0 } else { 10f64.powf(-5.0 + 4.0 * rng.uniform()) };
        total += 3.0 * noise;
        let dc = if rng.uniform() < 0.5 { 0.0 } else { (rng.uniform() - 0.5) * 2.0 * total };
        let headroom = 10f64.powf(-0.3 + 3.6 * rng.uniform());
        let scale = if total > 0.0 { (total * headroom / 32767.0).clamp(1e-9, 1e3) } else { 1e-4 };
        let cfg = FeatureConfig {
            window_samples: window_blocks * 16,
            acc_mps2_per_lsb: scale as f32,
            sample_rate_hz: 8000.0,
        };
        let codes = Signal { tones, dc_mps2: dc, noise_rms_mps2: noise, seed: case }.codes(len, &cfg);
        let f = run::<128, 384, 64>(&codes, cfg).as_array();
        let r = features_f64_detail(&codes, &cfg).unwrap();
        for i in 0..FEATURE_COUNT {
            let (a, b) = (f[i] as f64, r.values[i]);
            assert!(a.is_finite(), "case {case}: {} not finite", FEATURE_NAMES[i]);
            if i == SIGNAL_FREQ_HZ {
                let bins = (a - b).abs() / r.bin_hz;
                let k = (a / r.bin_hz).round() as usize;
                if bins > 2e-3 && r.power.get(k).copied().unwrap_or(0.0) >= 0.999 * r.power[r.peak_bin] {
                    ties += 1;
                    continue;
                }
                max_f1_bins = max_f1_bins.max(bins);
            }
            if a != b {
                max_rel[i] = max_rel[i].max((a - b).abs() / b.abs().max(1e-30));
            }
        }
    }
    println!("| feature | max relative difference |");
    println!("|---|---|");
    for i in 0..FEATURE_COUNT {
        println!("| {} | {:.2e} |", FEATURE_NAMES[i], max_rel[i]);
    }
    println!("f1: max difference {max_f1_bins:.2e} bins (near-ties skipped: {ties}); f11 relative as above (index {MEAN_FREQ_HZ})");
}

fn main() {
    // `cargo bench` passes `--bench`; any other argument filters nothing here.
    frequency_survey();
    reference_survey(20_000);
}
