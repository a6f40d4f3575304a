//! One module per `sts-twin` subcommand: its arguments and its `run`.

pub mod measure;
pub mod regress;
