#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

pub mod cmd;
pub mod report;
