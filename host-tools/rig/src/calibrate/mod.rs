//! Calibrating the co-processor against the machine before a cut: the analogue interface's
//! offset, `K_dv`, the analogue path's phase, stored in the firmware's persistent config and
//! verified after a reboot (`sts-twin calibrate-offset`, [`calibrate`]).
//!
//! The measurements ([`measure_params`], [`measure_path`], and the offset, `K_dv` and enable
//! check on a [`RestRig`]) run on any machine stepped as a [`crate::Plant`]; [`calibrate`]
//! builds the emulated machine itself from the plant parameters, effects and seed it is
//! given (the command's options).

pub mod board;
pub mod enable;
pub mod instruments;
pub mod kdv;
pub mod lab;

pub mod offset;
pub mod path;
pub mod procedure;
pub mod rest;

pub use board::{Board, HilBoard};
pub use enable::{enable_check, EnableCheck, EnableConfig};
pub use instruments::{CommandInstruments, PromptInstruments};
pub use kdv::{measure_kdv, KdvConfig, KdvPoint, KdvReport};
pub use lab::{calibrate_lab, LabCalibration, LabConfig, LabInstruments, LabPoint};
pub use offset::{measure_offset, OffsetConfig, OffsetPoint, OffsetReport};
pub use path::{measure_path, path_table, PathConfig, PathPoint};
pub use procedure::{
    calibrate, describe_config_source, measure_params, BootState, CalibrationConfig, CalibrationReport, Measured,
    StoreCheck,
};
pub use rest::{RestAverage, RestRig};

/// The emulated machine's types the calibration takes, for callers without the emulator
/// crate (the HIL tests).
pub use sts_emulator::{EffectSpec, Machine, PlantParams};
