//! Evaluation speed per core, measured in CPU time of the measuring thread (so that other
//! load on the machine does not count), for the expressions of `benches/eval.rs`.
//!
//! ```text
//! cargo run --release -p sts-symreg --example eval_speed
//! ```
use std::hint::black_box;
use std::time::Instant;
use sts_symreg::{BinaryOp, Evaluator, Expr, Program, UnaryOp};

/// CPU seconds used by this thread (Linux `/proc/thread-self/stat`, clock ticks of 10 ms).
fn thread_cpu_s() -> f64 {
    let stat = std::fs::read_to_string("/proc/thread-self/stat").expect("Linux /proc");
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = &stat[stat.rfind(')').expect("stat format") + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f[11].parse::<f64>().unwrap() + f[12].parse::<f64>().unwrap();
    ticks / 100.0
}

fn main() {
    let cols: Vec<Vec<f64>> =
        (0..12).map(|c| (0..100).map(|r| 0.5 + ((r * 7 + c * 13) % 97) as f64 * 0.1).collect()).collect();
    let refs: Vec<&[f64]> = cols.iter().map(Vec::as_slice).collect();
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
    for e in [&sqrt, &tanh, &pow] {
        let p = Program::compile(e);
        let mut ev = Evaluator::new(100);
        let mut out = vec![0.0; 100];
        let (w0, c0) = (Instant::now(), thread_cpu_s());
        let mut n = 0u64;
        while thread_cpu_s() - c0 < 2.0 {
            for _ in 0..10_000 {
                black_box(ev.eval(black_box(&p), black_box(&refs), &mut out));
            }
            n += 10_000;
        }
        let (wall, cpu) = (w0.elapsed().as_secs_f64(), thread_cpu_s() - c0);
        println!(
            "{:<28} nodes={}  {:>6.2} M evals/s per core (CPU time)  [{:.2} M/s wall]",
            e.to_string(),
            e.complexity(),
            n as f64 / cpu / 1e6,
            n as f64 / wall / 1e6
        );
    }
}
