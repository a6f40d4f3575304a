//! `sts-twin measure`: the offline dynamic-error measurement test on the emulated machine
//! (by default the paper's 99 groups: 1, 5, 10, ..., 40 Hz x 1..11 um, 6 s each at 8 kHz),
//! written as an `sts-twin-dataset/1` directory.

use anyhow::Context;
use std::path::PathBuf;
use sts_emulator::measure::{run_to_dir, MeasureConfig};
use sts_emulator::{EffectSpec, PlantParams};

/// Arguments of `sts-twin measure`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Output directory: new or empty, or holding a dataset with --force (replaced as a whole
    /// once the new one is written; interrupted, it stays as it was).
    #[arg(long)]
    pub out: PathBuf,
    /// Plant file (TOML; keys left out keep the default machine's values).
    #[arg(long)]
    pub plant: Option<PathBuf>,
    /// A physical effect to switch on, `NAME[:key=value,...]` (repeatable). Names:
    /// coulomb-friction, presliding-hysteresis, structural-mode, loop-delay, setpoint-delay,
    /// thermal-drift, force-ripple, axis-coupling, sensor-gain.
    #[arg(long = "effect", value_name = "NAME[:k=v,...]")]
    pub effects: Vec<String>,
    /// Seed of all noise (same seed, same bytes).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Seconds of motion before each group's recording starts (rounded up to whole command
    /// periods). 0, the default, records each group from rest as the paper's Eq. 1 (with the
    /// start transient); a lead-in records steady motion only.
    #[arg(long, default_value_t = 0.0)]
    pub lead_in_s: f64,
    /// Z frequencies of the groups, Hz, comma-separated (default: the paper's 1, 5, 10, ...,
    /// 40). The emulated machine may go beyond the paper's 40 Hz, e.g. to measure a twin for
    /// its whole range: `--freqs 1,5,10,...,100`.
    #[arg(long, value_delimiter = ',')]
    pub freqs: Option<Vec<f64>>,
    /// Stroke amplitudes of the groups, um, comma-separated (default: 1, 2, ..., 11).
    #[arg(long, value_delimiter = ',')]
    pub amps: Option<Vec<f64>>,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Replace the dataset in --out (never a directory holding the command's inputs).
    #[arg(long)]
    pub force: bool,
}

/// The measurement configuration the arguments describe.
pub fn config(args: &Args) -> anyhow::Result<MeasureConfig> {
    let plant = match &args.plant {
        Some(path) => PlantParams::from_file(path)?,
        None => PlantParams::default(),
    };
    let effects = args
        .effects
        .iter()
        .map(|text| text.parse::<EffectSpec>().with_context(|| format!("--effect {text}")))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let defaults = MeasureConfig::default();
    let config = MeasureConfig {
        plant,
        effects,
        seed: args.seed,
        lead_in_s: args.lead_in_s,
        freqs_hz: args.freqs.clone().unwrap_or(defaults.freqs_hz.clone()),
        amps_um: args.amps.clone().unwrap_or(defaults.amps_um.clone()),
        ..defaults
    };
    config.check().context("--freqs / --amps")?;
    Ok(config)
}

/// Runs `sts-twin measure`.
pub fn run(args: &Args) -> anyhow::Result<()> {
    sts_dataset::output::check_dataset_dir(
        &args.out,
        args.force,
        &args.plant.iter().map(PathBuf::as_path).collect::<Vec<_>>(),
    )?;
    let config = config(args)?;
    // Builds the machine once up front so that bad effect combinations fail before any output.
    sts_emulator::Machine::new(&config.plant, &config.effects, config.seed)?;
    let total = (config.freqs_hz.len() * config.amps_um.len()) as u64;
    let bar = if args.quiet {
        indicatif::ProgressBar::hidden()
    } else {
        let bar = indicatif::ProgressBar::new(total);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "measure {bar:40} {pos}/{len} groups [{elapsed_precise}, eta {eta}]",
            )
            .context("progress style")?,
        );
        bar
    };
    let start = std::time::Instant::now();
    let manifest = run_to_dir(&config, &args.out, &|done| bar.set_position(done as u64))
        .with_context(|| format!("measuring into {}", args.out.display()))?;
    bar.finish_and_clear();
    let samples = manifest.groups.len() * config.samples_per_group();
    eprintln!(
        "wrote {} groups ({samples} samples, {:.0} s of machine time) to {} in {:.1} s",
        manifest.groups.len(),
        manifest.groups.len() as f64 * config.duration_s,
        args.out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use clap::{CommandFactory, Parser};

    #[derive(Parser)]
    struct Measure {
        #[command(flatten)]
        args: super::Args,
    }

    #[test]
    fn the_help_names_every_effect_the_emulator_has() {
        let help = Measure::command().render_long_help().to_string();
        for name in sts_model::Effect::ALL.map(sts_model::Effect::name) {
            assert!(help.contains(name), "`measure --help` does not name {name}");
        }
    }
}
