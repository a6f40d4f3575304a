//! # sts-twin-core
//!
//! The one source of truth for everything the twin computes, shared bit for bit by the
//! firmware (in interrupt context, `no_std`, no heap) and the host tools:
//!
//! - [`features`]: the 12 accelerometer features of the paper's Table 1, streamed per sample
//!   in fixed point with O(1) work per sample.
//! - [`program`]: the twin program, a small validated stack-machine program holding the
//!   amplitude model, the phase model and extra error terms, serialised with postcard.
//! - [`axis`]: a servo-axis twin simulated tick by tick, for friction, hysteresis and encoder
//!   error, and the compensator that learns the correction through it at low priority.
//! - [`synth`]: per-tick synthesis of the predicted dynamic error (Eq. 4), phase-continuous.
//! - [`math`]: the table sine and exponential, the fixed-point helpers and the unit
//!   conversions the tick and the axis twin share.
//! - [`feedforward`]: predicted error to a DAC code (Eq. 5) with offset, slew limit and
//!   saturation counting.
//! - [`wire`]: the host <-> firmware control messages, COBS framing with a CRC.
//! - [`bus`]: the per-tick virtual analogue bus shared with the host in lockstep.
//! - [`commands`]: the recent ticks' commands, from the servo tick to the low-priority side.
//! - [`servo`]: the whole per-tick pipeline the firmware runs and the host simulates.
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
