//! The `sts-twin` command: a thin CLI over the `sts_twin` library.
use clap::{Parser, Subcommand};
use sts_twin::cmd;

/// sts-twin: a predictive digital twin of the dynamic error of a slow-tool-servo Z axis.
#[derive(Debug, Parser)]
#[command(name = "sts-twin", version, about, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// A co-processor board on a serial port: status, upload a twin, parameters, enable, save, counters, watch.
    Board(cmd::board::Args),
    /// Calibrate before a cut: interface offset, K_dv and analogue path, stored in the co-processor and verified.
    #[command(alias = "calibrate")]
    CalibrateOffset(cmd::calibrate::Args),
    /// Compare a model's predicted dynamic error with a measurement (text, JSON, HTML report).
    Compare(cmd::compare::Args),
    /// The main job: measure, fit, then cut at 40 Hz with the firmware in QEMU, without and with the twin.
    Demo(cmd::demo::Args),
    /// Emulated STS cut of the bicuspid surface (Eq. 6), with or without the twin.
    Machine(cmd::machine::Args),
    /// Rank the physical effects missing from a model by how much of its residual they explain.
    Diagnose(cmd::diagnose::Args),
    /// The lab's loop by itself: fit, diagnose, add the named effect, refit, until nothing is missing.
    Explain(cmd::explain::Args),
    /// The twin's formulas and Eq. 4 out to C, MATLAB/Simulink, SymPy or LaTeX.
    Export(cmd::export::Args),
    /// Train the explainable twin (amplitude and phase formulas) on a dataset.
    Fit(cmd::fit::Args),
    /// The firmware under QEMU on its own: status, benchmarks.
    Hil(cmd::hil::Args),
    /// A lab's own recording (CSV, TSV, MAT, TDMS or HDF5, its own channel names and units) to a dataset, the groups found from the command.
    Import(cmd::import::Args),
    /// Run the offline dynamic-error measurement test on the emulated machine.
    Measure(cmd::measure::Args),
    /// The emulated machine's measurement test against the paper's figures.
    PaperTable(cmd::paper_table::Args),
    /// Symbolic regression on any numeric CSV table.
    Regress(cmd::regress::Args),
    /// The bicuspid cut at several Z frequencies, without and with the twin (Markdown table).
    TrialTable(cmd::trial_table::Args),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    // `sts-twin compare ... | head` closes stdout early. Rust ignores SIGPIPE, so `println!`
    // then panics; restoring SIGPIPE instead would kill the process before the QEMU it may
    // have started is ended. So a closed stdout ends the command by unwinding (every guard
    // runs) and exits quietly, as a pipeline expects.
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if !is_closed_stdout(info.payload()) {
            default_hook(info);
        }
    }));
    match std::panic::catch_unwind(|| run(&cli)) {
        Ok(code) => code,
        Err(payload) if is_closed_stdout(payload.as_ref()) => std::process::ExitCode::SUCCESS,
        Err(payload) => std::panic::resume_unwind(payload),
    }
}

/// Whether a panic is `println!` failing on a closed pipe.
fn is_closed_stdout(payload: &(dyn std::any::Any + Send)) -> bool {
    let text = payload
        .downcast_ref::<String>()
        .map(String::as_str)
        .or_else(|| payload.downcast_ref::<&str>().copied())
        .unwrap_or("");
    text.starts_with("failed printing to stdout") && text.contains("Broken pipe")
}

fn run(cli: &Cli) -> std::process::ExitCode {
    let result = match &cli.command {
        Command::Board(args) => cmd::board::run(args),
        Command::CalibrateOffset(args) => cmd::calibrate::run(args),
        Command::Compare(args) => cmd::compare::run(args),
        Command::Demo(args) => cmd::demo::run(args),
        Command::Diagnose(args) => cmd::diagnose::run(args),
        Command::Export(args) => cmd::export::run(args),
        Command::Import(args) => cmd::import::run(args),
        Command::Explain(args) => cmd::explain::run(args),
        Command::Fit(args) => cmd::fit::run(args),
        Command::Hil(args) => cmd::hil::run(args),
        Command::Machine(args) => cmd::machine::run(args),
        Command::Measure(args) => cmd::measure::run(args),
        Command::PaperTable(args) => cmd::paper_table::run(args),
        Command::Regress(args) => cmd::regress::run(args),
        Command::TrialTable(args) => cmd::trial_table::run(args),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {}", sts_dataset::output::error_text(err.as_ref()));
            std::process::ExitCode::FAILURE
        }
    }
}
