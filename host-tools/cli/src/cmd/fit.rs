//! `sts-twin fit DATA --out MODEL`: train the twin on a dataset.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context as _;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use sts_symreg::OperatorSet;
use sts_twin_core::features::FEATURE_LABELS;

use sts_analysis as analysis;
use sts_fit::{fit_samples, FitConfig, FitProgress, Target, DEFAULT_OPERATORS};
use sts_model::ModelFile;

/// Arguments of `sts-twin fit`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset directory (sts-twin-dataset/1).
    pub data: PathBuf,
    /// Where to write the model file (JSON, sts-twin-model/1).
    #[arg(long, required_unless_present = "table")]
    pub out: Option<PathBuf>,
    /// Seed of the searches: the same data, seed and settings give the same model file.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Epoch limit per search (the deterministic budget; searches stop earlier once a
    /// formula meets the goal).
    #[arg(long, default_value_t = FitConfig::default().max_epochs)]
    pub epochs: usize,
    /// Optional wall-time cap per search, seconds (results then depend on machine speed).
    #[arg(long)]
    pub time_budget: Option<f64>,
    /// Cross-validation folds (groups assigned round robin).
    #[arg(long, default_value_t = FitConfig::default().folds)]
    pub folds: usize,
    /// Worker threads; searches run in parallel (the result does not depend on it).
    #[arg(long, default_value_t = 2)]
    pub threads: usize,
    /// Operators of the formulas, comma-separated, from: + - * / pow abs sqrt exp log tanh sin.
    #[arg(long, default_value = DEFAULT_OPERATORS)]
    pub operators: String,
    /// Largest formula complexity (node count).
    #[arg(long, default_value_t = FitConfig::default().max_complexity)]
    pub max_complexity: usize,
    /// Good-enough NMSE (1 - R^2) of the amplitude formula: the simplest formula reaching it
    /// held out is selected, and searches stop early once they reach it.
    #[arg(long, default_value_t = FitConfig::default().amplitude_goal_nmse)]
    pub amplitude_goal: f64,
    /// Good-enough NMSE (1 - R^2) of the phase formula.
    #[arg(long, default_value_t = FitConfig::default().phase_goal_nmse)]
    pub phase_goal: f64,
    /// Accelerometer scale, m/s^2 per LSB, when the manifest does not state it.
    #[arg(long)]
    pub acc_scale: Option<f64>,
    /// Physical effects the twin gains as per-tick terms (canonical names, comma separated),
    /// or `servo-axis`: the servo axis alone simulated from the command, the twin for the
    /// machine's whole speed range (measured over it: `measure --freqs`).
    #[arg(long, value_delimiter = ',')]
    pub effect: Vec<String>,
    /// Seconds at each group's start left out of the feature window (the start transient
    /// of a group recorded from rest).
    #[arg(long, default_value_t = analysis::DEFAULT_SKIP_S)]
    pub skip_s: f64,
    /// Also write the training table (features and targets per group) as CSV; without
    /// --out, only the table is written.
    #[arg(long)]
    pub table: Option<PathBuf>,
    /// Also write the formulas as Rust source.
    #[arg(long)]
    pub export_rust: Option<PathBuf>,
    /// Also write the formulas as C source.
    #[arg(long)]
    pub export_c: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Replace an existing output (never one of the command's inputs).
    #[arg(long)]
    pub force: bool,
}

