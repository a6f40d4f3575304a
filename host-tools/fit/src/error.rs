//! Errors of fitting the twin: the formulas' searches and the physical-effect terms.

use std::path::PathBuf;

use sts_analysis::targets::TargetError;
use sts_analysis::AnalysisError;
use sts_model::{Effect, ModelError};
use sts_symreg::SymregError;
use sts_twin_core::axis::{AxisError, AxisParams};
use sts_twin_core::program::{
    ProgramError, MAX_TERMS, RESONANCE_DAMPING_RANGE, RESONANCE_FREQ_RANGE_HZ, RESONANCE_GAIN_MAX,
};

use crate::target::Target;

/// Why the twin could not be fitted, or its effect terms not attached or recorded.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FitError {
    /// The groups' features or targets could not be computed.
    #[error(transparent)]
    Analysis(#[from] AnalysisError),
    /// The model's firmware program could not be decoded.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// The symbolic regression refused its data or settings.
    #[error(transparent)]
    Symreg(#[from] SymregError),
    /// Too few groups for a search.
    #[error("only {groups} groups can train the {target:?} model; at least 4 are needed")]
    TooFewGroups {
        /// The groups that can train it.
        groups: usize,
        /// The model.
        target: Target,
    },
    /// One search of the fit failed: the final one (`fold` `None`) or a fold's.
    #[error("{}", search_name(*.target, *.fold))]
    Search {
        /// The model searched for.
        target: Target,
        /// The cross-validation fold, `None` for the final search.
        fold: Option<usize>,
        /// Why.
        #[source]
        source: Box<FitError>,
    },
    /// A search thread panicked.
    #[error("a search panicked")]
    SearchPanicked,
    /// The searches' thread pool could not be started.
    #[error("cannot start {threads} threads: {error}")]
    ThreadPool {
        /// The threads asked for.
        threads: usize,
        /// Why (part of the message).
        error: rayon::ThreadPoolBuildError,
    },
    /// A fold's formulas do not compile to a program.
    #[error("fold {fold}: {error}")]
    FoldProgram {
        /// The fold.
        fold: usize,
        /// Why (part of the message).
        error: ProgramError,
    },
    /// The selected formulas do not compile to a program.
    #[error("final model: {error}")]
    FinalProgram {
        /// Why (part of the message).
        error: ProgramError,
    },
    /// A program does not fit the postcard buffer.
    #[error("cannot serialise the program: {error}")]
    Serialise {
        /// Why (part of the message).
        error: postcard::Error,
    },
    /// `--effect` names an effect that is not known.
    #[error(
        "--effect: unknown effect {name:?} (known: {}, and servo-axis: the servo-axis twin alone)",
        Effect::names()
    )]
    UnknownEffect {
        /// The name given.
        name: String,
    },
    /// A group's targets could not be measured for the effect terms.
    #[error("{file}")]
    Targets {
        /// The group's file.
        file: String,
        /// Why.
        #[source]
        source: TargetError,
    },
    /// An effect term's coefficient does not fit the firmware's fixed point.
    #[error("--effect {effect}: a coefficient of {value_um} um does not fit the firmware's term (at most 2147 um); the measurement does not show that effect in a usable form")]
    TermOutOfRange {
        /// The effect.
        effect: String,
        /// The coefficient, um per unit input.
        value_um: f64,
    },
    /// An in-band mode's resonance is outside the firmware term's ranges.
    #[error(
        "--effect structural-mode: the mode at {freq_hz:.2} Hz, damping {damping:.3}, gain {gain} is outside what the firmware's resonance holds ({}-{} Hz, damping {}-{}, gain at most {}); the measurement does not show that mode in a usable form",
        RESONANCE_FREQ_RANGE_HZ.0, RESONANCE_FREQ_RANGE_HZ.1, RESONANCE_DAMPING_RANGE.0, RESONANCE_DAMPING_RANGE.1, RESONANCE_GAIN_MAX
    )]
    ResonanceOutOfRange {
        /// The mode's frequency, Hz.
        freq_hz: f64,
        /// Its damping ratio.
        damping: f64,
        /// Its gain.
        gain: f64,
    },
    /// The effects need more per-tick terms than a program holds.
    #[error("--effect: {needed} per-tick terms needed, the program holds at most {MAX_TERMS}")]
    TooManyTerms {
        /// Terms needed.
        needed: usize,
    },
    /// The identified servo axis diverges on a group's motion.
    #[error("the identified servo axis diverges on the motion of {file} (its loop is unstable there: {axis:?}); the measurement may not show enough of the axis to identify it")]
    AxisDiverges {
        /// The group's file.
        file: String,
        /// The identified axis.
        axis: Option<Box<AxisParams>>,
    },
    /// Identifying the servo axis failed.
    #[error("identifying the servo axis")]
    IdentifyAxis {
        /// Why.
        #[source]
        source: Box<FitError>,
    },
    /// The axis twin needs the servo rate.
    #[error("the axis twin needs samples at the 8 kHz servo rate, the dataset has {sample_rate_hz} Hz")]
    AxisSampleRate {
        /// The dataset's sample rate, Hz.
        sample_rate_hz: f64,
    },
    /// The dataset has no groups.
    #[error("the dataset has no groups")]
    NoGroups,
    /// No start of the axis search.
    #[error("no start")]
    NoStart,
    /// No start of the structural mode's search.
    #[error("no mode start")]
    NoModeStart,
    /// The identified axis is outside what the firmware accepts.
    #[error("the identified axis is not usable: {error:?} ({params:?})")]
    AxisUnusable {
        /// Why (part of the message).
        error: AxisError,
        /// The identified axis.
        params: Box<AxisParams>,
    },
    /// `--effect axis-coupling` on a dataset without the columns it needs.
    #[error("--effect axis-coupling: the dataset has no x_acc_mps2 or spindle_deg column")]
    NoCouplingColumns,
    /// The program has no room for the effect terms.
    #[error("too many per-tick terms")]
    TermsFull,
    /// The program with the effect terms does not validate.
    #[error("program with effect terms: {error}")]
    EffectProgram {
        /// Why (part of the message).
        error: ProgramError,
    },
    /// A model file could not be read for its effect records.
    #[error("cannot read {path}")]
    Read {
        /// The model file.
        path: PathBuf,
        /// The operating system's reason.
        #[source]
        source: std::io::Error,
    },
    /// A model file is not JSON.
    #[error("{path}: not JSON")]
    NotJson {
        /// The model file.
        path: PathBuf,
        /// The parser's reason.
        #[source]
        source: serde_json::Error,
    },
    /// A model file's `effects` field is not a list of effect records.
    #[error("{path}: field `effects`")]
    EffectsField {
        /// The model file.
        path: PathBuf,
        /// The parser's reason.
        #[source]
        source: serde_json::Error,
    },
    /// The effect records could not be encoded as JSON.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// A model file could not be written whole with its effect records.
    #[error(transparent)]
    Output(#[from] sts_dataset::DatasetError),
    /// The fit was stopped through [`crate::FitConfig::stop`] before it finished.
    #[error("stopped before the fit finished")]
    Stopped,
}

