//! A servo-axis twin: the Z slide under its position controller, simulated tick by tick from
//! the command, with the nonlinear effects a linear error model cannot carry
//! (Coulomb/Stribeck friction, presliding hysteresis, the encoder's interpolation error).
//!
//! Predicting (the host's `compare` and `fit`, through the synthesiser), its output is the
//! axis's whole dynamic error at the TCP (TCP minus command), the effects included; the
//! program's formulas are fitted on what it leaves. Compensating (the firmware, and the host
//! simulating it), the same simulation runs at low priority on the command plus its own
//! correction and learns the correction that cancels its error ([`compensate`]); the servo
//! tick only synthesises that correction's harmonics. The state is kept relative to the
//! command, so that single precision stays accurate to far below a nanometre at any absolute
//! position.
//!
//! The model (all forces per kg of moving mass, which is not identifiable from motion data):
//! a PID position controller with velocity and acceleration feedforward on the encoder
//! reading, a one-tick computation delay, a first-order current loop, the slide with
//! viscous drag, and one structural mode between slide and TCP driven by the slide's
//! acceleration, or two (a machine whose structure has a second resonance the first cannot
//! stand for: `fit --effect structural-mode` beside an axis effect). Its linear part is discretised exactly (zero-order hold, [`discretise`]);
//! the friction force is applied linearly implicitly, so the stiff law of a sticking slide
//! stays stable at the 8 kHz tick.
//!
//! Parameters come from `sts-twin fit --effect` (identified from a measurement); the
//! firmware validates them ([`AxisParams::check`]) and computes the coefficients when the
//! program is activated ([`AxisModel::new`]). A diverging state (an unstable parameter set)
//! is reset to rest and counted ([`AxisState::resets`]), never output.

pub mod compensate;
pub mod discretise;
mod model;

pub use model::{AxisModel, AxisState};

/// The table `exp(-x)`, smoothed sign and table sine of the axis twin, which live with the
/// rest of the core's arithmetic in [`crate::math`] (re-exported here, beside the model that uses them).
pub use crate::math;

use serde::{Deserialize, Serialize};

/// Largest command delay the axis model takes, ticks.
pub const MAX_CMD_DELAY_TICKS: u8 = 8;

/// Parameters of a servo-axis twin, as a program carries them.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AxisParams {
    /// Delay of the command inside the controller before the servo loop, ticks.
    pub cmd_delay_ticks: u8,
    /// Proportional gain per kg, (N/m)/kg = 1/s^2.
    pub kp_per_s2: f32,
    /// Integral gain per kg, 1/s^3.
    pub ki_per_s3: f32,
    /// Derivative gain per kg, 1/s.
    pub kd_per_s: f32,
    /// Velocity feedforward per kg, 1/s.
    pub vff_per_s: f32,
    /// Acceleration feedforward as a fraction of the moving mass.
    pub aff: f32,
    /// Viscous drag per kg, 1/s.
    pub viscous_per_s: f32,
    /// Current (force) loop time constant, s.
    pub current_tau_s: f32,
    /// Structural mode between slide and TCP: frequency, Hz.
    pub mode_freq_hz: f32,
    /// Its damping ratio.
    pub mode_damping: f32,
    /// Its displacement at the TCP per unit of slide motion.
    pub mode_tcp_gain: f32,
    /// Friction, if any.
    pub friction: Option<Friction>,
    /// Presliding hysteresis, if any.
    pub hysteresis: Option<Hysteresis>,
    /// Encoder interpolation error, if any.
    pub ripple: Option<Ripple>,
    /// A second structural mode between slide and TCP, driven like the first by the slide's
    /// acceleration, if any.
    pub second_mode: Option<StructuralMode>,
}

/// A structural mode between slide and TCP: `q'' + 2 zeta w q' + w^2 q = -g a_slide`, the
/// TCP displaced by `q`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StructuralMode {
    /// Natural frequency `w / 2 pi`, Hz.
    pub freq_hz: f32,
    /// Damping ratio `zeta`.
    pub damping: f32,
    /// Displacement at the TCP per unit of slide motion `g`.
    pub tcp_gain: f32,
}

/// Coulomb friction with a Stribeck peak: `F(v) = -(Fc + (Fs - Fc) exp(-(v/vs)^2)) s(v/v_smooth)`,
/// `s(y)` a smoothed sign close to `tanh` ([`crate::math::smooth_sign`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Friction {
    /// Coulomb (sliding) force per kg, m/s^2.
    pub coulomb_mps2: f32,
    /// Static (breakaway) force per kg, m/s^2.
    pub static_mps2: f32,
    /// Stribeck velocity, m/s.
    pub stribeck_mps: f32,
    /// Velocity below which the sign is smoothed, m/s.
    pub smooth_mps: f32,
}

/// Dahl presliding hysteresis: `dF = sigma dx (1 - F/Fmax sgn(dx))`, the force opposing the motion.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Hysteresis {
    /// Limit force per kg, m/s^2.
    pub force_mps2: f32,
    /// Initial stiffness per kg, 1/s^2.
    pub stiffness_per_s2: f32,
}

