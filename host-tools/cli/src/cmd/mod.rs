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
pub mod range_twin;
pub mod regress;
mod status;
pub mod trial_table;
