//! The closed loop: the emulated machine and a co-processor (the firmware in QEMU, or the
//! same core simulated on the host) stepped together at the servo rate.
//!
//! Tick `k`: the machine steps with the command of tick `k` and the analogue input the
//! co-processor wrote at tick `k - 1`; its accelerometer code and the command phase go to the
//! co-processor, whose DAC code for tick `k` reaches the machine at tick `k + 1`.

#![deny(missing_docs)]

pub mod calibrate;
mod coprocessor;
mod error;
mod faults;
mod hil;
mod lossy;
mod sim;
mod trajectory;
pub mod trial;

pub use faults::{degraded_reasons, fault_report, print_fault_report};
pub use hil::{request_on, HilCoprocessor, REQUEST_TIMEOUT};
pub use lossy::{FrameFate, FrameInjector, InjectedFaults, LinkFaults, LinkStats, LossyHilCoprocessor, RetryPolicy};
pub use sim::SimCoprocessor;
pub use trajectory::{Bicuspid, Sinusoid, Trajectory, TrajectoryPoint};

pub use coprocessor::*;
pub use error::RigError;
