//! `sts-twin export MODEL --to c|matlab|sympy|latex [--name NAME] [--out FILE]`.

use std::path::PathBuf;

use anyhow::Context;
use sts_model::export::{export, ExportLanguage};
use sts_model::ModelFile;

/// Arguments of `sts-twin export`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The model file (from `sts-twin fit` or `explain`).
    pub model: PathBuf,
    /// What to write: `c` (a C99 header, double and float), `matlab` (a function for a Simulink
    /// MATLAB Function block), `sympy` (a Python module of SymPy expressions) or `latex`.
    #[arg(long = "to", value_name = "c|matlab|sympy|latex")]
    pub language: ExportLanguage,
    /// The functions' prefix (C), the function's name (MATLAB) or the module's (SymPy).
    #[arg(long, default_value = "sts_twin", value_parser = c_identifier)]
    pub name: String,
    /// Write to this file instead of standard output.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Replace an existing output (never one of the command's inputs).
    #[arg(long)]
    pub force: bool,
}

/// A name every target language takes: a letter, then letters, digits or underscores.
fn c_identifier(s: &str) -> Result<String, String> {
    let mut chars = s.chars();
    let ok =
        chars.next().is_some_and(|c| c.is_ascii_alphabetic()) && chars.all(|c| c.is_ascii_alphanumeric() || c == '_');
    if ok {
        Ok(s.to_string())
    } else {
        Err(format!("`{s}` is not a name C, MATLAB and Python all accept (a letter, then letters, digits or _)"))
    }
}

/// Runs `sts-twin export`.
pub fn run(args: &Args) -> anyhow::Result<()> {
    if let Some(out) = &args.out {
        sts_dataset::output::check_file(out, args.force, &[&args.model])?;
    }
    let model = ModelFile::read(&args.model)?;
    let origin =
        args.model.file_name().map_or_else(|| args.model.display().to_string(), |n| n.to_string_lossy().into_owned());
    let exported = export(&model, args.language, &args.name, &origin)
        .with_context(|| format!("exporting {}", args.model.display()))?;
    match &args.out {
        Some(path) => {
            sts_dataset::output::write_file(path, exported.text.as_bytes())?;
            eprintln!("written to {}", path.display());
        }
        None => print!("{}", exported.text),
    }
    for term in &exported.not_exported {
        eprintln!("not exported (the firmware runs it): {term}");
    }
    Ok(())
}