/// Encoder interpolation error: the reading is `x + a1 sin(theta) + a2 sin(2 theta)`,
/// `theta = 2 pi x / period + phase`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Ripple {
    /// First-harmonic amplitude, nm.
    pub amp_nm: f32,
    /// Second-harmonic amplitude, nm.
    pub harmonic2_nm: f32,
    /// `2^32 / period`, turns per nm.
    pub turns_per_nm: u32,
    /// Phase at position zero, turns (2^32 per turn).
    pub phase_turns: u32,
}

/// Why an [`AxisParams`] is refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum AxisError {
    /// A value is not finite or out of its documented range (the field's name).
    OutOfRange(&'static str),
}

impl core::fmt::Display for AxisError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::OutOfRange(field) => write!(f, "axis parameter {field} is not finite or out of its range"),
        }
    }
}

impl core::error::Error for AxisError {}

/// `lo <= x <= hi`, false for NaN.
fn within(x: f32, lo: f32, hi: f32) -> bool {
    x >= lo && x <= hi
}

/// The first failed check's field, as the error.
fn all_within(checks: &[(&'static str, bool)]) -> Result<(), AxisError> {
    match checks.iter().find(|(_, ok)| !ok) {
        Some((name, _)) => Err(AxisError::OutOfRange(name)),
        None => Ok(()),
    }
}

impl AxisParams {
    /// Checks every value is finite and physically plausible: gains and times positive
    /// and bounded so the coefficients and states stay well inside single precision.
    pub fn check(&self) -> Result<(), AxisError> {
        all_within(&[
            ("cmd_delay_ticks", self.cmd_delay_ticks <= MAX_CMD_DELAY_TICKS),
            ("kp_per_s2", within(self.kp_per_s2, 1.0, 1e9)),
            ("ki_per_s3", within(self.ki_per_s3, 0.0, 1e12)),
            ("kd_per_s", within(self.kd_per_s, 0.0, 1e6)),
            ("vff_per_s", within(self.vff_per_s, -1e6, 1e6)),
            ("aff", within(self.aff, -10.0, 10.0)),
            ("viscous_per_s", within(self.viscous_per_s, 0.0, 1e6)),
            ("current_tau_s", within(self.current_tau_s, 1e-6, 0.1)),
            ("mode_freq_hz", within(self.mode_freq_hz, 1.0, 3000.0)),
            ("mode_damping", within(self.mode_damping, 0.001, 10.0)),
            ("mode_tcp_gain", within(self.mode_tcp_gain, -100.0, 100.0)),
        ])?;
        if let Some(f) = &self.friction {
            all_within(&[
                ("friction.coulomb_mps2", within(f.coulomb_mps2, 0.0, 1e3)),
                ("friction.static_mps2", within(f.static_mps2, 0.0, 1e3)),
                ("friction.stribeck_mps", within(f.stribeck_mps, 1e-7, 1.0)),
                ("friction.smooth_mps", within(f.smooth_mps, 1e-8, 1.0)),
            ])?;
        }
        if let Some(h) = &self.hysteresis {
            if !within(h.force_mps2, 1e-6, 1e3) {
                return Err(AxisError::OutOfRange("hysteresis.force_mps2"));
            }
            if !within(h.stiffness_per_s2, 1.0, 1e10) {
                return Err(AxisError::OutOfRange("hysteresis.stiffness_per_s2"));
            }
        }
        if let Some(r) = &self.ripple {
            if !within(r.amp_nm, -1e4, 1e4) {
                return Err(AxisError::OutOfRange("ripple.amp_nm"));
            }
            if !within(r.harmonic2_nm, -1e4, 1e4) {
                return Err(AxisError::OutOfRange("ripple.harmonic2_nm"));
            }
            if r.turns_per_nm == 0 {
                return Err(AxisError::OutOfRange("ripple.turns_per_nm"));
            }
        }
        if let Some(m) = &self.second_mode {
            all_within(&[
                ("second_mode.freq_hz", within(m.freq_hz, 1.0, 3000.0)),
                ("second_mode.damping", within(m.damping, 0.001, 10.0)),
                ("second_mode.tcp_gain", within(m.tcp_gain, -100.0, 100.0)),
            ])?;
        }
        Ok(())
    }
}

/// The default emulated machine's axis (sts-emulator's built-in plant), per kg of its 45 kg
/// slide, without effects: for tests and examples, which add one.
#[cfg(any(test, feature = "std"))]
pub fn default_machine() -> AxisParams {
    let m = 45.0;
    AxisParams {
        cmd_delay_ticks: 2,
        kp_per_s2: 10.551e6 / m,
        ki_per_s3: 900.18e6 / m,
        kd_per_s: 0.017826e6 / m,
        vff_per_s: 450.0 / m,
        aff: 13.5 / m,
        viscous_per_s: 300.0 / m,
        current_tau_s: 80e-6,
        mode_freq_hz: 89.554,
        mode_damping: 0.28,
        mode_tcp_gain: 2.3662,
        friction: None,
        hysteresis: None,
        ripple: None,
        second_mode: None,
    }
}
