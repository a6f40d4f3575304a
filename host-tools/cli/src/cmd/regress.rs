//! `sts-twin regress`: symbolic regression on any numeric CSV table.
//!
//! Reads a CSV file with a header row, takes one column as the target and the others (or
//! those named with `--features`) as inputs, runs the `sts-symreg` search and prints the
//! selected formula, its R^2 and complexity, the Pareto front and why that member was
//! selected. `--json` prints the same as one JSON object (formulas in plain infix with the
//! CSV's column names and `**` for powers, readable by SymPy's `parse_expr`).

use anyhow::{bail, Context};
use serde::Serialize;
use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;
use sts_symreg::table::{read_table, Table};
use sts_symreg::{fit, Matrix, OperatorSet, SearchConfig, SearchResult, StopReason};

/// Arguments of `sts-twin regress`.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// The CSV file (header row, then numbers).
    pub file: PathBuf,
    /// Column to predict.
    #[arg(long)]
    pub target: String,
    /// Input columns, comma-separated (default: every other column).
    #[arg(long, value_delimiter = ',')]
    pub features: Option<Vec<String>>,
    /// Seed of the search (same seed, data and options give the same result).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Wall-time cap in seconds, checked between epochs. The search normally ends earlier
    /// (exact fit or --max-epochs); a run cut by this cap depends on the machine's speed.
    #[arg(long)]
    pub time_budget: Option<f64>,
    /// Epoch limit: the deterministic budget.
    #[arg(long, default_value_t = SearchConfig::default().max_epochs)]
    pub max_epochs: usize,
    /// Worker threads (the result does not depend on it).
    #[arg(long, default_value_t = 2)]
    pub threads: usize,
    /// Largest formula complexity (node count).
    #[arg(long, default_value_t = SearchConfig::default().max_complexity)]
    pub max_complexity: usize,
    /// Operators, comma-separated, from: + - * / pow abs sqrt exp log tanh sin.
    #[arg(long, default_value = "+,-,*,/,pow,abs,sqrt,exp,log,tanh,sin")]
    pub operators: String,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// One front member in the JSON output.
#[derive(Debug, Serialize)]
pub struct FrontJson {
    /// Plain infix with column names.
    pub formula: String,
    /// Mean squared error (target units squared).
    pub loss: f64,
    /// Node count.
    pub complexity: usize,
    /// R^2 on the data.
    pub r2: f64,
    /// Selection score.
    pub score: f64,
}

/// The JSON output of `sts-twin regress --json`.
#[derive(Debug, Serialize)]
pub struct RegressJson {
    /// The selected formula.
    pub formula: String,
    /// Its R^2.
    pub r2: f64,
    /// Its complexity.
    pub complexity: usize,
    /// Its mean squared error.
    pub loss: f64,
    /// The target column.
    pub target: String,
    /// The input columns, in variable order.
    pub features: Vec<String>,
    /// The Pareto front, simplest first.
    pub front: Vec<FrontJson>,
    /// Index of the selected member in `front`.
    pub selected: usize,
    /// Why that member (the rule and every member's score).
    pub explanation: String,
    /// `max_epochs`, `exact_fit` or `time_budget`.
    pub stop_reason: &'static str,
    /// Epochs run.
    pub epochs: usize,
    /// Formula evaluations.
    pub evaluations: u64,
    /// The seed.
    pub seed: u64,
}

/// The prepared problem: inputs, target and names.
struct Problem {
    x: Matrix,
    y: Vec<f64>,
    features: Vec<String>,
}

fn prepare(table: &Table, args: &Args) -> anyhow::Result<Problem> {
    let shown = args.file.display();
    let find = |name: &str| {
        table
            .columns
            .iter()
            .position(|c| c == name)
            .with_context(|| format!("{shown}: no column `{name}` (columns: {})", table.columns.join(", ")))
    };
    let target = find(&args.target)?;
    let feature_idx: Vec<usize> = match &args.features {
        Some(list) => list.iter().map(|n| find(n.trim())).collect::<anyhow::Result<_>>()?,
        None => (0..table.columns.len()).filter(|&i| i != target).collect(),
    };
    if feature_idx.contains(&target) {
        bail!("the target `{}` cannot also be a feature", args.target);
    }
    let features: Vec<String> = feature_idx.iter().map(|&i| table.columns[i].clone()).collect();
    let rows: Vec<Vec<f64>> = table.rows.iter().map(|r| feature_idx.iter().map(|&i| r[i]).collect()).collect();
    let y: Vec<f64> = table.rows.iter().map(|r| r[target]).collect();
    let x =
        if features.is_empty() { Matrix::from_row_major(y.len(), 0, Vec::new())? } else { Matrix::from_rows(&rows)? };
    Ok(Problem { x, y, features })
}

