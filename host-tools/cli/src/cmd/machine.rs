//! `sts-twin machine`: an emulated STS cut of the bicuspid surface, with or without the twin.

use std::path::PathBuf;

use anyhow::Context as _;
use sts_emulator::{EffectSpec, PlantParams};

use sts_hil::board::qemu::QemuBoard;
use sts_hil::HilConfig;
use sts_model::ModelFile;
use sts_rig::calibrate::PathPoint;
use sts_rig::trial::{calibrated, run_trial, stored_params, TrialConfig, TrialReport};
use sts_twin_core::SERVO_RATE_HZ;

use super::range_twin::fit_and_report;
use sts_rig::{Coprocessor, HilCoprocessor, SimCoprocessor};

/// Arguments of `sts-twin machine`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Z operational frequency, Hz (the spindle turns at half of it).
    #[arg(long, default_value_t = 40.0)]
    pub freq: f64,
    /// Model file of the twin. Without it (and without `--bare`) the machine is measured over
    /// its whole range and its twin fitted by itself, as `trial-table` does (the servo-axis
    /// twin and the effects the data shows, 20-200 s), written to `--out`, then the cut.
    #[arg(long)]
    pub twin: Option<PathBuf>,
    /// Cut the bare machine: no twin, nothing fitted.
    #[arg(long, conflicts_with = "twin")]
    pub bare: bool,
    /// Where the twin fitted without `--twin` is written.
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
    /// Offset voltage set in the co-processor, V, in place of the one the calibration before
    /// the cut measures (offset, K_dv and, for a twin, the analogue path, as
    /// `calibrate-offset` does).
    #[arg(long)]
    pub offset: Option<f64>,
    /// Seed of the machine's noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Feature window in the co-processor, seconds (default: four periods of the Z motion, at
    /// least 0.1 s).
    #[arg(long)]
    pub window_s: Option<f64>,
    /// Do not measure the analogue path's phase in the calibration before the twin's cut (Eq.
    /// 5 as the paper applies it, uncorrected for the path's lag).
    #[arg(long)]
    pub no_path: bool,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
    /// Write an HTML report (figures, surface map and error map over the disc) to this file.
    #[arg(long)]
    pub html: Option<PathBuf>,
    /// Cut with the calibration stored in this QEMU board memory file by
    /// `sts-twin calibrate-offset --bus FILE` (offset, K_dv, analogue path), as a machinist
    /// calibrates once and then cuts, instead of a calibration run here before the cut.
    #[arg(long, conflicts_with_all = ["sim", "offset", "no_path"])]
    pub bus: Option<PathBuf>,
    /// Replace an existing output named on the command line (the default --out is replaced
    /// without it; never one of the command's inputs).
    #[arg(long)]
    pub force: bool,
}

/// The emulated machine named on a command line: plant parameters and hidden effects.
#[derive(Debug, clap::Args)]
pub struct MachineArgs {
    /// Plant parameters (TOML); default: the built-in machine.
    #[arg(long)]
    pub plant: Option<PathBuf>,
    /// A physical effect in the machine, `NAME[:k=v,...]` (repeatable).
    #[arg(long = "effect")]
    pub effects: Vec<String>,
}

impl MachineArgs {
    /// Loads the plant parameters and parses the effects.
    pub fn load(&self) -> anyhow::Result<(PlantParams, Vec<EffectSpec>)> {
        load_plant(self.plant.as_ref(), &self.effects)
    }
}

/// Loads the plant parameters and effects named on a command line.
pub fn load_plant(plant: Option<&PathBuf>, effects: &[String]) -> anyhow::Result<(PlantParams, Vec<EffectSpec>)> {
    let params = match plant {
        Some(path) => PlantParams::from_file(path)?,
        None => PlantParams::default(),
    };
    let effects = effects
        .iter()
        .map(|text| text.parse::<EffectSpec>().with_context(|| format!("--effect {text}")))
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok((params, effects))
}

/// Boots the co-processor the user asked for: the core on the host, or the firmware on
/// `board` in QEMU.
pub fn coprocessor(sim: bool, board: QemuBoard) -> anyhow::Result<Box<dyn Coprocessor>> {
    Ok(if sim {
        Box::new(SimCoprocessor::boot(&[]))
    } else {
        Box::new(HilCoprocessor::start(HilConfig { board, ..HilConfig::default() })?)
    })
}

/// Boots the firmware on `board` in QEMU on an existing board memory file (its config store).
fn stored_calibration_board(bus: &std::path::Path, board: QemuBoard) -> anyhow::Result<Box<dyn Coprocessor>> {
    if !bus.is_file() {
        anyhow::bail!(
            "--bus {}: no such board memory file; calibrate first: sts-twin calibrate-offset --bus {}",
            bus.display(),
            bus.display()
        );
    }
    Ok(Box::new(HilCoprocessor::start(HilConfig { bus_path: Some(bus.to_path_buf()), board, ..HilConfig::default() })?))
}

