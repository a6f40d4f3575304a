#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

pub mod analysis;
pub mod effects;
mod linalg;
pub mod machine;
pub mod measure;
pub mod paper;
pub mod params;

pub use effects::{effect_params, EffectError, EffectSpec, ParamDef};
pub use machine::{Machine, MachineError, MachineOptions, StepInput, StepOutput};
pub use measure::{MeasureConfig, MeasureError, XMotion};
pub use params::{ParamsError, PlantParams, DEFAULT_PLANT_TOML};

/// Standard gravity, m/s^2.
pub const G_MPS2: f64 = 9.80665;
