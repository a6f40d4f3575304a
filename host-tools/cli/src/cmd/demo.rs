//! `sts-twin demo`: the main job. Measures the emulated machine and fits the two twins the
//! tool makes: the paper's formula twin (amplitude and phase formulas of the accelerometer's
//! features, fitted on 1-40 Hz) and the range twin (the servo-axis twin `trial-table` fits
//! over 1-100 Hz, which predicts from the command). Then cuts the bicuspid surface at 40 Hz
//! with the firmware in QEMU in the loop, bare and with each twin, and prints them side by side.

use std::path::{Path, PathBuf};

use sts_emulator::{MeasureConfig, PlantParams};

use sts_fit::{fit, FitConfig};
use sts_hil::board::qemu::QemuBoard;
use sts_rig::trial::{calibrated, run_trial, TrialConfig};

use super::machine::{coprocessor, print_path, print_report};
use super::range_twin::fit_and_report;
use sts_twin_core::SERVO_RATE_HZ;

/// Arguments of `sts-twin demo`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Z operational frequency of the cut, Hz.
    #[arg(long, default_value_t = 40.0)]
    pub freq: f64,
    /// Use an existing model file as the formula twin instead of measuring and fitting one.
    #[arg(long)]
    pub twin: Option<PathBuf>,
    /// Where to keep the fitted formula twin.
    #[arg(long, default_value = DEFAULT_OUT)]
    pub out: PathBuf,
    /// Use an existing model file as the range twin instead of measuring the machine over
    /// 1-100 Hz and fitting one.
    #[arg(long)]
    pub range_twin: Option<PathBuf>,
    /// Where to keep the fitted range twin.
    #[arg(long, default_value = DEFAULT_RANGE_OUT)]
    pub range_out: PathBuf,
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
    /// Replace an existing output named on the command line (the default --out is replaced
    /// without it; never one of the command's inputs).
    #[arg(long)]
    pub force: bool,
}

/// Where the fitted formula twin goes without --out.
const DEFAULT_OUT: &str = "target/demo-twin.json";
/// Where the fitted range twin goes without --range-out.
const DEFAULT_RANGE_OUT: &str = "target/demo-range-twin.json";

/// Runs `sts-twin demo`.
pub fn run(args: &Args) -> anyhow::Result<()> {
    let plant = PlantParams::default();
    if args.twin.is_none() {
        sts_dataset::output::check_file(&args.out, args.force || args.out == Path::new(DEFAULT_OUT), &[])?;
    }
    if args.range_twin.is_none() {
        sts_dataset::output::check_file(
            &args.range_out,
            args.force || args.range_out == Path::new(DEFAULT_RANGE_OUT),
            &[],
        )?;
    }
    let formula_twin = match &args.twin {
        Some(path) => sts_model::ModelFile::read(path)?,
        None => {
            println!("the paper's formula twin:");
            let model = measure_and_fit(args.seed, &args.out)?;
            println!("{}", fit_summary(&model, &args.out));
            model
        }
    };
    let range_twin = match &args.range_twin {
        Some(path) => sts_model::ModelFile::read(path)?,
        None => {
            println!("the range twin:");
            fit_and_report(&plant, &[], args.seed, &args.range_out, "demo: servo-axis twin over 1-100 Hz", false)?
        }
    };
    let which = if args.sim { "the core simulated on the host" } else { "the firmware in QEMU" };
    eprintln!(
        "cutting the bicuspid surface at {} Hz with {which} in the loop: bare, then with each twin ...",
        args.freq
    );
    let window_samples = args.window_s.map(|s| ((s * f64::from(SERVO_RATE_HZ)) as u32 / 16) * 16);
    let config = TrialConfig { freq_hz: args.freq, seed: args.seed, window_samples, ..TrialConfig::default() };
    let cuts = [
        ("bare machine", None),
        ("the paper's formula twin", Some(&formula_twin)),
        ("the range twin", Some(&range_twin)),
    ];
    let mut reports = Vec::new();
    for (name, twin) in cuts {
        println!("{name}:");
        let mut cop = coprocessor(args.sim, args.board)?;
        // Calibrated first, as a lab does: offset and K_dv, and the analogue path for a twin.
        let (params, points) = calibrated(cop.as_mut(), &plant, &[], args.seed, twin.is_some() && !args.no_path)?;
        if !points.is_empty() {
            print_path(&points);
        }
        let report = run_trial(cop.as_mut(), &plant, &[], twin, params, &config)?;
        print_report(&report);
        reports.push((name, report));
    }
    let bare_pv_um = reports[0].1.form_error_pv_um;
    println!("\n{:.0} Hz cut                 form error PV          phase error", args.freq);
    for (name, report) in &reports {
        let less = if report.twin {
            format!("({:.1}% less)", 100.0 * (1.0 - report.form_error_pv_um / bare_pv_um))
        } else {
            String::new()
        };
        println!("{name:<26} {:>7.3} um {less:<12}  {:>+7.3} deg", report.form_error_pv_um, report.phase_error_deg);
    }
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

/// An R^2 for people: four decimals, or `undefined` where the validation has none (the
/// formulas beside a servo-axis twin can have nothing left to score).
fn r2_text(r2: f64) -> String {
    if r2.is_finite() {
        format!("{r2:.4}")
    } else {
        "undefined".to_string()
    }
}

/// The fitted twin's formulas and held-out errors, in lines for people.
pub fn fit_summary(model: &sts_model::ModelFile, out: &std::path::Path) -> String {
    format!(
        "amplitude (um) = {}\nphase (deg)    = {}\nheld-out: amplitude R^2 {}, phase R^2 {}, waveform error {:.1} nm mean absolute ({} written)",
        model.amplitude.formula,
        model.phase.formula,
        r2_text(model.validation.amplitude_r2),
        r2_text(model.validation.phase_r2),
        model.validation.waveform_mae_um * 1e3,
        out.display()
    )
}
