//! Host benchmarks of the feature extraction: `push` per sample (8,000 pushes per
//! iteration, window full) and `capture` + `finish` per read of the default 40,000-sample
//! window.
//!
//! `cargo bench -p sts-twin-core --bench features`

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::hint::black_box;
use sts_twin_core::features::{
    DefaultFeatureExtractor, DefaultFeatureState, DefaultScratch, DefaultSpectralRings, FeatureConfig,
};

/// A 23.3 Hz, 0.3 m/s^2 sinusoid plus a DC offset and a pseudo-random dither, as codes.
fn codes(len: usize) -> Vec<i16> {
    let mut x = 0x1234_5678u32;
    (0..len)
        .map(|i| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            let t = i as f64 / 8000.0;
            let v = 3000.0 * (2.0 * std::f64::consts::PI * 23.3 * t).sin() + 500.0 + (x % 7) as f64 - 3.0;
            v as i16
        })
        .collect()
}

fn bench_push(c: &mut Criterion) {
    let cfg = FeatureConfig::DEFAULT;
    let input = codes(8000);
    let mut group = c.benchmark_group("features_push");
    group.throughput(Throughput::Elements(input.len() as u64));
    let rings = Box::new(DefaultSpectralRings::new());
    let mut state = Box::new(DefaultFeatureState::new(cfg).unwrap());
    // Fill the window first so every push also removes a sample.
    for &c in &codes(40_000) {
        state.push(&rings, c);
    }
    group.bench_function("push_8000_samples_default_window", |b| {
        b.iter(|| {
            for &c in &input {
                state.push(&rings, black_box(c));
            }
        })
    });
    group.finish();
}

fn bench_finish(c: &mut Criterion) {
    let cfg = FeatureConfig::DEFAULT;
    let rings = Box::new(DefaultSpectralRings::new());
    let mut state = Box::new(DefaultFeatureState::new(cfg).unwrap());
    for &c in &codes(48_000) {
        state.push(&rings, c);
    }
    let mut scratch = Box::new(DefaultScratch::new());
    let mut group = c.benchmark_group("features_finish");
    group.bench_function("capture_and_finish_40000_window", |b| {
        b.iter(|| {
            let cap = state.capture(&rings);
            black_box(rings.finish(black_box(&cap), &mut scratch).unwrap())
        })
    });
    group.bench_function("extractor_features_40000_window", |b| {
        let mut fx = Box::new(DefaultFeatureExtractor::new(cfg).unwrap());
        fx.push_slice(&codes(48_000));
        b.iter(|| black_box(fx.features()))
    });
    group.finish();
}

criterion_group!(benches, bench_push, bench_finish);
criterion_main!(benches);
