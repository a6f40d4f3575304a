//! `sts-twin board`: a co-processor board on a serial port, for the bench: its status, a
//! twin uploaded, parameters shown and set, compensation switched on and off, the settings
//! saved, the counters, and a live watch. Every action connects with the protocol-version
//! handshake (`sts_link::Board`) and names the port in its errors.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use sts_link::{Board, RetryPolicy, SerialLink, DEFAULT_BAUD};
use sts_model::ModelFile;
use sts_twin_core::analogue_path::AnaloguePath;
use sts_twin_core::wire::{Request, Response, Status};

/// Arguments of `sts-twin board`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// What to do.
    #[command(subcommand)]
    pub action: Action,
    /// The board's serial port: /dev/ttyACM0 for a NUCLEO-H743ZI's ST-LINK virtual COM port,
    /// /dev/ttyUSB0 for a USB-serial adapter, COM3 on Windows.
    #[arg(long, global = true, value_name = "DEV")]
    pub port: Option<String>,
    /// The line's baud rate (the firmware's USART3 runs at 115200 8N1).
    #[arg(long, global = true, default_value_t = DEFAULT_BAUD)]
    pub baud: u32,
    /// Give up on an answer after this many seconds (a request is retried meanwhile).
    #[arg(long, global = true, default_value_t = 5.0, value_name = "S")]
    pub timeout_s: f64,
}

/// `sts-twin board` actions.
#[derive(Debug, clap::Subcommand)]
pub enum Action {
    /// The board's state: compensation, the twin, parameters, supervisor, counters, faults.
    Status,
    /// Upload a twin (a model file from `fit` or `explain`) and make it the active one. A twin
    /// the board refuses leaves the old one in force. `save` keeps it across a power cycle.
    Upload {
        /// The model file.
        model: PathBuf,
        /// Stage the twin without activating it (`ActivateStaged` later).
        #[arg(long)]
        stage_only: bool,
    },
    /// Show the feedforward parameters and the analogue-path table; with options, set them
    /// (the others stay; parameters the board refuses leave the old ones in force).
    Params {
        /// Motion per volt at the controller's analogue input, um/V.
        #[arg(long, allow_negative_numbers = true)]
        k_dv_um_per_v: Option<f32>,
        /// Encoder pulses per volt, pulses/V.
        #[arg(long, allow_negative_numbers = true)]
        k_vc_pulses_per_v: Option<f32>,
        /// The controller's reading of 0 V at its analogue input, V (calibrate-offset
        /// measures it).
        #[arg(long, allow_negative_numbers = true)]
        offset_v: Option<f32>,
        /// The largest DAC change per servo tick, V.
        #[arg(long, allow_negative_numbers = true)]
        slew_v_per_tick: Option<f32>,
        /// Set the analogue-path table from a CSV file with the columns `freq_hz`, `phase_deg`
        /// and, optionally, `gain` (|H| relative to K_dv; 0 or missing: not measured), at most
        /// 10 rows with increasing frequencies; `#` starts a comment line.
        #[arg(long, value_name = "CSV", conflicts_with = "clear_path")]
        path: Option<PathBuf>,
        /// The amplitude of the sine the table was measured with, um (with --path; 0: not
        /// stated).
        #[arg(long, default_value_t = 0.0, requires = "path")]
        path_amp_um: f32,
        /// Forget the analogue-path table (the twin's phases are then used as they are).
        #[arg(long)]
        clear_path: bool,
    },
    /// Switch compensation on (it ramps in, never steps).
    Enable,
    /// Switch compensation off (it ramps out).
    Disable,
    /// Store the parameters, the supervisor's thresholds, the feature settings and the
    /// active twin in the board's flash; the board boots with them (compensation off).
    Save,
    /// The board's event and fault counters.
    Counters {
        /// Set every counter to zero afterwards.
        #[arg(long)]
        reset: bool,
    },
    /// Status, counters and the prediction, a few times a second, until Ctrl-C.
    Watch {
        /// Lines per second.
        #[arg(long, default_value_t = 2.0)]
        hz: f64,
        /// Stop after this many lines (0: until Ctrl-C).
        #[arg(long, default_value_t = 0)]
        count: u32,
    },
}

