//! The least squares' hot loop: one group's regression reduced to its triangular factor
//! (`Stats::from_columns`), against nalgebra's QR of the same matrix, on the shapes of the
//! fits (a group's window of samples, a candidate's or an effect's columns).
use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::DMatrix;
use std::hint::black_box;
use sts_numerics::lsq::Stats;

fn columns(rows: usize, cols: usize) -> Vec<Vec<f64>> {
    (0..cols).map(|j| (0..rows).map(|i| ((i * (j + 3)) as f64 * 1e-3).sin() + 0.1 * j as f64).collect()).collect()
}

fn bench_factor(c: &mut Criterion) {
    let mut group = c.benchmark_group("group_factor");
    for (rows, regressors) in [(4_000, 8), (4_000, 24)] {
        let x = columns(rows, regressors);
        let r: Vec<f64> = (0..rows).map(|i| (i as f64 * 7e-3).cos()).collect();
        group.bench_function(format!("stats_from_columns_{rows}x{regressors}"), |b| {
            b.iter(|| black_box(Stats::from_columns(black_box(&x), black_box(&r))))
        });
        let m = DMatrix::from_fn(rows, regressors + 1, |i, j| if j < regressors { x[j][i] } else { r[i] });
        group.bench_function(format!("nalgebra_qr_r_{rows}x{regressors}"), |b| {
            b.iter(|| black_box(black_box(m.clone()).qr().r()))
        });
    }
    group.finish();
}

criterion_group!(benches, bench_factor);
criterion_main!(benches);
