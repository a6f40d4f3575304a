//! `sts-twin explain DATA --out MODEL [--model BASE] [--max-effects N] [--html FILE] [--json]`:
//! the lab's loop (fit, diagnose, add the named effect, refit) run until `none`.

use std::path::PathBuf;

use sts_assess::explain::{explain, Base, ExplainConfig, ExplainProgress, Explanation};
use sts_fit::effects::{read_records, write_model};
use sts_fit::FitConfig;
use sts_model::ModelFile;

use crate::report;

/// Arguments of `sts-twin explain`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset directory (sts-twin-dataset/1): the machine's measurement.
    pub data: PathBuf,
    /// Where to write the final twin (JSON, sts-twin-model/1), ready for the firmware.
    #[arg(long)]
    pub out: PathBuf,
    /// Start from this twin (e.g. of the machine as it was) instead of fitting one on DATA.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Effects added at most.
    #[arg(long, default_value_t = 4)]
    pub max_effects: usize,
    /// Seed of the formulas' searches.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Epoch limit per search.
    #[arg(long, default_value_t = FitConfig::default().max_epochs)]
    pub epochs: usize,
    /// Also write the ladder as an HTML report.
    #[arg(long)]
    pub html: Option<PathBuf>,
    /// Print JSON instead of text (progress goes to stderr).
    #[arg(long)]
    pub json: bool,
    /// Replace an existing output (never one of the command's inputs).
    #[arg(long)]
    pub force: bool,
}

/// Runs `sts-twin explain`.
pub fn run(args: &Args) -> anyhow::Result<()> {
    let mut inputs = vec![args.data.as_path()];
    inputs.extend(args.model.as_deref());
    let mut outputs = vec![args.out.as_path()];
    outputs.extend(args.html.as_deref());
    sts_dataset::output::check_files(&outputs, args.force, &inputs)?;
    let dataset = sts_analysis::read_dataset(&args.data)?;
    let base = match &args.model {
        Some(path) => Some(Base { model: ModelFile::read(path)?, effects: read_records(path)? }),
        None => None,
    };
    let config = ExplainConfig {
        fit: FitConfig { seed: args.seed, max_epochs: args.epochs, ..FitConfig::default() },
        max_effects: args.max_effects,
    };
    let name = args.data.file_name().map_or_else(|| "data".into(), |n| n.to_string_lossy().into_owned());
    let description = format!("fitted by sts-twin explain on {name} (seed {})", args.seed);
    let mut on_progress = |p: ExplainProgress| {
        let line = match p {
            ExplainProgress::Fitting => "fitting a twin on the data".to_string(),
            ExplainProgress::Diagnosing { effects } => format!("diagnosing the twin{}", with_effects(effects)),
            ExplainProgress::Refitting { effects } => format!("fitting a twin{}", with_effects(effects)),
        };
        eprintln!("{line}");
    };
    let e = explain(&dataset, &description, base, &config, &mut on_progress)?;
    write_model(&args.out, &e.model, Some(&e.effects))?;
    if let Some(path) = &args.html {
        sts_dataset::output::write_file(path, report::explain::render(&name, &e).as_bytes())?;
    }
    let written = format!("twin written to {} (program id {:08x})", args.out.display(), e.model.program.id);
    let report = args.html.as_ref().map(|path| format!("report written to {}", path.display()));
    if args.json {
        println!("{}", serde_json::to_string_pretty(&sts_assess::json::explanation(&e))?);
        // stdout holds the JSON alone; the files written are named on stderr.
        eprintln!("{written}");
        if let Some(report) = report {
            eprintln!("{report}");
        }
    } else {
        print_ladder(&e);
        println!("{written}");
        if let Some(report) = report {
            println!("{report}");
        }
    }
    Ok(())
}

/// `" with a, b"` for the effects a twin carries, nothing where it carries none.
fn with_effects(effects: &[String]) -> String {
    if effects.is_empty() {
        String::new()
    } else {
        format!(" with {}", effects.join(", "))
    }
}

fn print_ladder(e: &Explanation) {
    println!("start: the twin's waveform RMS on the data {:.1} nm", e.start_waveform_rms_um * 1e3);
    for (i, s) in e.steps.iter().enumerate() {
        let params: Vec<String> = s.params.iter().map(|(k, v)| format!("{k} = {v:.4}")).collect();
        println!(
            "{}. {}: explained {:.0}% of the residual (p = {:.1e}); {:.1} -> {:.1} nm",
            i + 1,
            s.effect,
            s.explained_fraction * 100.0,
            s.p_value,
            s.waveform_rms_um_before * 1e3,
            s.waveform_rms_um_after * 1e3
        );
        println!("   {}", s.evidence);
        if !params.is_empty() {
            println!("   identified: {}", params.join(", "));
        }
    }
    println!("stop: {}", e.stop.describe());
    println!("{}", e.last.summary);
    if let Some(text) = &e.last.not_repeating {
        println!("note: {text}");
    }
    if let Some(text) = &e.last.unexplained {
        println!("unexplained: {text}");
    }
    println!(
        "final: held-out waveform RMS {:.1} nm; the data's floor (what does not repeat from period to period) {:.1} nm",
        e.waveform_rms_um * 1e3,
        e.last.repeatability.floor_um * 1e3
    );
}
