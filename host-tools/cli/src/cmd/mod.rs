//! One module per `sts-twin` subcommand: its arguments and its `run`.

pub mod calibrate;
pub mod compare;
pub mod demo;
pub mod diagnose;
pub mod explain;
pub mod fit;
pub mod hil;
pub mod machine;
pub mod measure;
pub mod paper_table;
pub mod regress;
pub mod trial_table;
