#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

mod compile;
mod effect;
mod error;
pub mod export;
mod file;
pub mod replay;

pub use compile::{compile_program, expr_to_code};
pub use effect::{Effect, FitEffect, UnknownEffect, SERVO_AXIS};
pub use error::{ModelError, ModelFileError};
pub use file::*;
