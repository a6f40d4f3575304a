//! Assessing a model against a measurement: [`compare`] (the predicted dynamic error against
//! the measured one, group by group) and [`diagnose`] (which physical effect is missing).
#![deny(missing_docs)]

pub mod compare;
pub mod diagnose;
mod error;

pub use error::AssessError;
