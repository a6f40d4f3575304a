//! One module per `sts-twin` subcommand: its arguments and its `run`.

pub mod demo;
pub mod fit;
pub mod machine;
pub mod measure;
pub mod paper_table;
pub mod regress;
