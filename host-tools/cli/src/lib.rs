//! # sts-twin
//!
//! The library under the `sts-twin` command: every command is a thin layer over a function
//! here, so that tests and other programs drive the same code the user runs.
#![deny(missing_docs)]

pub mod analysis;
pub mod calibrate;
pub mod cmd;
pub mod compare;
pub mod diagnose;
pub mod effects;
pub mod fit;
pub mod hil;
pub mod model;
pub mod report;
pub mod rig;
pub mod trial;
