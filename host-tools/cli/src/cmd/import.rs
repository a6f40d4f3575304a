//! `sts-twin import RECORDING... --out DIR [--map FILE] [--quiet]`.

use std::path::{Path, PathBuf};

use anyhow::Context;
use sts_import::mapping::Mapping;

/// Arguments of `sts-twin import`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The recordings, one long recording of the measurement test each; several follow one
    /// another in machine time. Formats read: CSV and TSV (.csv, .tsv, .txt), MATLAB v5, v7
    /// and v7.3 (.mat), NI TDMS (.tdms), HDF5 (.h5, .hdf5).
    #[arg(required = true)]
    pub recordings: Vec<PathBuf>,
    /// The dataset directory to write: new or empty, or holding a dataset with --force
    /// (replaced as a whole once the new one is written; interrupted, it stays as it was).
    #[arg(long)]
    pub out: PathBuf,
    /// The mapping file (TOML: the channels' names, units and scales; docs/import.md). Without
    /// it the recording has the dataset's own columns: t_s, z_cmd_um, z_enc_um, z_tcp_um, acc_mps2.
    #[arg(long)]
    pub map: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Replace the dataset in --out (never a directory holding the command's inputs).
    #[arg(long)]
    pub force: bool,
}

/// The mapping of a recording with the dataset's own column names and units.
const CANONICAL: &str = r#"
[channels]
time = { name = "t_s", unit = "s" }
command = { name = "z_cmd_um", unit = "um" }
encoder = { name = "z_enc_um", unit = "um" }
probe = { name = "z_tcp_um", unit = "um" }
accelerometer = { name = "acc_mps2", unit = "m/s^2" }
"#;

/// Runs `sts-twin import`.
pub fn run(args: &Args) -> anyhow::Result<()> {
    let mut inputs: Vec<&Path> = args.recordings.iter().map(PathBuf::as_path).collect();
    inputs.extend(args.map.as_deref());
    sts_dataset::output::check_dataset_dir(&args.out, args.force, &inputs)?;
    let (mapping, mapping_path) = match &args.map {
        Some(path) => (Mapping::read(path)?, path.clone()),
        None => {
            let path = Path::new("(the dataset's own columns)");
            (Mapping::parse(path, CANONICAL)?, path.to_path_buf())
        }
    };
    let bar = if args.quiet {
        indicatif::ProgressBar::hidden()
    } else {
        let bar = indicatif::ProgressBar::new(0);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "import {bar:40} {bytes}/{total_bytes} [{elapsed_precise}, eta {eta}]",
            )
            .context("progress style")?,
        );
        bar
    };
    let start = std::time::Instant::now();
    let imported = sts_import::import(&args.recordings, &mapping, &mapping_path, &args.out, &mut |done, total| {
        bar.set_length(total);
        bar.set_position(done);
    })?;
    bar.finish_and_clear();
    println!(
        "{:<10} {:>10} {:>10} {:>10} {:>10} {:>10}",
        "group", "start_s", "length_s", "freq_hz", "amp_um", "pause_s"
    );
    for g in &imported.groups {
        println!(
            "{:<10} {:>10.3} {:>10.3} {:>10} {:>10} {:>10.3}",
            g.file, g.start_s, g.duration_s, g.freq_hz, g.amp_um, g.pause_before_s
        );
    }
    eprintln!(
        "wrote {} groups ({} rows read at {} Hz) to {} in {:.1} s",
        imported.groups.len(),
        imported.rows,
        imported.sample_rate_hz,
        args.out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
