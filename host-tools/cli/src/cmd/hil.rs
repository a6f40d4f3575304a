//! `sts-twin hil`: the firmware under QEMU on its own: boot it and read its status, or
//! benchmark the rig (instructions per servo tick, lockstep and open-loop throughput).

use std::path::PathBuf;

use sts_twin_core::wire::{Request, Response};

use sts_hil::board::qemu::QemuBoard;
use sts_hil::{bench_instructions_prepared, bench_throughput, FirmwareVariant, HilConfig, QemuPlacement};
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
    /// The emulated board: `mps2-an386` (Cortex-M4F), `mps2-an500` (Cortex-M7, the
    /// STM32H7's core; the same image as the AN386's) or `riscv-virt` (RV32IMAC, its own image).
    #[arg(long, global = true, default_value = "mps2-an386", value_parser = parse_board)]
    pub board: QemuBoard,
    /// Where QEMU's threads run: `one` (all on one CPU of this process's set: the default),
    /// `any` (wherever the kernel puts them) or a CPU number.
    #[arg(long, global = true, default_value = "one", value_parser = parse_placement)]
    pub qemu_cpu: QemuPlacement,
}

fn parse_placement(text: &str) -> Result<QemuPlacement, String> {
    match text {
        "one" => Ok(QemuPlacement::OneCpu),
        "any" => Ok(QemuPlacement::Anywhere),
        _ => text.parse().map(QemuPlacement::Cpu).map_err(|_| format!("`{text}` is not `one`, `any` or a CPU number")),
    }
}

/// A QEMU board by its name ([`QemuBoard::name`]; `an386` and `an500` also name the MPS2
/// images).
pub fn parse_board(text: &str) -> Result<QemuBoard, String> {
    let alias = match text {
        "an386" => Some(QemuBoard::An386),
        "an500" => Some(QemuBoard::An500),
        _ => None,
    };
    alias.or_else(|| QemuBoard::from_name(text)).ok_or_else(|| {
        let names: Vec<&str> = QemuBoard::ALL.iter().map(|b| b.name()).collect();
        format!("`{text}` is not a QEMU board: one of {}", names.join(", "))
    })
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
    /// Boot the firmware with its control link on a pseudo-terminal and keep it running (until
    /// Ctrl-C or `--seconds`): a board to try `sts-twin board --port` on without hardware.
    Serve {
        /// A named bus file whose config store (the board's flash) is kept across runs.
        #[arg(long)]
        bus_file: Option<PathBuf>,
        /// Stop after this many seconds (default: run until Ctrl-C).
        #[arg(long)]
        seconds: Option<f64>,
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
        board: args.board,
        placement: args.qemu_cpu,
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
            println!("board: QEMU {} ({})", args.board.name(), args.board.core());
            super::status::print_status(&status);
            Ok(())
        }
        Action::Serve { bus_file, seconds } => {
            if args.bringup {
                anyhow::bail!("`hil serve` needs the twin firmware (the bring-up application has no control protocol)");
            }
            let mut hil =
                sts_hil::Hil::start(HilConfig { bus_path: bus_file.clone(), control_pty: true, ..config(args) })?;
            let pty = hil.control_pty().map(|p| p.display().to_string()).unwrap_or_default();
            println!(
                "the twin firmware runs on QEMU {} ({}); its control link is {pty}",
                args.board.name(),
                args.board.core()
            );
            println!("try: sts-twin board --port {pty} status");
            let started = std::time::Instant::now();
            while seconds.is_none_or(|s| started.elapsed().as_secs_f64() < s) {
                hil.alive("serving the control link")?;
                std::thread::sleep(std::time::Duration::from_millis(100));
            }
            hil.shutdown()?;
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
