//! Calibrating the co-processor against the machine: the analogue path's phase.

pub mod path;

pub use path::{measure_path, path_table, PathConfig, PathPoint};
