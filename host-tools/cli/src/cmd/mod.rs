//! One module per `sts-twin` subcommand: its arguments and its `run`.

pub mod board;
pub mod calibrate;
pub mod compare;
pub mod demo;
pub mod diagnose;
pub mod explain;
pub mod export;
pub mod fit;
pub mod hil;
pub mod import;
pub mod machine;
pub mod measure;
pub mod paper_table;
pub mod regress;
mod status;
pub mod trial_table;

/// Named parameters (name with unit, value) as a JSON object, in their order.
pub(crate) fn params_json(params: &[(String, f64)]) -> serde_json::Map<String, serde_json::Value> {
    params.iter().map(|(k, v)| (k.clone(), serde_json::json!(v))).collect()
}
