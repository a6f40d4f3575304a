//! `sts-twin trial-table`: the bicuspid cut at several Z frequencies, without and with the
//! twin, as a Markdown table (the README's table is this command's output).

use std::path::PathBuf;

use serde::Serialize;

use sts_assess::explain::{explain, Base, ExplainConfig};
use sts_emulator::{EffectSpec, MeasureConfig, PlantParams};
use sts_fit::effects::{fit_with, write_records, AXIS_EFFECTS, SERVO_AXIS};
use sts_fit::{fit, FitConfig};
use sts_model::ModelFile;
use sts_rig::trial::{calibrated, run_trial, TrialConfig, TrialReport};

use super::machine::{coprocessor, MachineArgs};

/// Arguments of `sts-twin trial-table`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Z operational frequencies, Hz, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "5,10,20,30,40,60,80")]
    pub freqs: Vec<f64>,
    /// Model file of the twin; without it the machine is measured over its whole range
    /// (1, 5, 10, ..., 100 Hz x 1..11 um), a servo-axis twin fitted (`fit --effect
    /// servo-axis`), the effects the data shows added as `explain` adds them (friction,
    /// hysteresis, a ripple, ...), and the twin written to `--out`.
    #[arg(long)]
    pub twin: Option<PathBuf>,
    /// Where a fitted model is written.
    #[arg(long, default_value = "target/range-twin.json")]
    pub out: PathBuf,
    /// The emulated machine.
    #[command(flatten)]
    pub machine: MachineArgs,
    /// Run the core on the host instead of the firmware in QEMU (bit-identical, faster).
    #[arg(long)]
    pub sim: bool,
    /// Seed of the machine's noise (and of the fit, without `--twin`).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print the rows as JSON instead of a Markdown table (stdout holds the JSON only; the
    /// fit's and the trials' progress go to stderr).
    #[arg(long)]
    pub json: bool,
}

/// One frequency of the table.
#[derive(Debug, Serialize)]
pub struct Row {
    /// The bare machine's cut.
    pub bare: TrialReport,
    /// The cut with the twin.
    pub twin: TrialReport,
    /// Form error reduction, percent.
    pub reduction_pct: f64,
    /// What the co-processor did in the twin's cut ([`TrialReport::compensation_summary`]).
    pub compensation: String,
}

/// Z frequencies of the measurement a twin for the whole range is fitted on, Hz.
fn range_freqs_hz() -> Vec<f64> {
    std::iter::once(1.0).chain((1..=20).map(|k| 5.0 * f64::from(k))).collect()
}

/// Measures `plant` with `effects` over [`range_freqs_hz`], fits the servo-axis twin with
/// formulas on what it leaves, and from it lets `explain` add the effects the data shows
/// (the machine's own, which the tool is not told); writes the twin to `out`.
fn measure_and_fit_range(
    plant: &PlantParams,
    effects: &[EffectSpec],
    seed: u64,
    out: &std::path::Path,
) -> anyhow::Result<ModelFile> {
    let measure = MeasureConfig {
        plant: plant.clone(),
        effects: effects.to_vec(),
        seed,
        freqs_hz: range_freqs_hz(),
        ..MeasureConfig::default()
    };
    eprintln!(
        "measuring the machine over its range: {} groups, 1-100 Hz x 1-11 um, {:.0} s each ...",
        measure.freqs_hz.len() * measure.amps_um.len(),
        measure.duration_s
    );
    let dataset = sts_emulator::measure::run(&measure, &|_| {})?;
    eprintln!("fitting the servo-axis twin and the formulas on what it leaves ...");
    let prepared = sts_fit::effects::prepare(&dataset, &[SERVO_AXIS.to_string()])?;
    let description = "trial-table: servo-axis twin over 1-100 Hz";
    let fit_config = FitConfig { seed, ..FitConfig::default() };
    let model = fit(&prepared.dataset, description, &fit_config, &mut |_| {})?;
    let model = prepared.attach(model)?;
    eprintln!("{}", axis_summary(&prepared.records));
    eprintln!("diagnosing it and adding the effects the data shows, as `explain` does ...");
    let base = Base { model, effects: prepared.records };
    let config = ExplainConfig { fit: fit_config.clone(), max_effects: EXPLAIN_MAX_EFFECTS };
    let explanation = explain(&dataset, description, Some(base), &config, &mut |_| {})?;
    for step in &explanation.steps {
        eprintln!(
            "added {}: {:.1} -> {:.1} nm on the measurement",
            step.effect,
            step.waveform_rms_um_before * 1e3,
            step.waveform_rms_um_after * 1e3
        );
    }
    let named: Vec<String> = explanation.effects.iter().map(|r| r.effect.clone()).collect();
    let (mut model, records) = if named.iter().any(|n| AXIS_EFFECTS.contains(&n.as_str())) {
        // Friction, hysteresis and a ripple share the one axis twin, and on a measurement of
        // the whole range the diagnosis tells them apart less surely than it tells them from
        // nothing (a friction machine's was named hysteresis): the twin with all three is
        // fitted too, and the one that predicts the measurement better, held out, is kept.
        let names: Vec<String> = named
            .iter()
            .filter(|n| **n != SERVO_AXIS && !AXIS_EFFECTS.contains(&n.as_str()))
            .cloned()
            .chain(AXIS_EFFECTS.iter().map(|n| n.to_string()))
            .collect();
        eprintln!("fitting the axis twin with {} too ...", names.join(", "));
        let (all_three, all_records) = fit_with(&dataset, &names, description, &fit_config, &mut |_| {})?;
        let (explained_um, all_three_um) =
            (explanation.model.validation.waveform_rms_um, all_three.validation.waveform_rms_um);
        eprintln!(
            "held out: {:.1} nm with {}, {:.1} nm with all three",
            explained_um * 1e3,
            named.join(", "),
            all_three_um * 1e3
        );
        if all_three_um < explained_um {
            (all_three, all_records)
        } else {
            (explanation.model, explanation.effects)
        }
    } else {
        (explanation.model, explanation.effects)
    };
    let carried: Vec<&str> = records.iter().map(|r| r.effect.as_str()).filter(|n| *n != SERVO_AXIS).collect();
    if !carried.is_empty() {
        model.description = format!("{description}, with {}", carried.join(", "));
    }
    if let Some(dir) = out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    model.write(out)?;
    write_records(out, &records)?;
    Ok(model)
}

