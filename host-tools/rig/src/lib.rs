#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

pub mod calibrate;
mod coprocessor;
mod error;
mod faults;
mod hil;
mod lossy;
pub mod plant;
mod serial;
mod sim;
mod trajectory;
pub mod trial;

pub use faults::{degraded_reasons, fault_report, gate_report, print_fault_report};
pub use hil::{request_on, HilCoprocessor, REQUEST_TIMEOUT};
pub use lossy::LossyHilCoprocessor;
pub use plant::{Plant, PlantInput, PlantReading};
pub use serial::SerialCoprocessor;
pub use sim::SimCoprocessor;
pub use sts_link::{FrameFate, FrameInjector, InjectedFaults, LinkFaults, LinkStats, RetryPolicy};
pub use trajectory::{Bicuspid, Sinusoid, Trajectory, TrajectoryPoint};

pub use coprocessor::*;
pub use error::RigError;
