//! One module per `sts-twin` subcommand: its arguments and its `run`.

pub mod fit;
pub mod measure;
pub mod paper_table;
pub mod regress;
