//! `sts-twin hil`: the firmware under QEMU on its own: boot it and read its status, or
//! benchmark the rig (instructions per servo tick, lockstep and open-loop throughput).

use std::path::PathBuf;

use sts_twin_core::wire::{Request, Response};

use sts_hil::board::qemu::Mps2Image;
use sts_hil::{bench_instructions_prepared, bench_throughput, FirmwareVariant, HilConfig};
use sts_rig::{request_on, Coprocessor, HilCoprocessor};

/// Arguments of `sts-twin hil`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// What to do.
    #[command(subcommand)]
    pub action: Action,
    /// The firmware ELF (default: `STS_TWIN_FIRMWARE_ELF`, or built from this workspace).
    #[arg(long, global = true)]
    pub firmware: Option<PathBuf>,
    /// Boot the platform's bring-up application instead of the twin.
    #[arg(long, global = true)]
    pub bringup: bool,
    /// Print the firmware's decoded log lines as they arrive.
    #[arg(long, global = true)]
    pub logs: bool,
    /// The emulated board: `an386` (Cortex-M4F) or `an500` (Cortex-M7, the STM32H7's core).
    /// The same firmware image runs on both.
    #[arg(long, global = true, value_enum, default_value_t = Board::An386)]
    pub board: Board,
}

/// The QEMU boards the firmware runs on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Board {
    /// MPS2 AN386: Cortex-M4F.
    An386,
    /// MPS2 AN500: Cortex-M7.
    An500,
}

impl From<Board> for Mps2Image {
    fn from(board: Board) -> Self {
        match board {
            Board::An386 => Mps2Image::An386,
            Board::An500 => Mps2Image::An500,
        }
    }
}

/// `sts-twin hil` actions.
#[derive(Debug, clap::Subcommand)]
pub enum Action {
    /// Boot the firmware, print its status (counters, parameters, config source), end QEMU.
    Status {
        /// A named bus file whose config store is kept across runs (default: a fresh one).
        #[arg(long)]
        bus_file: Option<PathBuf>,
        /// Print the status as JSON-like debug output instead of a summary.
        #[arg(long)]
        raw: bool,
    },
    /// Measure instructions per servo tick and HIL throughput.
    Bench {
        /// Ticks per measurement.
        #[arg(long, default_value_t = 20_000)]
        ticks: u32,
        /// Upload this model's program and enable compensation before counting instructions
        /// (with a 2,000-sample feature window, so that model updates happen during the run).
        #[arg(long)]
        model: Option<PathBuf>,
    },
}

fn config(args: &Args) -> HilConfig {
    HilConfig {
        elf: args.firmware.clone(),
        variant: if args.bringup { FirmwareVariant::BringUp } else { FirmwareVariant::Twin },
        echo_logs: args.logs || HilConfig::default().echo_logs,
        board: args.board.into(),
        ..HilConfig::default()
    }
}

/// Runs `sts-twin hil`.
pub fn run(args: &Args) -> anyhow::Result<()> {
    match &args.action {
        Action::Status { bus_file, raw } => {
            if args.bringup {
                anyhow::bail!(
                    "`hil status` needs the twin firmware (the bring-up application has no control protocol)"
                );
            }
            let mut cop = HilCoprocessor::start(HilConfig { bus_path: bus_file.clone(), ..config(args) })?;
            let answer = cop.request(Request::GetStatus);
            let diagnostics = cop.hil().diagnostics();
            cop.shutdown()?;
            let Response::Status(status) = answer? else {
                anyhow::bail!("the firmware did not answer GetStatus with a status");
            };
            if *raw {
                println!("{status:#?}");
                println!("{diagnostics:#?}");
                return Ok(());
            }
            let c = &status.counters;
            let board = Mps2Image::from(args.board);
            println!("board: QEMU {} ({})", board.qemu_machine(), board.core());
            println!("config: {:?}", status.config_source);
            println!(
                "compensation: {} (gain {:.3}), program {:?} (staged {:?}), inputs {}",
                if status.enabled { "enabled" } else { "disabled" },
                status.gain,
                status.program_id,
                status.staged_program_id,
                if status.degraded == 0 {
                    "trusted".to_string()
                } else {
                    format!("degraded (bits {:#06b})", status.degraded)
                }
            );
            let p = &status.params;
            println!(
                "feedforward: K_dv {} um/V, K_vc {} pulses/V, offset {} V, slew {} V/tick, DAC full scale {} V, enable ramp {} ticks, analogue-path points {}",
                p.k_dv_um_per_v, p.k_vc_pulses_per_v, p.offset_v, p.slew_v_per_tick, p.dac_full_scale_v, p.enable_ramp_ticks, p.analogue_path.count
            );
            println!(
                "features: window {} samples at {} Hz, {} m/s^2 per LSB",
                status.feature_config.window_samples,
                status.feature_config.sample_rate_hz,
                status.feature_config.acc_mps2_per_lsb
            );
            println!("counters: {c:?}");
            Ok(())
        }
        Action::Bench { ticks, model } => {
            let model = model.as_ref().map(|path| sts_model::ModelFile::read(path)).transpose()?;
            let requests = match &model {
                Some(model) => {
                    let features =
                        sts_twin_core::features::FeatureConfig { window_samples: 2000, ..model.feature_config };
                    // The bench's inputs are a command ramp, not a cut: the supervisor would
                    // hold compensation off (its own tick cost, the command stored at each
                    // block end, is paid either way).
                    let supervisor_off =
                        sts_twin_core::supervisor::SupervisorParams { active: false, ..Default::default() };
                    vec![
                        Request::SetFeatureConfig(features),
                        Request::SetSupervisor(supervisor_off),
                        Request::UploadProgram { program: model.firmware_program()?, activate: true },
                        Request::SetEnabled(true),
                    ]
                }
                None => Vec::new(),
            };
            let report = bench_instructions_prepared(config(args), *ticks, |hil| {
                for (seq, request) in requests.into_iter().enumerate() {
                    match request_on(hil, seq as u16 + 1, request) {
                        Ok(Response::Ack) => {}
                        other => return Err(sts_hil::HilError::Protocol(format!("preparing the bench: {other:?}"))),
                    }
                }
                Ok(())
            })?;
            println!("{report}");
            let throughput = bench_throughput(config(args), *ticks)?;
            println!("{throughput}");
            Ok(())
        }
    }
}
