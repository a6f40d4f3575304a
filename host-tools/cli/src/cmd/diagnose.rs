//! `sts-twin diagnose DATA --model MODEL [--json]`.

use std::path::PathBuf;

use sts_assess::diagnose::diagnose;
use sts_model::ModelFile;

/// Arguments of `sts-twin diagnose`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset directory (sts-twin-dataset/1).
    pub data: PathBuf,
    /// The model whose residual is diagnosed.
    #[arg(long)]
    pub model: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Runs `sts-twin diagnose`.
pub fn run(args: &Args) -> anyhow::Result<()> {
    let dataset = sts_analysis::read_dataset(&args.data)?;
    let model = ModelFile::read(&args.model)?;
    let d = diagnose(&dataset, &model)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&sts_assess::json::diagnosis(&d, &dataset))?);
    } else {
        println!("verdict: {}", d.verdict);
        println!("{}", d.summary);
        if let Some(text) = &d.not_repeating {
            println!("note: {text}");
        }
        if let Some(text) = &d.unexplained {
            println!("unexplained: {text}");
        }
        println!("ranking (explained fraction of the held-out residual; * of the residual without each group's fundamental):");
        for (i, r) in d.ranking.iter().enumerate() {
            let params: Vec<String> = r.params.iter().map(|(k, v)| format!("{k} = {v:.4}")).collect();
            println!(
                "  {}. {:<22} {:>6.1}%{} p = {:.1e}{}  [{}]",
                i + 1,
                r.effect,
                r.explained_fraction * 100.0,
                if r.without_fundamental { "*" } else { " " },
                r.p_value,
                if r.significant { "  significant" } else { "" },
                params.join(", ")
            );
            println!("     {}", r.evidence);
        }
        println!("{}", d.test);
    }
    Ok(())
}
