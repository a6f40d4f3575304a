//! Fitting the twin to a dataset: the explainable amplitude and phase formulas
//! ([`formulas`], symbolic regression), and the physical-effect terms of the firmware program
//! ([`effects`], `fit --effect`).
#![deny(missing_docs)]

pub mod effects;
mod error;
pub mod formulas;

pub use error::FitError;

pub use formulas::*;
