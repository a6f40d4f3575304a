#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

pub mod effects;
pub mod formulas;

pub use formulas::*;
