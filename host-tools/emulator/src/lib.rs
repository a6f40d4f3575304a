//! # sts-emulator
//!
//! The emulated machine the firmware is tested against and the source of training and test
//! data until a lab's own measurements arrive: an A3200-like Z axis (digital PID servo loop
//! with velocity/acceleration feedforward and computation delay, analogue input converted to
//! motion pulses), the Z slide on hydrostatic bearings driven by a linear motor, a compliant
//! path from the encoder to the tool centre point (TCP) with a structural mode, and the
//! sensors (encoder, capacitance probe, accelerometer with its 16-bit ADC), plus eight
//! switchable physical effects ([`EFFECT_NAMES`]).
//!
//! - [`Machine`]: step it tick by tick at 8 kHz (the HIL harness drives it in closed loop).
//! - [`measure`]: the offline dynamic-error measurement test (99 groups) into a dataset.
//! - [`paper`]: the default machine against the paper's figures.
//!
//! ```
//! use sts_emulator::{Machine, PlantParams, StepInput};
//! let mut machine = Machine::new(&PlantParams::default(), &[], 7).unwrap();
//! let out = machine.step(&StepInput { z_cmd_um: 0.0, ..StepInput::default() });
//! assert_eq!(out.time_s, 0.0);
//! assert!((machine.time_s() - 1.0 / 8000.0).abs() < 1e-15);
//! ```
#![deny(missing_docs)]

pub mod analysis;
pub mod effects;
mod linalg;
pub mod machine;
pub mod measure;
pub mod paper;
pub mod params;

pub use effects::{EffectError, EffectKind, EffectSpec, ParamDef, EFFECT_NAMES};
pub use machine::{Machine, MachineError, MachineOptions, StepInput, StepOutput, TICK_S};
pub use measure::{MeasureConfig, MeasureError, XMotion};
pub use params::{ParamsError, PlantParams, DEFAULT_PLANT_TOML, SERVO_RATE_HZ};

/// Standard gravity, m/s^2.
pub const G_MPS2: f64 = 9.80665;
