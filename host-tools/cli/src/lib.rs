//! # sts-twin
//!
//! The `sts-twin` command over the library crates, which form the data flow: `sts-analysis`
//! -> `sts-model` -> `sts-fit` / `sts-assess` -> `sts-hil` -> `sts-rig`. Here are only the
//! commands (one module each) and the reports they write.
#![deny(missing_docs)]

pub mod cmd;
pub mod report;