/// Prints a measured analogue path for people.
pub fn print_path(points: &[PathPoint]) {
    eprintln!(
        "analogue path (DAC -> TCP) gain and phase: {}",
        path_text(points.iter().map(|p| (p.freq_hz, p.gain, p.phase_deg)))
    );
}

/// An analogue-path table as `5 Hz 1.002 +0.05 deg, 10 Hz ...` (`none` when empty; a gain
/// of 0 is not measured and left out).
fn path_text(points: impl Iterator<Item = (f64, f64, f64)>) -> String {
    let cells: Vec<String> = points
        .map(|(freq_hz, gain, phase_deg)| match gain > 0.0 {
            true => format!("{freq_hz:.0} Hz {gain:.3} {phase_deg:+.2} deg"),
            false => format!("{freq_hz:.0} Hz {phase_deg:+.2} deg"),
        })
        .collect();
    if cells.is_empty() {
        "none".to_string()
    } else {
        cells.join(", ")
    }
}

/// Prints a trial report for people.
pub fn print_report(report: &TrialReport) {
    println!(
        "{:>5.1} Hz  twin {:<5}  form error (PV) {:>7.3} um  RMS {:>6.3} um  phase error {:>6.2} deg  ({}, {} points, cut {:.1} s; {:.1} s of machine time in {:.2} s)",
        report.freq_hz,
        report.twin,
        report.form_error_pv_um,
        report.form_error_rms_um,
        report.phase_error_deg,
        report.coprocessor,
        report.points,
        report.cut_time_s,
        report.machine_time_s,
        report.wall_time_s
    );
}

/// Runs `sts-twin machine`.
pub fn run(args: &Args) -> anyhow::Result<()> {
    let mut inputs: Vec<&std::path::Path> =
        args.twin.iter().chain(&args.machine.plant).chain(&args.bus).map(PathBuf::as_path).collect();
    inputs.retain(|p| p.exists());
    if args.twin.is_none() && !args.bare {
        let force = args.force || args.out == std::path::Path::new(super::range_twin::DEFAULT_OUT);
        sts_dataset::output::check_file(&args.out, force, &inputs)?;
    }
    if let Some(html) = &args.html {
        sts_dataset::output::check_file(html, args.force, &inputs)?;
    }
    let (plant, effects) = args.machine.load()?;
    let model = match (&args.twin, args.bare) {
        (Some(path), _) => Some(ModelFile::read(path)?),
        (None, true) => None,
        (None, false) => Some(fit_and_report(
            &plant,
            &effects,
            args.seed,
            &args.out,
            "machine: servo-axis twin over 1-100 Hz",
            args.json,
        )?),
    };
    let window_samples = args.window_s.map(|s| ((s * f64::from(SERVO_RATE_HZ)) as u32 / 16) * 16);
    let config = TrialConfig { freq_hz: args.freq, seed: args.seed, window_samples, ..TrialConfig::default() };
    let mut cop = match &args.bus {
        Some(bus) => stored_calibration_board(bus, args.board)?,
        None => coprocessor(args.sim, args.board)?,
    };
    let params = if let Some(bus) = &args.bus {
        let stored = stored_params(cop.as_mut()).with_context(|| format!("--bus {}", bus.display()))?;
        if !args.json {
            eprintln!(
                "stored calibration: offset {:+.3} mV, K_dv {:.4} um/V, analogue path {}",
                f64::from(stored.offset_v) * 1e3,
                stored.k_dv_um_per_v,
                path_text(stored.analogue_path.points().map(|(freq_hz, gain, phase_deg)| (
                    f64::from(freq_hz),
                    f64::from(gain),
                    f64::from(phase_deg)
                )))
            );
        }
        stored
    } else {
        // Calibrated first, as a lab does: offset and K_dv, and the analogue path for a twin.
        let with_path = model.is_some() && !args.no_path;
        let (mut params, points) = calibrated(cop.as_mut(), &plant, &effects, args.seed, with_path)?;
        if let Some(offset_v) = args.offset {
            params.offset_v = offset_v as f32;
        }
        if !args.json && !points.is_empty() {
            print_path(&points);
        }
        params
    };
    let report = run_trial(cop.as_mut(), &plant, &effects, model.as_ref(), params, &config)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print_report(&report);
        if model.is_some() {
            // Where the cut's ticks went: the gate holds compensation off at the centre.
            println!("compensation over the cut's ticks: {}", report.compensation_summary());
        }
    }
    if let Some(path) = &args.html {
        let title = format!(
            "bicuspid cut at {} Hz, {}",
            report.freq_hz,
            if report.twin { "with the twin" } else { "bare machine" }
        );
        sts_dataset::output::write_file(
            path,
            crate::report::trial::render(&title, std::slice::from_ref(&report)).as_bytes(),
        )?;
        if !args.json {
            eprintln!("report written to {}", path.display());
        }
    }
    if model.is_some() {
        sts_rig::print_fault_report(cop.as_mut())?; // every fault the co-processor counted, on stderr
    }
    Ok(())
}
