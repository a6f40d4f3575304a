//! Errors of assessing a model against a measurement.

use sts_analysis::AnalysisError;
use sts_fit::FitError;
use sts_model::ModelError;

/// Why a model could not be compared with or diagnosed on a dataset.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AssessError {
    /// The model's firmware program could not be decoded.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// A group's features or targets could not be computed.
    #[error(transparent)]
    Analysis(#[from] AnalysisError),
    /// A search of the data's own error (the in-band mode) could not be fitted.
    #[error(transparent)]
    Fit(#[from] FitError),
}