fn config(args: &Args) -> anyhow::Result<SearchConfig> {
    let operators = OperatorSet::parse(&args.operators)?;
    let time_budget = match args.time_budget {
        Some(s) if !s.is_finite() || s <= 0.0 => bail!("--time-budget must be a positive number of seconds"),
        Some(s) => Some(Duration::from_secs_f64(s)),
        None => None,
    };
    if args.threads == 0 {
        bail!("--threads must be at least 1");
    }
    Ok(SearchConfig {
        seed: args.seed,
        threads: args.threads,
        max_epochs: args.max_epochs,
        time_budget,
        operators,
        max_complexity: args.max_complexity,
        ..SearchConfig::default()
    })
}

fn stop_name(r: StopReason) -> &'static str {
    match r {
        StopReason::MaxEpochs => "max_epochs",
        StopReason::ExactFit => "exact_fit",
        StopReason::TimeBudget => "time_budget",
    }
}

fn to_json(result: &SearchResult, target: &str, features: &[String], seed: u64) -> RegressJson {
    let best = result.best();
    RegressJson {
        formula: best.expr.to_infix(features),
        r2: best.r2,
        complexity: best.complexity,
        loss: best.loss,
        target: target.to_string(),
        features: features.to_vec(),
        front: result
            .front
            .iter()
            .map(|m| FrontJson {
                formula: m.expr.to_infix(features),
                loss: m.loss,
                complexity: m.complexity,
                r2: m.r2,
                score: m.score,
            })
            .collect(),
        selected: result.selected,
        explanation: rename_vars(&result.explanation, features),
        stop_reason: stop_name(result.stop_reason),
        epochs: result.epochs,
        evaluations: result.evaluations,
        seed,
    }
}

/// The engine's explanation names variables `x0, x1, ...`; show column names instead by
/// re-printing each formula line.
fn rename_vars(explanation: &str, features: &[String]) -> String {
    // Replace whole-word `x<digits>` tokens, longest index first is unnecessary with
    // word-boundary scanning.
    let mut out = String::with_capacity(explanation.len());
    let bytes = explanation.as_bytes();
    let mut i = 0;
    while i < bytes.len() {
        let at_word_start =
            i == 0 || !(bytes[i - 1].is_ascii_alphanumeric() || bytes[i - 1] == b'_' || bytes[i - 1] == b'.');
        if at_word_start && bytes[i] == b'x' {
            let mut j = i + 1;
            while j < bytes.len() && bytes[j].is_ascii_digit() {
                j += 1;
            }
            let ends_word = j == bytes.len() || !(bytes[j].is_ascii_alphanumeric() || bytes[j] == b'_');
            if j > i + 1
                && ends_word
                && let Ok(k) = explanation[i + 1..j].parse::<usize>()
                && let Some(name) = features.get(k)
            {
                out.push_str(name);
                i = j;
                continue;
            }
        }
        let ch = explanation[i..].chars().next().unwrap_or(' ');
        out.push(ch);
        i += ch.len_utf8();
    }
    out
}

