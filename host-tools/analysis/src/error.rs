//! Errors of turning a dataset into what the twin learns from.

use sts_dataset::DatasetError;

use crate::features::FeatureExtractionError;
use crate::targets::TargetError;
use sts_twin_core::SERVO_RATE_HZ;

/// Why a dataset could not be read or turned into group samples.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AnalysisError {
    /// The dataset could not be read (the error names the file, and the line and column).
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    /// The dataset is not sampled at the co-processor's servo rate.
    #[error(
        "the dataset is sampled at {sample_rate_hz} Hz and the co-processor's servo runs at {SERVO_RATE_HZ} Hz: resample it first (`analysis::resample::to_servo_rate`; the sts-twin commands do it themselves)"
    )]
    SampleRate {
        /// The dataset's sample rate, Hz.
        sample_rate_hz: f64,
    },
    /// A group's features could not be computed.
    #[error("{file}: {error}")]
    Features {
        /// The group's file.
        file: String,
        /// Why (part of the message).
        error: FeatureExtractionError,
    },
    /// A group's targets could not be measured.
    #[error("{file}: {error}")]
    Targets {
        /// The group's file.
        file: String,
        /// Why (part of the message).
        error: TargetError,
    },
}
