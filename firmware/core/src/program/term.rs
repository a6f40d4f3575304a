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
}

impl TickTerm {
    /// Whether the term is well formed given the set of registers the code stores.
    pub(super) fn check(&self, written: u16) -> bool {
        match *self {
            Self::Harmonic { order, amp_reg, phase_reg } => {
                (1..=MAX_HARMONIC_ORDER).contains(&order) && register_ok(amp_reg, written) && register_ok(phase_reg, written)
            }
        }
    }
}