/// Runs `sts-twin board`.
pub fn run(args: &Args) -> anyhow::Result<()> {
    let mut board = connect(args)?;
    match &args.action {
        Action::Status => {
            println!("board: {} (control protocol {})", board.describe(), sts_twin_core::wire::PROTOCOL_VERSION);
            super::status::print_status(&status(&mut board)?);
        }
        Action::Upload { model, stage_only } => upload(&mut board, model, *stage_only)?,
        Action::Params {
            k_dv_um_per_v,
            k_vc_pulses_per_v,
            offset_v,
            slew_v_per_tick,
            path,
            path_amp_um,
            clear_path,
        } => {
            // The file is read before anything is sent: a bad table changes nothing.
            let table = path.as_deref().map(|p| read_path_table(p, *path_amp_um)).transpose()?;
            let before = status(&mut board)?;
            let mut params = before.params;
            let set = [
                k_dv_um_per_v.map(|v| params.k_dv_um_per_v = v),
                k_vc_pulses_per_v.map(|v| params.k_vc_pulses_per_v = v),
                offset_v.map(|v| params.offset_v = v),
                slew_v_per_tick.map(|v| params.slew_v_per_tick = v),
                clear_path.then(|| params.analogue_path = AnaloguePath::NONE),
                table.map(|t| params.analogue_path = t),
            ];
            if set.iter().any(Option::is_some) {
                accepted(&mut board, Request::SetParams(params), "the parameters")?;
                println!("set (not yet saved: `sts-twin board save` keeps them across a power cycle)");
            }
            super::status::print_params(&status(&mut board)?);
        }
        Action::Enable => {
            accepted(&mut board, Request::SetEnabled(true), "enabling")?;
            println!("compensation enabled (ramping in)");
        }
        Action::Disable => {
            accepted(&mut board, Request::SetEnabled(false), "disabling")?;
            println!("compensation disabled (ramping out)");
        }
        Action::Save => {
            accepted(&mut board, Request::SaveConfig, "saving")?;
            let s = status(&mut board)?;
            println!(
                "saved: parameters, supervisor thresholds, feature settings and twin {} (the board boots with them, compensation off)",
                s.program_id.map_or("none".to_string(), |id| id.to_string())
            );
        }
        Action::Counters { reset } => {
            let s = status(&mut board)?;
            super::status::print_counters(&s.counters);
            if *reset {
                accepted(&mut board, Request::ResetCounters, "resetting the counters")?;
                println!("counters reset");
            }
        }
        Action::Watch { hz, count } => watch(&mut board, *hz, *count)?,
    }
    Ok(())
}

/// One row of an analogue-path CSV file.
#[derive(Debug, serde::Deserialize)]
struct PathRow {
    freq_hz: f32,
    /// Empty or missing: not measured.
    #[serde(default)]
    gain: Option<f32>,
    phase_deg: f32,
}

