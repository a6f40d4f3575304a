#![doc = include_str!("../README.md")]
#![cfg_attr(not(feature = "std"), no_std)]
#![deny(missing_docs)]
#![forbid(unsafe_code)]

/// The servo rate: one tick of the co-processor (and of the motion controller's servo loop
/// it follows) every 125 us. Every rate and tick length of the host tools derives from it.
pub const SERVO_RATE_HZ: u32 = 8_000;

/// One servo tick, s.
pub const TICK_S: f64 = 1.0 / SERVO_RATE_HZ as f64;

pub mod analogue_path;
pub mod axis;
pub mod bus;
pub mod commands;
pub mod config;
pub mod control;
pub mod counters;
pub mod features;
pub mod feedforward;
pub mod math;
pub mod program;
pub mod servo;
pub mod supervisor;
pub mod synth;
pub mod twin;
pub mod wire;
