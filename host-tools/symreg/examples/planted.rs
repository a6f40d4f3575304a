//! The planted-problem benchmark of this engine alone (the side-by-side comparison with the
//! peers lives in `bench/symreg-peers`).
//!
//! ```text
//! cargo run --release -p sts-symreg --example planted -- [--problem P1|P2|both] [--seeds N]
//!     [--first-seed S] [--threads T] [--max-epochs E] [--write-csv DIR]
//! ```
//! Prints one line per run and a summary: recovery rate of the exact form as the selected
//! model, and median wall time. `--write-csv DIR` only writes the data sets
//! (`DIR/P1_seed0.csv`, ...; columns x0..x11,y) and exits.
use std::time::Instant;
use sts_symreg::planted::{generate, is_exact_recovery, Planted, N_FEATURES};
use sts_symreg::{fit, SearchConfig};

fn main() {
    let mut problems = vec![Planted::P1, Planted::P2];
    let mut seeds = 10u64;
    let mut first_seed = 0u64;
    let mut cfg = SearchConfig::default();
    let mut csv_dir: Option<String> = None;
    let mut verbose = false;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut val = || args.next().unwrap_or_else(|| panic!("{a} needs a value"));
        match a.as_str() {
            "--problem" => {
                problems = match val().as_str() {
                    "P1" => vec![Planted::P1],
                    "P2" => vec![Planted::P2],
                    _ => vec![Planted::P1, Planted::P2],
                }
            }
            "--seeds" => seeds = val().parse().expect("--seeds N"),
            "--first-seed" => first_seed = val().parse().expect("--first-seed S"),
            "--threads" => cfg.threads = val().parse().expect("--threads T"),
            "--max-epochs" => cfg.max_epochs = val().parse().expect("--max-epochs E"),
            "--write-csv" => csv_dir = Some(val()),
            "--verbose" => verbose = true,
            other => panic!("unknown argument {other}"),
        }
    }
    if let Some(dir) = csv_dir {
        std::fs::create_dir_all(&dir).expect("create the CSV directory");
        for &p in &problems {
            for seed in first_seed..first_seed + seeds {
                let (x, y) = generate(p, seed, 99);
                let mut s = String::new();
                let header: Vec<String> = (0..N_FEATURES).map(|j| format!("x{j}")).collect();
                s.push_str(&header.join(","));
                s.push_str(",y\n");
                for (r, y_r) in y.iter().enumerate() {
                    for v in x.row(r) {
                        s.push_str(&format!("{v:?},"));
                    }
                    s.push_str(&format!("{y_r:?}\n"));
                }
                let path = format!("{dir}/{}_seed{seed}.csv", p.name());
                std::fs::write(&path, s).expect("write CSV");
            }
        }
        return;
    }
    for &p in &problems {
        let mut times = Vec::new();
        let mut recovered = 0;
        for seed in first_seed..first_seed + seeds {
            let (x, y) = generate(p, seed, 99);
            let cfg = SearchConfig { seed, ..cfg.clone() };
            let t0 = Instant::now();
            let result = fit(&x, &y, &cfg, |_| {}).expect("search runs");
            let dt = t0.elapsed().as_secs_f64();
            times.push(dt);
            let best = result.best();
            let ok = is_exact_recovery(p, &best.expr);
            recovered += ok as usize;
            let exact_on_front = result.front.iter().any(|m| is_exact_recovery(p, &m.expr));
            println!(
                "{} seed {seed:>3}: {:>6.2} s  epochs {:>4}  evals {:>9}  {:?}  recovered {}  (exact on front {})  c={} r2={:.12}  {}",
                p.name(),
                dt,
                result.epochs,
                result.evaluations,
                result.stop_reason,
                if ok { "yes" } else { "NO " },
                exact_on_front,
                best.complexity,
                best.r2,
                best.expr.to_infix_rounded::<&str>(&[], 5)
            );
            if verbose || !ok {
                println!("{}", result.explanation);
            }
        }
        times.sort_by(f64::total_cmp);
        let median = if times.len() % 2 == 1 {
            times[times.len() / 2]
        } else {
            0.5 * (times[times.len() / 2 - 1] + times[times.len() / 2])
        };
        println!(
            "SUMMARY {}: recovered {}/{} ({:.0}%), median wall time {:.2} s, threads {}",
            p.name(),
            recovered,
            seeds,
            100.0 * recovered as f64 / seeds as f64,
            median,
            cfg.threads
        );
    }
}