/// Runs the command, writing the report to `out` (progress goes to stderr).
pub fn run_to(args: &Args, out: &mut dyn Write, show_progress: bool) -> anyhow::Result<()> {
    let table = read_table(&args.file)?;
    let problem = prepare(&table, args)?;
    let cfg = config(args)?;
    let bar = if show_progress {
        let bar = indicatif::ProgressBar::with_draw_target(
            Some(cfg.max_epochs as u64),
            indicatif::ProgressDrawTarget::stderr(),
        );
        bar.set_style(
            indicatif::ProgressStyle::with_template("{spinner} epoch {pos}/{len} {elapsed} {msg}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        Some(bar)
    } else {
        None
    };
    let features = problem.features.clone();
    let result = fit(&problem.x, &problem.y, &cfg, |p| {
        if let Some(bar) = &bar {
            bar.set_position(p.epoch as u64);
            let front: Vec<String> = p.front.iter().map(|m| format!("c{}:R2={:.4}", m.complexity, m.r2)).collect();
            if let Some(sel) = p.front.get(p.selected) {
                bar.set_message(format!(
                    "best c={} R2={:.6} {} | front {}",
                    sel.complexity,
                    sel.r2,
                    sel.expr.to_infix_rounded(&features, 4),
                    front.join(" ")
                ));
            }
        }
    })
    .with_context(|| format!("symbolic regression on {}", args.file.display()))?;
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    let report = to_json(&result, &args.target, &problem.features, args.seed);
    if args.json {
        serde_json::to_writer_pretty(&mut *out, &report)?;
        writeln!(out)?;
    } else {
        writeln!(out, "{} = {}", args.target, report.formula)?;
        writeln!(out, "R^2 = {:.6}   complexity = {}   MSE = {:.6e}", report.r2, report.complexity, report.loss)?;
        writeln!(
            out,
            "search: {} epochs, {} evaluations, stopped by {}",
            report.epochs, report.evaluations, report.stop_reason
        )?;
        writeln!(out)?;
        write!(out, "{}", report.explanation)?;
    }
    Ok(())
}

/// Runs `sts-twin regress`.
pub fn run(args: &Args) -> anyhow::Result<()> {
    let stdout = std::io::stdout();
    let mut lock = stdout.lock();
    run_to(args, &mut lock, true)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct TestCli {
        #[command(flatten)]
        args: Args,
    }

    fn temp_csv(name: &str, text: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("sts-twin-regress-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        path
    }

    fn planted_csv() -> String {
        // speed_hz, gain, noise_col -> y = 1.5*speed_hz/gain + 0.5
        let mut s = String::from("speed_hz,gain,noise_col,y\n");
        for i in 0..40 {
            let a = 1.0 + (i as f64 * 0.37) % 4.0;
            let b = 0.5 + (i as f64 * 0.53) % 2.0;
            let n = (i * 7 % 11) as f64;
            s.push_str(&format!("{a},{b},{n},{}\n", 1.5 * a / b + 0.5));
        }
        s
    }

    fn run_cli(argv: &[&str]) -> anyhow::Result<String> {
        let cli = TestCli::try_parse_from(std::iter::once("regress").chain(argv.iter().copied()))?;
        let mut out = Vec::new();
        run_to(&cli.args, &mut out, false)?;
        Ok(String::from_utf8(out)?)
    }

    #[test]
    fn json_runs_are_identical_and_use_column_names() {
        let path = temp_csv("planted.csv", &planted_csv());
        let p = path.to_str().unwrap();
        let argv = ["--target", "y", "--seed", "3", "--max-epochs", "15", "--json", p];
        let a = run_cli(&argv).unwrap();
        let b = run_cli(&argv).unwrap();
        assert_eq!(a, b);
        let v: serde_json::Value = serde_json::from_str(&a).unwrap();
        let formula = v["formula"].as_str().unwrap();
        assert!(formula.contains("speed_hz") && formula.contains("gain"), "{formula}");
        assert!(v["r2"].as_f64().unwrap() > 0.999999, "{a}");
        assert!(v["complexity"].as_u64().unwrap() >= 5);
        let front = v["front"].as_array().unwrap();
        assert!(!front.is_empty());
        for m in front {
            assert!(m["formula"].is_string() && m["loss"].is_number() && m["complexity"].is_number());
        }
    }

    #[test]
    fn bad_cells_are_reported_with_file_line_and_column() {
        let path = temp_csv("bad.csv", "a,b,y\n1,2,3\n4,oops,6\n");
        let err = run_cli(&["--target", "y", path.to_str().unwrap()]).unwrap_err().to_string();
        assert!(
            err.contains("bad.csv:3") && err.contains("column 2") && err.contains("`b`") && err.contains("oops"),
            "{err}"
        );

        let path = temp_csv("short.csv", "a,b,y\n1,2,3\n4,5\n");
        let err = format!("{:#}", run_cli(&["--target", "y", path.to_str().unwrap()]).unwrap_err());
        assert!(err.contains("short.csv:3") && err.contains("2 fields, expected 3"), "{err}");

        let path = temp_csv("nan.csv", "a,y\n1,2\n2,NaN\n");
        let err = run_cli(&["--target", "y", path.to_str().unwrap()]).unwrap_err().to_string();
        assert!(err.contains("nan.csv:3") && err.contains("`y`"), "{err}");

        let path = temp_csv("ok.csv", "a,y\n1,2\n2,3\n3,5\n");
        let err = run_cli(&["--target", "z", path.to_str().unwrap()]).unwrap_err().to_string();
        assert!(err.contains("no column `z`") && err.contains("a, y"), "{err}");

        let err = format!("{:#}", run_cli(&["--target", "y", "/nonexistent/dir/x.csv"]).unwrap_err());
        assert!(err.contains("cannot open /nonexistent/dir/x.csv"), "{err}");
    }

    #[test]
    fn explanation_uses_column_names() {
        let names = vec!["speed".to_string(), "gain".to_string()];
        assert_eq!(rename_vars("2.0*x0/x1 + x12 + max1", &names), "2.0*speed/gain + x12 + max1");
    }
}
