#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

pub mod bases;
mod error;
pub mod features;
pub mod probe_scale;
pub mod repeat;
pub mod resample;
pub mod response;
pub mod samples;
pub mod score;
pub mod sine;
pub mod targets;

pub use error::AnalysisError;
pub use samples::{
    feature_config_for, feature_start, group_samples, group_samples_skipping, read_dataset, training_table_csv,
    unwrap_phases, GroupSample, DEFAULT_SKIP_S, FEATURE_WINDOW_S,
};
