//! `sts-twin calibrate-offset`: the calibration before a cut (offset, `K_dv`, analogue path),
//! stored in the co-processor's config and verified after a reboot.

use std::io::Write as _;
use std::path::PathBuf;

use anyhow::Context as _;

use crate::cmd::machine::MachineArgs;
use sts_hil::board::qemu::QemuBoard;
use sts_hil::HilConfig;
use sts_rig::calibrate::{
    calibrate, calibrate_lab, CalibrationConfig, CommandInstruments, HilBoard, LabConfig, PromptInstruments,
};
use sts_rig::{SerialCoprocessor, SimCoprocessor};

/// Arguments of `sts-twin calibrate-offset`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Run the core on the host instead of the firmware in QEMU (its config store is then
    /// in memory and ends with the command).
    #[arg(long)]
    pub sim: bool,
    /// The emulated machine.
    #[command(flatten)]
    pub machine: MachineArgs,
    /// Seed of the machine's noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// The QEMU board the firmware runs on: `mps2-an386` (Cortex-M4F), `mps2-an500`
    /// (Cortex-M7) or `riscv-virt` (RV32IMAC).
    #[arg(long, default_value = "mps2-an386", value_parser = super::hil::parse_board, conflicts_with = "port")]
    pub board: QemuBoard,
    /// The QEMU board's memory file, which holds its config store: created if missing and
    /// kept, so that the calibration outlives the command (default: a file that ends with it).
    #[arg(long, conflicts_with = "sim")]
    pub bus: Option<PathBuf>,
    /// Frequencies of the analogue path's measurement, Hz, comma-separated (at most 8;
    /// default 5,10,20,30,40,50,60,80).
    #[arg(long, value_delimiter = ',')]
    pub path_freqs: Option<Vec<f64>>,
    /// Amplitude of the analogue path's measurement sine, um (default 8: large enough that
    /// the slide slides rather than sticks).
    #[arg(long)]
    pub path_amp_um: Option<f64>,
    /// Do not measure the analogue path (an empty table is stored: no phase correction).
    #[arg(long, conflicts_with_all = ["path_freqs", "path_amp_um"])]
    pub no_path: bool,
    /// Print the result as JSON.
    #[arg(long)]
    pub json: bool,
    /// Calibrate a board on this serial port on the lab's own machine instead of the emulated
    /// one: the offset and K_dv from the controller's readings and the probe at the tool
    /// (asked for on the terminal, or printed by the commands below); the analogue path is
    /// not measured this way.
    #[arg(long, value_name = "DEV", conflicts_with_all = ["sim", "bus", "path_freqs", "path_amp_um"])]
    pub port: Option<String>,
    /// The board's baud rate (with --port).
    #[arg(long, default_value_t = sts_link::DEFAULT_BAUD, requires = "port")]
    pub baud: u32,
    /// A command that prints the motion controller's reading of its analogue input, V (with
    /// --port; the board's output voltage is in STS_TWIN_DAC_V). Without it, you are asked.
    #[arg(long, value_name = "CMD", requires = "port")]
    pub controller_reading_cmd: Option<String>,
    /// A command that switches the controller's analogue feedforward input on (with --port).
    /// Without it, you are asked to, and to press Enter.
    #[arg(long, value_name = "CMD", requires = "port")]
    pub feedforward_on_cmd: Option<String>,
    /// A command that prints the probe's reading at the tool, um (with --port). Without it,
    /// you are asked.
    #[arg(long, value_name = "CMD", requires = "port")]
    pub probe_cmd: Option<String>,
}

/// Runs `sts-twin calibrate-offset`.
pub fn run(args: &Args) -> anyhow::Result<()> {
    if let Some(port) = &args.port {
        return run_on_port(args, port);
    }
    let (plant, effects) = args.machine.load()?;
    let mut config = CalibrationConfig::full();
    if args.no_path {
        config.path = None;
    } else if let Some(path) = &mut config.path {
        if let Some(freqs_hz) = &args.path_freqs {
            path.freqs_hz = freqs_hz.clone();
        }
        if let Some(amp_um) = args.path_amp_um {
            if !(amp_um.is_finite() && amp_um > 0.0) {
                anyhow::bail!("--path-amp-um must be a positive number of micrometres, not {amp_um}");
            }
            path.amp_um = amp_um;
        }
    }
    let quiet = args.json;
    let mut progress = |line: &str| {
        if !quiet {
            eprintln!("{line}");
        }
    };
    let report = if args.sim {
        let mut board = SimCoprocessor::boot(&[]);
        calibrate(&mut board, &plant, &effects, args.seed, &config, &mut progress)?
    } else {
        let hil_config = HilConfig { bus_path: args.bus.clone(), board: args.board, ..HilConfig::default() };
        let mut board = HilBoard::start(hil_config)?;
        let result = calibrate(&mut board, &plant, &effects, args.seed, &config, &mut progress);
        let stopped = board.shutdown();
        let report = result?;
        stopped?;
        report
    };
    let text = if args.json {
        serde_json::to_string_pretty(&report).context("encoding the JSON report")?
    } else {
        report.to_string()
    };
    writeln!(std::io::stdout().lock(), "{text}").context("writing the report")?;
    if !report.verified {
        anyhow::bail!("the calibration is not verified: {}", report.failures().join("; "));
    }
    Ok(())
}

/// `calibrate-offset --port`: the lab calibration of a board on a serial port.
fn run_on_port(args: &Args, port: &str) -> anyhow::Result<()> {
    let board = super::board::connect_port(port, args.baud, 5.0)?;
    let mut cop = SerialCoprocessor::new(board);
    let quiet = args.json;
    let mut progress = |line: &str| {
        if !quiet {
            eprintln!("{line}");
        }
    };
    let config = LabConfig::default();
    let report = match (&args.controller_reading_cmd, &args.probe_cmd) {
        (Some(controller_reading), Some(tool_position)) => {
            let mut commands = CommandInstruments {
                controller_reading: controller_reading.clone(),
                feedforward_on: args.feedforward_on_cmd.clone(),
                tool_position: tool_position.clone(),
            };
            calibrate_lab(&mut cop, &mut commands, &config, &mut progress)?
        }
        (None, None) if args.feedforward_on_cmd.is_none() => {
            let mut prompt = PromptInstruments::new(std::io::stdin().lock(), std::io::stderr());
            calibrate_lab(&mut cop, &mut prompt, &config, &mut progress)?
        }
        _ => anyhow::bail!(
            "give both --controller-reading-cmd and --probe-cmd (and optionally --feedforward-on-cmd), or none of them to be asked for each reading"
        ),
    };
    let text = if args.json {
        serde_json::to_string_pretty(&report).context("encoding the JSON report")?
    } else {
        format!("{}: calibrated\n{report}", cop.board().describe())
    };
    writeln!(std::io::stdout().lock(), "{text}").context("writing the report")?;
    Ok(())
}
