//! `sts-twin compare DATA --model MODEL [--baseline MODEL0] [--html FILE] [--json]`.

use std::path::PathBuf;

use anyhow::Context as _;

use crate::report::{render, ReportInput};
use sts_assess::compare::{compare, Comparison};
use sts_model::ModelFile;

/// Arguments of `sts-twin compare`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset directory (sts-twin-dataset/1).
    pub data: PathBuf,
    /// The model file to compare.
    #[arg(long)]
    pub model: PathBuf,
    /// A second model shown side by side (e.g. before adding an effect).
    #[arg(long)]
    pub baseline: Option<PathBuf>,
    /// Write the self-contained HTML report (with the diagnosis) to this file.
    #[arg(long)]
    pub html: Option<PathBuf>,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Groups (indices) whose waveforms the report shows besides the worst ones.
    #[arg(long, value_delimiter = ',')]
    pub groups: Vec<usize>,
    /// Replace an existing output (never one of the command's inputs).
    #[arg(long)]
    pub force: bool,
}

fn file_label(path: &std::path::Path) -> String {
    path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned())
}

fn print_text(label: &str, c: &Comparison) {
    println!(
        "{label}: waveform RMS {:.1} nm, MAE {:.1} nm over {} groups' last second (measured RMS {:.1} nm)",
        c.waveform_rms_um * 1e3,
        c.waveform_mae_um * 1e3,
        c.groups.len(),
        c.measured_rms_um * 1e3
    );
    println!("  amplitude R^2 {:.4}, phase R^2 {:.4}", c.amplitude_r2, c.phase_r2);
    let h: Vec<String> = c.harmonics_um.iter().enumerate().map(|(k, v)| format!("{}f {:.1}", k + 1, v * 1e3)).collect();
    println!("  residual at harmonics (nm, mean over groups): {}", h.join(", "));
    if !c.other_lines.is_empty() {
        let l: Vec<String> = c.other_lines.iter().map(|l| format!("{} Hz {:.1}", l.freq_hz, l.amp_um * 1e3)).collect();
        println!("  other residual lines (nm): {}", l.join(", "));
    }
    if let Some(text) = c.repeatability.describe(|i| (c.groups[i].freq_hz, c.groups[i].amp_um)) {
        println!("  not repeating: {text}");
    }
    if let Some(text) = c.describe_acc_blind() {
        println!("  accelerometer: {text}");
    }
    println!("  worst groups:");
    for i in c.worst(5) {
        let g = &c.groups[i];
        println!(
            "    {} ({} Hz, {} um, t = {:.0} s): amplitude {:.3} vs {:.3} um, phase {:.2} vs {:.2} deg, RMS {:.1} nm, mean {:.1} nm",
            g.file, g.freq_hz, g.amp_um, g.start_s, g.predicted_amp_um, g.measured_amp_um, g.predicted_phase_deg, g.measured_phase_deg, g.waveform_rms_um * 1e3, g.residual_mean_um * 1e3
        );
    }
}

/// Runs `sts-twin compare`.
pub fn run(args: &Args) -> anyhow::Result<()> {
    if let Some(html) = &args.html {
        let mut inputs = vec![args.data.as_path(), args.model.as_path()];
        inputs.extend(args.baseline.as_deref());
        sts_dataset::output::check_file(html, args.force, &inputs)?;
    }
    let dataset = sts_analysis::read_dataset(&args.data)?;
    let model = ModelFile::read(&args.model)?;
    let (c, waves) = compare(&dataset, &model).with_context(|| format!("comparing {}", args.model.display()))?;
    let baseline = match &args.baseline {
        Some(path) => {
            let m = ModelFile::read(path)?;
            let (b, bw) = compare(&dataset, &m).with_context(|| format!("comparing {}", path.display()))?;
            Some((b, bw, file_label(path)))
        }
        None => None,
    };
    if let Some(path) = &args.html {
        let diagnosis = sts_assess::diagnose::diagnose(&dataset, &model)?;
        let input = ReportInput {
            dataset: args.data.display().to_string(),
            model: (&c, &waves),
            model_label: file_label(&args.model),
            baseline: baseline.as_ref().map(|(b, bw, l)| (b, bw.as_slice(), l.clone())),
            diagnosis: Some(&diagnosis),
            chosen_groups: args.groups.clone(),
        };
        sts_dataset::output::write_file(path, render(&input).as_bytes())?;
    }
    if args.json {
        let mut value = sts_assess::json::comparison(&c)?;
        if let Some((b, _, label)) = &baseline {
            value["baseline"] = sts_assess::json::comparison(b)?;
            value["baseline"]["file"] = serde_json::Value::String(label.clone());
        }
        println!("{}", serde_json::to_string_pretty(&value)?);
        if let Some(path) = &args.html {
            // stdout holds the JSON alone.
            eprintln!("report written to {}", path.display());
        }
    } else {
        print_text(&file_label(&args.model), &c);
        if let Some((b, _, label)) = &baseline {
            print_text(label, b);
            let fall = 1.0 - c.waveform_rms_um / b.waveform_rms_um.max(1e-300);
            println!(
                "waveform RMS {} by {:.0}% from {label}",
                if fall >= 0.0 { "falls" } else { "rises" },
                fall.abs() * 100.0
            );
        }
        if let Some(path) = &args.html {
            println!("report written to {}", path.display());
        }
    }
    Ok(())
}
