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
        let ranking: Vec<serde_json::Value> = d
            .ranking
            .iter()
            .map(|r| {
                let params = super::params_json(&r.params);
                serde_json::json!({
                    "effect": r.effect,
                    "explained_fraction": r.explained_fraction,
                    "p_value": r.p_value,
                    "groups_improved": r.groups_improved,
                    "significant": r.significant,
                    "explained_rms_um": r.explained_rms_um,
                    "without_fundamental": r.without_fundamental,
                    "params": params,
                    "evidence": r.evidence,
                })
            })
            .collect();
        let out = serde_json::json!({
            "verdict": d.verdict,
            "ranking": ranking,
            "residual_rms_um": d.residual_rms_um,
            "model_cv_rms_um": d.model_cv_rms_um,
            "summary": d.summary,
            "test": d.test,
            "repeatability": {
                "floor_um": d.repeatability.floor_um,
                "not_repeating_groups": d.repeatability.not_repeating.iter().map(|&i| dataset.manifest.groups.get(i).map_or_else(String::new, |g| g.file.clone())).collect::<Vec<_>>(),
                "note": d.not_repeating,
            },
            "structure": d.structure,
            "unexplained": d.unexplained,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
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
