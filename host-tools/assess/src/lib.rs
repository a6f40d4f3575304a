#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

pub mod absorbed;
pub mod compare;
pub mod diagnose;
mod error;
pub mod explain;
pub mod json;

pub use error::AssessError;