/// "final Amplitude search", "Phase search of fold 2".
fn search_name(target: Target, fold: Option<usize>) -> String {
    match fold {
        Some(fold) => format!("{target:?} search of fold {fold}"),
        None => format!("final {target:?} search"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The message and its causes, as the sts-twin command prints an error (`{:#}`).
    fn chain(error: &dyn std::error::Error) -> String {
        std::iter::successors(Some(error), |e| e.source()).map(|e| e.to_string()).collect::<Vec<_>>().join(": ")
    }

    #[test]
    fn a_search_and_a_group_are_named_before_their_cause() {
        let too_few = |target| Box::new(FitError::TooFewGroups { groups: 3, target });
        let final_search =
            FitError::Search { target: Target::Amplitude, fold: None, source: too_few(Target::Amplitude) };
        assert_eq!(final_search.to_string(), "final Amplitude search");
        assert_eq!(
            chain(&final_search),
            "final Amplitude search: only 3 groups can train the Amplitude model; at least 4 are needed"
        );
        let fold_search = FitError::Search { target: Target::Phase, fold: Some(2), source: too_few(Target::Phase) };
        assert_eq!(
            chain(&fold_search),
            "Phase search of fold 2: only 3 groups can train the Phase model; at least 4 are needed"
        );
        let group = FitError::Targets { file: "g001.csv".into(), source: TargetError::NoCommand { freq_hz: 10.0 } };
        assert_eq!(chain(&group), "g001.csv: the command has no sinusoid at 10 Hz to measure the phase against");
        let axis = FitError::IdentifyAxis { source: Box::new(FitError::NoGroups) };
        assert_eq!(chain(&axis), "identifying the servo axis: the dataset has no groups");
    }
}
