#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

pub mod effects;
mod error;
pub mod formulas;
mod target;

pub use error::FitError;
pub use target::Target;

pub use formulas::*;
pub use sts_symreg::StopFlag;