/// Effects `trial-table` lets `explain` add at most (as `explain --max-effects` does).
const EXPLAIN_MAX_EFFECTS: usize = 4;

/// The identified servo axis in a line for people.
fn axis_summary(records: &[sts_fit::effects::EffectRecord]) -> String {
    let params: Vec<String> =
        records.iter().flat_map(|r| r.params.iter()).map(|(name, value)| format!("{name} {value:.4}")).collect();
    format!("servo-axis twin: {}", params.join(", "))
}

/// Runs `sts-twin trial-table`.
pub fn run(args: &Args) -> anyhow::Result<()> {
    let (plant, effects) = args.machine.load()?;
    if let Some(bad) = args.freqs.iter().find(|f| !(f.is_finite() && **f > 0.0 && **f < 4000.0)) {
        anyhow::bail!("--freqs: {bad} Hz is not a Z frequency the servo can follow (0 < f < 4000)");
    }
    let model = match &args.twin {
        Some(path) => ModelFile::read(path)?,
        None => {
            let model = measure_and_fit_range(&plant, &effects, args.seed, &args.out)?;
            // With --json, stdout holds the JSON only.
            let summary = super::demo::fit_summary(&model, &args.out);
            if args.json {
                eprintln!("{summary}");
            } else {
                println!("{summary}");
            }
            model
        }
    };
    let mut rows = Vec::new();
    for &freq_hz in &args.freqs {
        let config = TrialConfig { freq_hz, seed: args.seed, ..TrialConfig::default() };
        // Each cut on a freshly booted co-processor, calibrated first as a lab does.
        eprintln!("{freq_hz} Hz: calibration, then the bare machine ...");
        let mut cop = coprocessor(args.sim)?;
        let (bare_params, _) = calibrated(cop.as_mut(), &plant, &effects, args.seed, false)?;
        let bare = run_trial(cop.as_mut(), &plant, &effects, None, bare_params, &config)?;
        eprintln!("{freq_hz} Hz: calibration with the analogue path, then the twin ...");
        let mut cop = coprocessor(args.sim)?;
        let (twin_params, _) = calibrated(cop.as_mut(), &plant, &effects, args.seed, true)?;
        let twin = run_trial(cop.as_mut(), &plant, &effects, Some(&model), twin_params, &config)?;
        let reduction_pct = 100.0 * (1.0 - twin.form_error_pv_um / bare.form_error_pv_um);
        let compensation = twin.compensation_summary();
        rows.push(Row { bare, twin, reduction_pct, compensation });
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    let which = if args.sim { "sim (the core on the host)" } else { "hil (the firmware in QEMU)" };
    println!(
        "| Z frequency | form error PV, bare | with the twin | reduction | phase error, bare | with the twin | \
         compensation in the cut |"
    );
    println!("|---|---|---|---|---|---|---|");
    for row in &rows {
        println!(
            "| {:.0} Hz | {:.3} um | {:.3} um | {:.1}% | {:+.2} deg | {:+.2} deg | {} |",
            row.bare.freq_hz,
            row.bare.form_error_pv_um,
            row.twin.form_error_pv_um,
            row.reduction_pct,
            row.bare.phase_error_deg,
            row.twin.phase_error_deg,
            row.compensation
        );
    }
    println!("\nCo-processor: {which}; model: {}; machine seed {}.", model.description, args.seed);
    Ok(())
}
