//! `sts-twin paper-table`: the emulated machine's measurement test against the paper's
//! figures (Section 3, Fig. 2c-e), with tolerances.

use std::path::PathBuf;
use sts_emulator::measure::MeasureConfig;
use sts_emulator::paper::{format_table, paper_table, AMP_40HZ_UM, AMP_5HZ_UM};
use sts_emulator::PlantParams;

/// Arguments of `sts-twin paper-table`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Plant file (TOML; keys left out keep the default machine's values).
    #[arg(long)]
    pub plant: Option<PathBuf>,
    /// Seed of all noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print a Markdown table.
    #[arg(long)]
    pub markdown: bool,
}

/// Runs `sts-twin paper-table`; fails when a figure is out of tolerance.
pub fn run(args: &Args) -> anyhow::Result<()> {
    let plant = match &args.plant {
        Some(path) => PlantParams::from_file(path)?,
        None => PlantParams::default(),
    };
    let config = MeasureConfig { plant, seed: args.seed, ..MeasureConfig::default() };
    let rows = paper_table(&config)?;
    print!("{}", format_table(&rows, args.markdown));
    println!(
        "\nFigures from the last second of each group (sine fits at the command frequency). The paper does not \
         give the amplitude of Fig. 2e: 5 Hz figures at A = {AMP_5HZ_UM} um, 40 Hz figures at A = {AMP_40HZ_UM} um."
    );
    let failed = rows.iter().filter(|r| !r.passes()).count();
    if failed > 0 {
        anyhow::bail!("{failed} figure(s) out of tolerance");
    }
    Ok(())
}