/// The analogue-path table in the CSV file `path`, validated; errors name the file, and the
/// line and field where there is one.
fn read_path_table(path: &std::path::Path, amp_um: f32) -> anyhow::Result<AnaloguePath> {
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .comment(Some(b'#'))
        .from_path(path)
        .with_context(|| format!("{}: cannot read the analogue-path table", path.display()))?;
    let mut points = Vec::new();
    for row in reader.deserialize::<PathRow>() {
        let row = row.map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        points.push((row.freq_hz, row.gain.unwrap_or(0.0), row.phase_deg));
    }
    if points.is_empty() {
        anyhow::bail!(
            "{}: no rows (the header is `freq_hz,gain,phase_deg`; use --clear-path for no table)",
            path.display()
        );
    }
    AnaloguePath::from_responses(amp_um, &points).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

fn connect(args: &Args) -> anyhow::Result<Board<SerialLink>> {
    let Some(port) = &args.port else {
        anyhow::bail!("`sts-twin board` needs the board's serial port: --port DEV (e.g. --port /dev/ttyACM0)");
    };
    connect_port(port, args.baud, args.timeout_s)
}

/// Opens `port` and connects with the handshake, giving up on an answer after `timeout_s`.
pub(crate) fn connect_port(port: &str, baud: u32, timeout_s: f64) -> anyhow::Result<Board<SerialLink>> {
    if !(timeout_s.is_finite() && timeout_s > 0.0) {
        anyhow::bail!("--timeout-s {timeout_s}: must be a positive number of seconds");
    }
    let link = SerialLink::open(port, baud)?;
    Ok(Board::connect(link, policy(timeout_s))?)
}

/// Retries that give up after about `timeout_s`: 80 ms first, doubling to 1 s.
fn policy(timeout_s: f64) -> RetryPolicy {
    let first = Duration::from_millis(80);
    let max = Duration::from_secs(1);
    let (mut attempts, mut spent, mut wait) = (0u32, Duration::ZERO, first);
    while spent.as_secs_f64() < timeout_s {
        attempts += 1;
        spent += wait;
        wait = (wait * 2).min(max);
    }
    RetryPolicy { first_timeout: first, max_timeout: max, attempts: attempts.max(1) }
}

fn status(board: &mut Board<SerialLink>) -> anyhow::Result<Status> {
    match board.request(Request::GetStatus)? {
        Response::Status(status) => Ok(status),
        other => anyhow::bail!("{}: GetStatus was answered with {other:?}", board.describe()),
    }
}

/// Sends `request` and fails with the board's reason unless it is acknowledged.
fn accepted(board: &mut Board<SerialLink>, request: Request, what: &str) -> anyhow::Result<()> {
    match board.request(request)? {
        Response::Ack => Ok(()),
        Response::Rejected(why) => {
            anyhow::bail!("{}: the board refused {what}: {why}; nothing changed", board.describe())
        }
        other => anyhow::bail!("{}: {what} was answered with {other:?}", board.describe()),
    }
}

/// Stage, set the features, activate: a twin refused at any step leaves the old one in
/// force (the features are only set once the program is accepted; the board refuses an
/// invalid feature setting before anything changes).
fn upload(board: &mut Board<SerialLink>, path: &std::path::Path, stage_only: bool) -> anyhow::Result<()> {
    let model = ModelFile::read(path)?;
    let program = model.firmware_program().with_context(|| format!("{}: the twin program", path.display()))?;
    let (id, terms) = (program.id, program.terms.len());
    accepted(board, Request::UploadProgram { program, activate: false }, &format!("the twin of {}", path.display()))?;
    if stage_only {
        println!("twin {id} staged on {} ({terms} per-tick terms); the active twin is unchanged", board.describe());
        return Ok(());
    }
    accepted(board, Request::SetFeatureConfig(model.feature_config), "the twin's feature settings")?;
    accepted(board, Request::ActivateStaged, "activating the twin")?;
    println!(
        "twin {id} active on {} ({terms} per-tick terms, window {} samples); not yet saved: `sts-twin board save` keeps it across a power cycle",
        board.describe(),
        model.feature_config.window_samples
    );
    Ok(())
}

fn watch(board: &mut Board<SerialLink>, hz: f64, count: u32) -> anyhow::Result<()> {
    if !(hz.is_finite() && hz > 0.0 && hz <= 50.0) {
        anyhow::bail!("--hz {hz}: must be above 0 and at most 50 lines per second");
    }
    let period = Duration::from_secs_f64(1.0 / hz);
    let start = Instant::now();
    let mut last: Option<Status> = None;
    // As wide as the longest state, "tripped: worse than bare".
    const SUPERVISOR_WIDTH: usize = 24;
    println!(
        "{:>7}  {:>4}  {:>5}  {:>7}  {:>9}  {:>8}  {:<SUPERVISOR_WIDTH$}  {:>6}  new faults",
        "t s", "comp", "gain", "amp um", "phase deg", "freq Hz", "supervisor", "ticks"
    );
    for line in 0.. {
        if count > 0 && line >= count {
            break;
        }
        let s = status(board)?;
        let new_faults = last.as_ref().map_or(0, |l| s.counters.fault_sum().wrapping_sub(l.counters.fault_sum()));
        let supervisor = match (s.supervisor.tripped, s.supervisor.gated) {
            (Some(trip), _) => format!("tripped: {}", super::status::trip_text(trip)),
            (None, true) => "gated".to_string(),
            (None, false) if s.supervisor_params.active => "on".to_string(),
            (None, false) => "off".to_string(),
        };
        println!(
            "{:7.1}  {:>4}  {:5.3}  {:7.4}  {:9.3}  {:8.2}  {:<SUPERVISOR_WIDTH$}  {:>6}  {}",
            start.elapsed().as_secs_f64(),
            if s.enabled { "on" } else { "off" },
            s.gain,
            s.amp_um,
            s.phase_deg,
            s.features[0],
            supervisor,
            s.counters.ticks,
            new_faults
        );
        last = Some(s);
        let next = period.saturating_mul(line + 1);
        std::thread::sleep(next.saturating_sub(start.elapsed()));
    }
    Ok(())
}
