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
    /// Run the offline dynamic-error measurement test on the emulated machine.
    Measure(cmd::measure::Args),
    /// Symbolic regression on any numeric CSV table.
    Regress(cmd::regress::Args),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Measure(args) => cmd::measure::run(args),
        Command::Regress(args) => cmd::regress::run(args),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
