#![doc = include_str!("../README.md")]
#![cfg_attr(not(feature = "std"), no_std)]
#![deny(missing_docs)]
#![forbid(unsafe_code)]

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
pub mod synth;
pub mod twin;
pub mod wire;
