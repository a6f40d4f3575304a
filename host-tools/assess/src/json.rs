//! The JSON of `compare`, `diagnose` and `explain`: what `sts-twin ... --json` prints and what
//! the Python package returns, built in one place so that the two agree bit for bit.

use serde_json::{json, Map, Value};
use sts_dataset::Dataset;

use crate::compare::Comparison;
use crate::diagnose::Diagnosis;
use crate::explain::Explanation;

/// Named parameters (name with unit, value) as a JSON object, in their order.
pub fn params(params: &[(String, f64)]) -> Map<String, Value> {
    params.iter().map(|(k, v)| (k.clone(), json!(v))).collect()
}

/// A comparison: the summary figures and one entry per group.
pub fn comparison(c: &Comparison) -> Result<Value, serde_json::Error> {
    serde_json::to_value(c)
}

/// A diagnosis of a model on `dataset` (the dataset names the groups that do not repeat).
pub fn diagnosis(d: &Diagnosis, dataset: &Dataset) -> Value {
    let ranking: Vec<Value> = d
        .ranking
        .iter()
        .map(|r| {
            json!({
                "effect": r.effect,
                "explained_fraction": r.explained_fraction,
                "p_value": r.p_value,
                "groups_improved": r.groups_improved,
                "significant": r.significant,
                "explained_rms_um": r.explained_rms_um,
                "without_fundamental": r.without_fundamental,
                "params": params(&r.params),
                "evidence": r.evidence,
            })
        })
        .collect();
    let not_repeating: Vec<String> = d
        .repeatability
        .not_repeating
        .iter()
        .map(|&i| dataset.manifest.groups.get(i).map_or_else(String::new, |g| g.file.clone()))
        .collect();
    json!({
        "verdict": d.verdict,
        "groups": d.group_files.len(),
        "groups_needed": crate::diagnose::groups_needed(),
        "ranking": ranking,
        "residual_rms_um": d.residual_rms_um,
        "model_cv_rms_um": d.model_cv_rms_um,
        "summary": d.summary,
        "test": d.test,
        "repeatability": {
            "floor_um": d.repeatability.floor_um,
            "not_repeating_groups": not_repeating,
            "note": d.not_repeating,
        },
        "structure": d.structure,
        "unexplained": d.unexplained,
    })
}

/// The ladder of `explain`: each step's effect, parameters, evidence and error before and
/// after, why it stopped, and the final error.
pub fn explanation(e: &Explanation) -> Value {
    let steps: Vec<Value> = e
        .steps
        .iter()
        .map(|s| {
            json!({
                "effect": s.effect,
                "params": params(&s.params),
                "explained_fraction": s.explained_fraction,
                "p_value": s.p_value,
                "evidence": s.evidence,
                "waveform_rms_um_before": s.waveform_rms_um_before,
                "waveform_rms_um_after": s.waveform_rms_um_after,
            })
        })
        .collect();
    json!({
        "steps": steps,
        "verdict": e.stop.verdict(),
        "stop": e.stop.describe(),
        "start_waveform_rms_um": e.start_waveform_rms_um,
        "waveform_rms_um": e.waveform_rms_um,
        "floor_um": e.last.repeatability.floor_um,
        "last_diagnosis": e.last.summary,
        "unexplained": e.last.unexplained,
        "test": e.last.test,
    })
}
