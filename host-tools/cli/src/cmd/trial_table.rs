//! `sts-twin trial-table`: the bicuspid cut at several Z frequencies, without and with the
//! twin, as a Markdown table (the README's table is this command's output).

use std::path::PathBuf;

use serde::Serialize;

use sts_hil::board::qemu::QemuBoard;
use sts_model::ModelFile;
use sts_rig::trial::{calibrated, run_trial, TrialConfig, TrialReport};

use super::machine::{coprocessor, MachineArgs};
use super::range_twin::fit_and_report;

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
    #[arg(long, default_value = super::range_twin::DEFAULT_OUT)]
    pub out: PathBuf,
    /// The emulated machine.
    #[command(flatten)]
    pub machine: MachineArgs,
    /// Run the core on the host instead of the firmware in QEMU (bit-identical, faster).
    #[arg(long)]
    pub sim: bool,
    /// The QEMU board the firmware runs on: `mps2-an386` (Cortex-M4F), `mps2-an500`
    /// (Cortex-M7) or `riscv-virt` (RV32IMAC).
    #[arg(long, default_value = "mps2-an386", value_parser = super::hil::parse_board)]
    pub board: QemuBoard,
    /// Seed of the machine's noise (and of the fit, without `--twin`).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print the rows as JSON instead of a Markdown table (stdout holds the JSON only; the
    /// fit's and the trials' progress go to stderr).
    #[arg(long)]
    pub json: bool,
    /// Replace an existing output named on the command line (the default --out is replaced
    /// without it; never one of the command's inputs).
    #[arg(long)]
    pub force: bool,
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

/// Runs `sts-twin trial-table`.
pub fn run(args: &Args) -> anyhow::Result<()> {
    let (plant, effects) = args.machine.load()?;
    if let Some(bad) = args.freqs.iter().find(|f| !(f.is_finite() && **f > 0.0 && **f < 4000.0)) {
        anyhow::bail!("--freqs: {bad} Hz is not a Z frequency the servo can follow (0 < f < 4000)");
    }
    if args.twin.is_none() {
        let inputs: Vec<&std::path::Path> = args.machine.plant.iter().map(PathBuf::as_path).collect();
        let force = args.force || args.out == std::path::Path::new(super::range_twin::DEFAULT_OUT);
        sts_dataset::output::check_file(&args.out, force, &inputs)?;
    }
    let model = match &args.twin {
        Some(path) => ModelFile::read(path)?,
        None => fit_and_report(
            &plant,
            &effects,
            args.seed,
            &args.out,
            "trial-table: servo-axis twin over 1-100 Hz",
            args.json,
        )?,
    };
    let mut rows = Vec::new();
    for &freq_hz in &args.freqs {
        let config = TrialConfig { freq_hz, seed: args.seed, ..TrialConfig::default() };
        // Each cut on a freshly booted co-processor, calibrated first as a lab does.
        eprintln!("{freq_hz} Hz: calibration, then the bare machine ...");
        let mut cop = coprocessor(args.sim, args.board)?;
        let (bare_params, _) = calibrated(cop.as_mut(), &plant, &effects, args.seed, false)?;
        let bare = run_trial(cop.as_mut(), &plant, &effects, None, bare_params, &config)?;
        eprintln!("{freq_hz} Hz: calibration with the analogue path, then the twin ...");
        let mut cop = coprocessor(args.sim, args.board)?;
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