/// Runs `sts-twin fit`.
pub fn run(args: &Args) -> anyhow::Result<()> {
    let started = Instant::now();
    let operators = OperatorSet::parse(&args.operators).with_context(|| format!("--operators {:?}", args.operators))?;
    if !(args.amplitude_goal >= 0.0 && args.phase_goal >= 0.0) {
        anyhow::bail!("--amplitude-goal and --phase-goal must be zero or positive");
    }
    if !(args.skip_s.is_finite() && args.skip_s >= 0.0) {
        anyhow::bail!("--skip-s must be zero or positive");
    }
    let config = FitConfig {
        seed: args.seed,
        threads: args.threads.max(1),
        max_epochs: args.epochs,
        time_budget_s: args.time_budget,
        folds: args.folds,
        acc_scale_override: args.acc_scale,
        skip_s: args.skip_s,
        operators,
        max_complexity: args.max_complexity,
        amplitude_goal_nmse: args.amplitude_goal,
        phase_goal_nmse: args.phase_goal,
        ..FitConfig::default()
    };
    let outputs: Vec<&Path> = [&args.out, &args.table, &args.export_rust, &args.export_c]
        .into_iter()
        .flatten()
        .map(PathBuf::as_path)
        .collect();
    sts_dataset::output::check_files(&outputs, args.force, &[&args.data])?;
    let dataset = sts_analysis::read_dataset(&args.data)?;
    let read_s = started.elapsed().as_secs_f64();
    let prepared = if args.effect.is_empty() { None } else { Some(sts_fit::effects::prepare(&dataset, &args.effect)?) };
    let dataset = prepared.as_ref().map_or(&dataset, |p| &p.dataset);
    let effects_s = started.elapsed().as_secs_f64();
    let feature_config = analysis::feature_config_for(dataset, args.acc_scale);
    let samples = analysis::group_samples_skipping(dataset, &feature_config, args.skip_s)?;
    if let Some(path) = &args.table {
        sts_dataset::output::write_file(path, analysis::training_table_csv(&samples).as_bytes())?;
        println!("training table written to {}", path.display());
    }
    let Some(out) = &args.out else {
        return Ok(());
    };
    let features_s = started.elapsed().as_secs_f64();

    let folds = config.folds.max(2);
    let bar = if args.quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::with_draw_target(Some(2 * folds as u64 + 2), ProgressDrawTarget::stderr())
    };
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:20} {pos}/{len} searches  {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    // The bar shows the current best formulas of the final (all-group) searches.
    let mut finals = [String::new(), String::new()];
    let mut on_progress = |p: &FitProgress| {
        bar.set_position(p.searches_done as u64);
        if p.fold.is_none() {
            let k = usize::from(p.target == Target::Phase);
            finals[k] = format!("{}: {} (epoch {})", if k == 0 { "amp" } else { "phase" }, p.best, p.epoch);
            bar.set_message(format!("{}  |  {}", finals[0], finals[1]));
        }
    };
    let description = format!("fitted by sts-twin fit on {} (seed {})", dataset_name(&args.data), args.seed);
    let model = fit_samples(dataset, &samples, feature_config, &description, &config, &mut on_progress)?;
    bar.finish_and_clear();
    let model = match &prepared {
        Some(p) => p.attach(model)?,
        None => model,
    };
    sts_fit::effects::write_model(out, &model, prepared.as_ref().map(|p| p.records.as_slice()))?;
    print_report(&model, out);
    let identified = if prepared.is_some() {
        format!(", the effects identified in {:.1} s", effects_s - read_s)
    } else {
        String::new()
    };
    println!(
        "read {} groups in {read_s:.1} s{identified}, features and targets in {:.1} s, searches and validation in {:.1} s",
        samples.len(),
        features_s - effects_s,
        started.elapsed().as_secs_f64() - features_s
    );

    if let Some(path) = &args.export_rust {
        sts_dataset::output::write_file(path, model.rust_source(&dataset_name(&args.data)).as_bytes())?;
        println!("Rust source written to {}", path.display());
    }
    if let Some(path) = &args.export_c {
        sts_dataset::output::write_file(path, model.c_source(&dataset_name(&args.data)).as_bytes())?;
        println!("C source written to {}", path.display());
    }
    Ok(())
}

/// The dataset's directory name (not its full path: model files carry no machine paths).
fn dataset_name(path: &Path) -> String {
    path.canonicalize()
        .ok()
        .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .unwrap_or_else(|| path.display().to_string())
}

fn print_report(model: &ModelFile, out: &Path) {
    let v = &model.validation;
    // Six significant digits for reading; the model file holds the exact constants.
    println!("amplitude (um) = {}", model.amplitude.expr.to_infix_rounded(&FEATURE_LABELS, 6));
    println!(
        "  complexity {}, R^2 train {:.5}, held-out {:.5}",
        model.amplitude.complexity, model.amplitude.r2_train, v.amplitude_r2
    );
    println!("phase (deg)    = {}", model.phase.expr.to_infix_rounded(&FEATURE_LABELS, 6));
    println!(
        "  complexity {}, R^2 train {:.5}, held-out {:.5}",
        model.phase.complexity, model.phase.r2_train, v.phase_r2
    );
    println!("amplitude selection:\n{}", indent(&model.amplitude.selection));
    println!("phase selection:\n{}", indent(&model.phase.selection));
    println!(
        "held-out waveform error over {} groups ({} folds): mean absolute {:.1} nm, RMS {:.1} nm",
        v.groups.len(),
        v.folds,
        v.waveform_mae_um * 1e3,
        v.waveform_rms_um * 1e3
    );
    let mut worst: Vec<_> = v.groups.iter().collect();
    worst.sort_by(|a, b| b.waveform_rms_um.total_cmp(&a.waveform_rms_um));
    println!("worst held-out groups:");
    for g in worst.iter().take(5) {
        println!(
            "  {} ({} Hz, {} um): amplitude {:.3} vs {:.3} um, phase {:.2} vs {:.2} deg, RMS {:.1} nm",
            g.file,
            g.freq_hz,
            g.amp_um,
            g.predicted_amp_um,
            g.measured_amp_um,
            g.predicted_phase_deg,
            g.measured_phase_deg,
            g.waveform_rms_um * 1e3
        );
    }
    println!(
        "model written to {} (program id {:08x}, {} bytes of code)",
        out.display(),
        model.program.id,
        model.program.code_hex.len() / 2
    );
}

fn indent(text: &str) -> String {
    text.lines().map(|l| format!("  {l}\n")).collect()
}
