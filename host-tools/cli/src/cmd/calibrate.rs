//! `sts-twin calibrate-offset`: the calibration before a cut (offset, `K_dv`, analogue path),
//! stored in the co-processor's config and verified after a reboot.

use std::io::Write as _;
use std::path::PathBuf;

use anyhow::Context as _;

use crate::cmd::machine::MachineArgs;
use sts_hil::HilConfig;
use sts_rig::calibrate::{calibrate, CalibrationConfig, HilBoard};
use sts_rig::SimCoprocessor;

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
}

/// Runs `sts-twin calibrate-offset`.
pub fn run(args: &Args) -> anyhow::Result<()> {
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
        let hil_config = HilConfig { bus_path: args.bus.clone(), ..HilConfig::default() };
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
