//! `sts-twin demo`: the main job. Measures the emulated machine, fits the twin, then cuts the
//! bicuspid surface at 40 Hz with the firmware in QEMU in the loop, without and with the twin.

use std::path::PathBuf;

use sts_emulator::{MeasureConfig, PlantParams};

use sts_fit::{fit, FitConfig};
use sts_hil::board::qemu::QemuBoard;
use sts_rig::trial::{calibrated, run_trial, TrialConfig};

use super::machine::{coprocessor, print_path, print_report};
use sts_analysis::resample::SERVO_RATE_HZ;

/// Arguments of `sts-twin demo`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Z operational frequency of the cut, Hz.
    #[arg(long, default_value_t = 40.0)]
    pub freq: f64,
    /// Use an existing model file instead of measuring and fitting one.
    #[arg(long)]
    pub twin: Option<PathBuf>,
    /// Where to keep the fitted model.
    #[arg(long, default_value = "target/demo-twin.json")]
    pub out: PathBuf,
    /// Run the core on the host instead of the firmware in QEMU.
    #[arg(long)]
    pub sim: bool,
    /// The QEMU board the firmware runs on: `mps2-an386` (Cortex-M4F), `mps2-an500`
    /// (Cortex-M7) or `riscv-virt` (RV32IMAC).
    #[arg(long, default_value = "mps2-an386", value_parser = super::hil::parse_board)]
    pub board: QemuBoard,
    /// Seed of the measurement, the fit and the cut.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Feature window in the co-processor during the cut, seconds (default: four periods of
    /// the Z motion, at least 0.1 s). The twin is trained on 5 s windows of steady motion,
    /// whose features hardly depend on the window; during a cut the amplitude changes with
    /// the radius, and a short window follows it.
    #[arg(long)]
    pub window_s: Option<f64>,
    /// Do not measure the analogue path's phase before the twin's cut (Eq. 5 as the paper
    /// applies it, uncorrected for the path's lag).
    #[arg(long)]
    pub no_path: bool,
}

/// Runs `sts-twin demo`.
pub fn run(args: &Args) -> anyhow::Result<()> {
    let plant = PlantParams::default();
    let model = match &args.twin {
        Some(path) => sts_model::ModelFile::read(path)?,
        None => {
            let model = measure_and_fit(args.seed, &args.out)?;
            println!("{}", fit_summary(&model, &args.out));
            model
        }
    };
    let which = if args.sim { "the core simulated on the host" } else { "the firmware in QEMU" };
    eprintln!("3/3 cutting the bicuspid surface at {} Hz with {which} in the loop ...", args.freq);
    let window_samples = args.window_s.map(|s| ((s * SERVO_RATE_HZ) as u32 / 16) * 16);
    let config = TrialConfig { freq_hz: args.freq, seed: args.seed, window_samples, ..TrialConfig::default() };
    let mut reports = Vec::new();
    for twin in [None, Some(&model)] {
        let mut cop = coprocessor(args.sim, args.board)?;
        // Calibrated first, as a lab does: offset and K_dv, and the analogue path for the twin.
        let (params, points) = calibrated(cop.as_mut(), &plant, &[], args.seed, twin.is_some() && !args.no_path)?;
        if !points.is_empty() {
            print_path(&points);
        }
        let report = run_trial(cop.as_mut(), &plant, &[], twin, params, &config)?;
        print_report(&report);
        reports.push(report);
    }
    let (bare, twin) = (&reports[0], &reports[1]);
    println!(
        "form error {:.3} -> {:.3} um ({:.0}% less), phase error {:.2} -> {:.2} deg",
        bare.form_error_pv_um,
        twin.form_error_pv_um,
        100.0 * (1.0 - twin.form_error_pv_um / bare.form_error_pv_um),
        bare.phase_error_deg,
        twin.phase_error_deg
    );
    Ok(())
}

/// Measures the default emulated machine (the 99-group test), fits the twin and writes it to
/// `out` (progress on stderr).
pub fn measure_and_fit(seed: u64, out: &std::path::Path) -> anyhow::Result<sts_model::ModelFile> {
    eprintln!("measuring the emulated machine: 99 groups, 1-40 Hz x 1-11 um, 6 s each ...");
    let measure = MeasureConfig { seed, ..MeasureConfig::default() };
    let dataset = sts_emulator::measure::run(&measure, &|_| {})?;
    eprintln!("fitting the twin (symbolic regression, cross-validated) ...");
    let model =
        fit(&dataset, "demo: default emulated machine", &FitConfig { seed, ..FitConfig::default() }, &mut |_| {})?;
    if let Some(dir) = out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    model.write(out)?;
    Ok(model)
}

/// The fitted twin's formulas and held-out errors, in lines for people.
pub fn fit_summary(model: &sts_model::ModelFile, out: &std::path::Path) -> String {
    format!(
        "amplitude (um) = {}\nphase (deg)    = {}\nheld-out: amplitude R^2 {:.4}, phase R^2 {:.4}, waveform error {:.1} nm mean absolute ({} written)",
        model.amplitude.formula,
        model.phase.formula,
        model.validation.amplitude_r2,
        model.validation.phase_r2,
        model.validation.waveform_mae_um * 1e3,
        out.display()
    )
}
