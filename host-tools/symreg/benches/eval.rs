//! Raw evaluation speed: a 6-node expression on 100 rows (the target is at least 0.5 million
//! evaluations per second per core).
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::hint::black_box;
use sts_symreg::{BinaryOp, Evaluator, Expr, Program, UnaryOp};

fn data(n_rows: usize, n_cols: usize) -> Vec<Vec<f64>> {
    (0..n_cols).map(|c| (0..n_rows).map(|r| 0.5 + ((r * 7 + c * 13) % 97) as f64 * 0.1).collect()).collect()
}

fn bench_eval(c: &mut Criterion) {
    let cols = data(100, 12);
    let refs: Vec<&[f64]> = cols.iter().map(Vec::as_slice).collect();
    let mut group = c.benchmark_group("eval_100_rows");
    group.throughput(Throughput::Elements(1));
    // Six nodes need one unary operator (binary-only trees have an odd node count).
    let sqrt = Expr::unary(
        UnaryOp::Sqrt,
        Expr::binary(BinaryOp::Add, Expr::binary(BinaryOp::Mul, Expr::Var(0), Expr::Var(1)), Expr::Var(2)),
    );
    let tanh = Expr::unary(
        UnaryOp::Tanh,
        Expr::binary(BinaryOp::Add, Expr::binary(BinaryOp::Mul, Expr::Const(1.5), Expr::Var(0)), Expr::Var(1)),
    );
    let pow = Expr::binary(
        BinaryOp::Mul,
        Expr::Var(0),
        Expr::binary(BinaryOp::Pow, Expr::binary(BinaryOp::Div, Expr::Var(1), Expr::Var(2)), Expr::Const(0.78)),
    );
    for (name, e) in [("sqrt", &sqrt), ("tanh", &tanh), ("pow", &pow)] {
        let p = Program::compile(e);
        let mut ev = Evaluator::new(100);
        let mut out = vec![0.0; 100];
        group.bench_function(format!("{name}_nodes={}", e.complexity()), |b| {
            b.iter(|| {
                let ok = ev.eval(black_box(&p), black_box(&refs), &mut out);
                black_box(ok);
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench_eval);
criterion_main!(benches);
