#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

pub mod effects;
mod error;
pub mod formulas;

pub use error::FitError;

pub use formulas::*;
