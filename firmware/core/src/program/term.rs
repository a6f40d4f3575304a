//! Per-tick error terms: what the servo interrupt adds to the fundamental every tick, with
//! coefficients computed by the program at the model-update rate.

use serde::{Deserialize, Serialize};

use super::validate::register_ok;

/// Highest harmonic order a [`TickTerm::Harmonic`] may have.
pub const MAX_HARMONIC_ORDER: u8 = 15;

/// One per-tick error term. Its coefficients live in program registers, so the slow
/// model update computes them from the features and the servo tick only evaluates a kernel.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TickTerm {
    /// `amp * sin(order * theta + phase)`: a harmonic of the command phase `theta`
    /// (odd harmonics from friction and hysteresis, for instance).
    Harmonic {
        /// The harmonic order, 1 to [`MAX_HARMONIC_ORDER`].
        order: u8,
        /// Register holding the amplitude, micrometres.
        amp_reg: u8,
        /// Register holding the phase, degrees.
        phase_reg: u8,
    },
    /// Slow drift of the tool (thermal growth): `offset + decay * exp(-t / tau)` at the
    /// synthesiser's machine time `t` (ticks since it started, see `Synth::set_time_ticks`).
    Drift {
        /// Level approached for `t -> infinity`, picometres.
        offset_pm: i32,
        /// Part that decays with `tau`, picometres (negative for a growing error).
        decay_pm: i32,
        /// Time constant, servo ticks (at least 256).
        tau_ticks: u32,
    },
    /// Another axis moving the tool in Z: `x_gain * x_acc + spindle_amp * sin(spindle + phase)`
    /// from the tick's X acceleration and spindle angle.
    AxisCoupling {
        /// Z deflection per X acceleration, picometres per (m/s^2).
        x_gain_pm_per_mps2: i32,
        /// Once-per-revolution spindle error, picometres.
        spindle_amp_pm: i32,
        /// Its phase at spindle angle zero, turns (2^32 per turn).
        spindle_phase_turns: u32,
    },
    /// A Laguerre filter bank (pole `a`, [`LAGUERRE_STAGES`] stages) driven by a nonlinear
    /// function of the command: the response of the servo loop to a friction force, a
    /// presliding (Dahl) force or a position-periodic encoder error.
    Laguerre {
        /// What drives the filter.
        input: TermInput,
        /// The pole `a`, Q30 (0 < a < 1).
        pole_q30: i32,
        /// Output weight of each stage, picometres per unit stage output.
        gains_pm: [i32; LAGUERRE_STAGES],
    },
}

/// Stages of a [`TickTerm::Laguerre`] filter bank.
pub const LAGUERRE_STAGES: usize = 8;

/// The signal driving a [`TickTerm::Laguerre`] bank, computed every tick from the command
/// position (`cmd_pos_nm`), scaled to at most 1 in magnitude.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TermInput {
    /// Friction: the sign of the command velocity, smoothed: `clamp(v / v_smooth, -1, 1)`
    /// with `v` the command position's change over 4 ticks.
    VelocitySign {
        /// `v_smooth` in nanometres per 4 ticks (at least 1).
        smooth_nm_per_4_ticks: i32,
    },
    /// Presliding hysteresis: the Dahl state `u` with `du/dx = (1 - u sgn(dx)) / x0`.
    Dahl {
        /// `1 / x0` in Q30 per nanometre.
        inv_x0_q30: i32,
    },
    /// Position-periodic error: `sin(2 pi x / period + phase)` of the command position.
    PositionSine {
        /// `2^32 / period` in turns per nanometre.
        turns_per_nm: u32,
        /// Phase at position zero, turns.
        phase_turns: u32,
    },
}

impl TickTerm {
    /// Whether the term is well formed given the set of registers the code stores.
    pub(super) fn check(&self, written: u16) -> bool {
        match *self {
            Self::Harmonic { order, amp_reg, phase_reg } => {
                (1..=MAX_HARMONIC_ORDER).contains(&order) && register_ok(amp_reg, written) && register_ok(phase_reg, written)
            }
            Self::Drift { tau_ticks, .. } => tau_ticks >= 256,
            Self::AxisCoupling { .. } => true,
            Self::Laguerre { input, pole_q30, .. } => {
                let input_ok = match input {
                    TermInput::VelocitySign { smooth_nm_per_4_ticks } => smooth_nm_per_4_ticks >= 1,
                    TermInput::Dahl { inv_x0_q30 } => inv_x0_q30 > 0,
                    TermInput::PositionSine { turns_per_nm, .. } => turns_per_nm > 0,
                };
                input_ok && pole_q30 > 0 && pole_q30 < (1 << 30)
            }
        }
    }
}
