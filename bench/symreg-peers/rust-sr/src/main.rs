//! Runs the `symbolic_regression` crate on one CSV (last column is the target) and prints one
//! JSON object: the model chosen by PySR's default "best" rule on its Pareto front, and the
//! front itself.
//!
//! ```text
//! symreg-peer-rust-sr FILE.csv --seed N --threads T --timeout S [--maxsize M]
//! ```
use ndarray::{Array1, Array2};
use std::time::Instant;
use symbolic_regression::prelude::*;
use symbolic_regression::{equation_search, Dataset, EarlyStop, Options};

fn main() {
    let mut args = std::env::args().skip(1);
    let path = args.next().expect("usage: FILE.csv --seed N --threads T --timeout S");
    let (mut seed, mut threads, mut timeout, mut maxsize) = (0u64, 2usize, 10.0f64, 20usize);
    while let Some(a) = args.next() {
        let v = args.next().expect("flag needs a value");
        match a.as_str() {
            "--seed" => seed = v.parse().expect("seed"),
            "--threads" => threads = v.parse().expect("threads"),
            "--timeout" => timeout = v.parse().expect("timeout"),
            "--maxsize" => maxsize = v.parse().expect("maxsize"),
            other => panic!("unknown flag {other}"),
        }
    }
    rayon::ThreadPoolBuilder::new().num_threads(threads).build_global().expect("thread pool");

    let text = std::fs::read_to_string(&path).expect("read CSV");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let n_features = header.len() - 1;
    let rows: Vec<Vec<f64>> = lines
        .filter(|l| !l.trim().is_empty())
        .map(|l| l.split(',').map(|v| v.trim().parse::<f64>().expect("number")).collect())
        .collect();
    let n_rows = rows.len();
    let mut x = Array2::<f64>::zeros((n_features, n_rows));
    let mut y = Array1::<f64>::zeros(n_rows);
    for (i, r) in rows.iter().enumerate() {
        for j in 0..n_features {
            x[(j, i)] = r[j];
        }
        y[i] = r[n_features];
    }
    let mean = y.iter().sum::<f64>() / n_rows as f64;
    let var = y.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n_rows as f64;
    let dataset = Dataset::new(x, y);

    const D: usize = 2;
    let operators =
        BuiltinOpsF64::from_names(["add", "sub", "mul", "div", "pow", "abs", "sqrt", "exp", "log", "tanh", "sin"])
            .expect("operators");
    let options = Options::<f64, D> {
        operators,
        seed,
        niterations: 100_000,
        maxsize,
        timeout_in_seconds: timeout,
        progress: false,
        // Same early stop as the sts-symreg run: NMSE below 1e-12.
        early_stop_condition: Some(EarlyStop::below(1e-12 * var)),
        ..Default::default()
    };
    let t0 = Instant::now();
    let result = equation_search::<f64, BuiltinOpsF64, D>(&dataset, &options);
    let wall = t0.elapsed().as_secs_f64();
    let front = result.hall_of_fame.pareto_front();

    // PySR's model_selection="best": among members with loss <= 1.5 * the best loss, the
    // highest score -d ln(loss) / d complexity.
    let min_loss = front.iter().map(|m| m.loss).fold(f64::INFINITY, f64::min);
    let mut best_i = front.len() - 1;
    let mut best_score = f64::NEG_INFINITY;
    let mut prev: Option<(f64, usize)> = None;
    let mut entries = Vec::new();
    for (i, m) in front.iter().enumerate() {
        let score = match prev {
            None => 0.0,
            Some((pl, pc)) => {
                let dc = (m.complexity as f64 - pc as f64).max(1.0);
                -(m.loss.max(1e-300).ln() - pl.max(1e-300).ln()) / dc
            }
        };
        prev = Some((m.loss, m.complexity));
        if m.loss <= 1.5 * min_loss && score > best_score {
            best_score = score;
            best_i = i;
        }
        let formula = string_tree(&m.expr, Default::default());
        entries.push(format!(
            "{{\"formula\": \"{}\", \"loss\": {:e}, \"complexity\": {}}}",
            formula.replace('"', "'"),
            m.loss,
            m.complexity
        ));
    }
    let selected = string_tree(&front[best_i].expr, Default::default());
    println!(
        "{{\"formula\": \"{}\", \"complexity\": {}, \"loss\": {:e}, \"wall_s\": {:.3}, \"front\": [{}]}}",
        selected.replace('"', "'"),
        front[best_i].complexity,
        front[best_i].loss,
        wall,
        entries.join(", ")
    );
}
