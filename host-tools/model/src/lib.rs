//! The twin as a file and as the board runs it: the model file `sts-twin-model/1` (the
//! fitted formulas as text, their statistics, the feature settings, and the firmware program
//! ready to upload) and the replay of a model on a measured group, through the firmware's own
//! program interpreter and synthesiser.
#![deny(missing_docs)]

mod compile;
mod error;
mod file;
pub mod replay;

pub use compile::{compile_program, expr_to_code};
pub use error::{ModelError, ModelFileError};
pub use file::*;
