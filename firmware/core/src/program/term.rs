//! Per-tick error terms: what the servo interrupt adds to the fundamental every tick, with
//! coefficients computed by the program at the model-update rate.

use serde::{Deserialize, Serialize};

use super::REGISTER_COUNT;
use crate::axis::AxisParams;

/// Largest pole (Q30, 0.995) whose Laguerre stages are computed in 32 bits.
///
/// Why they fit: with `|u| <= 1` every stage is bounded by the l1 norm of its impulse
/// response from the input, times `2^24 sqrt(1 - a^2)`, plus the rounding of the shifts
/// (at most one unit per shift, through the same filters). At `a = 0.995` that is below
/// `0.45 * 2^31` for every stage (`synth::kernel`'s test `narrow_stages_are_bounded_well_inside_i32` computes it),
/// so twice a stage fits in 32 bits, the product terms (`2a * 2y`, below `2^62`) and their
/// sums (below `2^63`) are exact in 64 bits, and with gains of at most 2^32 in sum the
/// weighted sum of the doubled stages cannot overflow either: the 32-bit stages give the
/// 64-bit ones' output bit for bit (`narrow_and_wide_laguerre_banks_agree_bit_for_bit`
/// checks it at the limits).
pub const NARROW_POLE_MAX_Q30: i32 = (1 << 30) / 200 * 199;

/// Whether a Laguerre bank with pole `pole_q30` and gains `gains_pm` runs on 32-bit stages
/// (otherwise on 64-bit ones, about twice the instructions).
pub fn laguerre_stages_are_narrow(pole_q30: i32, gains_pm: &[i32; LAGUERRE_STAGES]) -> bool {
    let gain_sum: u64 = gains_pm.iter().map(|g| u64::from(g.unsigned_abs())).sum();
    pole_q30 > 0 && pole_q30 <= NARROW_POLE_MAX_Q30 && gain_sum <= 1 << 32
}

/// Smoothing velocities (nm per 4 ticks) below this are divided by in 32 bits; at or above,
/// a 64-bit division (a library call) does it.
pub const VELOCITY_SMOOTH_32_BIT_LIMIT: i32 = 1 << 17;

/// Lowest and highest mode frequency a [`TickTerm::Resonance`] may have, Hz (well inside the
/// tick's Nyquist frequency, and far enough from zero that the poles are resolved in f32).
pub const RESONANCE_FREQ_RANGE_HZ: (f32, f32) = (0.5, 1000.0);
/// Lowest and highest damping ratio of a [`TickTerm::Resonance`] (underdamped: the closed
/// forms of `synth::resonance`).
pub const RESONANCE_DAMPING_RANGE: (f32, f32) = (0.005, 0.95);
/// Largest gain magnitude of a [`TickTerm::Resonance`] (tool motion per unit of the
/// high-passed command).
pub const RESONANCE_GAIN_MAX: f32 = 20.0;

/// Whether a resonance's parameters are within the ranges the closed forms and f32 hold.
pub fn resonance_params_ok(freq_hz: f32, damping: f32, gain: f32) -> bool {
    (RESONANCE_FREQ_RANGE_HZ.0..=RESONANCE_FREQ_RANGE_HZ.1).contains(&freq_hz)
        && (RESONANCE_DAMPING_RANGE.0..=RESONANCE_DAMPING_RANGE.1).contains(&damping)
        && gain.is_finite()
        && gain.abs() <= RESONANCE_GAIN_MAX
}

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
    /// A servo-axis twin ([`crate::axis`]): the axis's dynamic error at the TCP, friction,
    /// presliding hysteresis or the encoder's interpolation error included, simulated tick
    /// by tick from the command through the identified controller, slide and structural
    /// mode. The servo compensates through it at low priority
    /// ([`crate::axis::compensate`]) and synthesises the correction's third harmonic in this
    /// term's slot (its fundamental joins the program's).
    Axis(AxisParams),
    /// A structural mode between slide and tool: `gain * H(s) x` with the second-order
    /// high-pass `H = s^2 / (s^2 + 2 zeta w s + w^2)` of the command position `x` (the mode
    /// driven by the slide's acceleration), stepped every tick in f32
    /// (`synth::resonance`). A mode inside the measurement's band, whose resonance the
    /// amplitude and phase formulas cannot follow.
    Resonance {
        /// The mode's natural frequency, Hz.
        freq_hz: f32,
        /// Its damping ratio (underdamped).
        damping: f32,
        /// Tool motion per unit of the high-passed command.
        gain: f32,
    },
    /// A slot in which the servo synthesises a higher harmonic of the [`TickTerm::Axis`]
    /// twin's correction (`order` times the command frequency; its compensator learns it
    /// where that lies below [`crate::axis::compensate::MAX_HARMONIC_HZ`], and it is silent
    /// elsewhere). Valid only beside an axis term, with an order of its own, 2 to
    /// [`MAX_HARMONIC_ORDER`] and not the third (the axis term's own slot carries that).
    AxisHarmonic {
        /// The harmonic order.
        order: u8,
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
                (1..=MAX_HARMONIC_ORDER).contains(&order)
                    && register_ok(amp_reg, written)
                    && register_ok(phase_reg, written)
            }
            Self::Drift { tau_ticks, .. } => tau_ticks >= 256,
            Self::AxisCoupling { .. } => true,
            Self::Axis(params) => params.check().is_ok(),
            Self::AxisHarmonic { order } => {
                (2..=MAX_HARMONIC_ORDER).contains(&order)
                    && !crate::axis::compensate::BASE_ORDERS.contains(&u32::from(order))
            }
            Self::Resonance { freq_hz, damping, gain } => resonance_params_ok(freq_hz, damping, gain),
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

/// Instructions the servo tick may take on the target, from the input's arrival to the
/// output written (the budget [`Program::validate`](super::Program::validate) holds every
/// program to).
pub const TICK_BUDGET_INSTRUCTIONS: u32 = 800;

/// The worst servo tick's instructions as a sum over a program's terms (Cortex-M4F, the
/// firmware's `firmware` profile, counted under QEMU `-icount` by `twin_bench`; each share is
/// the worst measured tick rounded up by one or two, for the bench timer's steps of 0.625
/// instructions and for register allocation, which moves a tick by a few).
///
/// The tick's extra work (the end or start of a 16-sample feature block, a model request,
/// applying a model result) never falls on the same tick twice: requests and results come
/// half a block away from the block ends, and a late result waits for a tick without either.
/// [`FIXED`](tick_cost::FIXED) is the worst such tick of a program without per-tick terms;
/// each term adds its own share, the same on every tick.
///
/// A program switch stays within the larger of the two programs' costs: the old program's
/// harmonics that go ramp out over the synthesiser's ramp (80 ticks) and are then dropped,
/// and meanwhile the new program's kernel terms (and harmonics taking a fading one's slot)
/// wait, starting with the first model result after (see `Synth::apply`). What a tick runs
/// meanwhile (the old harmonics, the kernel terms both keep, new harmonics in other slots)
/// lies within the old program's slots or, if a new harmonic lies beyond them, within the
/// new one's, each term costing at most what that program has in its slot (a harmonic
/// standing for a kernel term costs less, every term at least a harmonic). The fade's last
/// tick, which silences the faded slots, steps no ramp.
pub mod tick_cost {
    /// A tick without per-tick terms at its worst: the paper program's, whose formulas are
    /// not evaluated in the tick (the model update runs at low priority).
    pub const FIXED: u32 = 534;
    /// More for a servo-axis twin, whose correction is synthesised as a harmonic term: the
    /// tick stores its command in the ring the twin's compensator reads at low priority.
    pub const AXIS_COMMANDS: u32 = 20;
    /// A harmonic term in a program without kernel terms.
    pub const HARMONIC: u32 = 26;
    /// A harmonic term in a program with kernel terms (the harmonic pass then skips the
    /// kernel slots by a bit mask).
    pub const HARMONIC_BESIDE_KERNELS: u32 = 42;
    /// Once, when the program has kernel terms (anything but harmonics): running them.
    pub const KERNELS: u32 = 42;
    /// A Laguerre bank on the position sine, with 32-bit stages; high enough that the
    /// two-bank program and three harmonics beside a bank, which measure over the budget,
    /// are refused.
    pub const LAGUERRE_POSITION_SINE: u32 = 119;
    /// A Laguerre bank on the velocity sign, with 32-bit stages and divisions.
    pub const LAGUERRE_VELOCITY_SIGN: u32 = 145;
    /// A Laguerre bank on the Dahl state, with 32-bit stages.
    pub const LAGUERRE_DAHL: u32 = 162;
    /// More for a Laguerre bank whose stages need 64 bits: a pole above 0.995 or gains
    /// above 2^32 in sum.
    pub const LAGUERRE_WIDE_STAGES: u32 = 178;
    /// More for a velocity-sign bank whose smoothing velocity needs a 64-bit division
    /// (2^17 nm per 4 ticks or more, 262 mm/s): a library call whose length depends on the
    /// operands, so this is its worst case.
    pub const VELOCITY_64_BIT_DIVISION: u32 = 260;
    /// A drift term, with its 64-bit step every 256 ticks.
    pub const DRIFT: u32 = 53;
    /// An axis-coupling term: the X gain is taken to Q20 when the term starts, so the tick
    /// multiplies rather than divides. A velocity bank beside it is accepted, a Dahl bank
    /// beside it is not.
    pub const AXIS_COUPLING: u32 = 65;
    /// A resonance: its f32 state update and one saturating conversion (an `i64` conversion
    /// would be a library call); the in-band mode's program (a velocity bank and a
    /// resonance) comes to the budget exactly.
    pub const RESONANCE: u32 = 79;
}

impl TickTerm {
    /// Instructions this term adds to the worst servo tick ([`tick_cost`]), in a program that
    /// has kernel terms (`with_kernels`) or not.
    pub fn tick_cost(&self, with_kernels: bool) -> u32 {
        use tick_cost::*;
        match *self {
            // The servo synthesises the axis twin's correction as a harmonic in its slot (its
            // simulation runs at low priority, see `Models::compute`).
            Self::Harmonic { .. } | Self::AxisHarmonic { .. } if with_kernels => HARMONIC_BESIDE_KERNELS,
            Self::Harmonic { .. } | Self::AxisHarmonic { .. } => HARMONIC,
            Self::Axis(_) if with_kernels => HARMONIC_BESIDE_KERNELS + AXIS_COMMANDS,
            Self::Axis(_) => HARMONIC + AXIS_COMMANDS,
            Self::Drift { .. } => DRIFT,
            Self::AxisCoupling { .. } => AXIS_COUPLING,
            Self::Resonance { .. } => RESONANCE,
            Self::Laguerre { input, pole_q30, ref gains_pm } => {
                let bank = match input {
                    TermInput::VelocitySign { smooth_nm_per_4_ticks }
                        if smooth_nm_per_4_ticks >= VELOCITY_SMOOTH_32_BIT_LIMIT =>
                    {
                        LAGUERRE_VELOCITY_SIGN + VELOCITY_64_BIT_DIVISION
                    }
                    TermInput::VelocitySign { .. } => LAGUERRE_VELOCITY_SIGN,
                    TermInput::Dahl { .. } => LAGUERRE_DAHL,
                    TermInput::PositionSine { .. } => LAGUERRE_POSITION_SINE,
                };
                if laguerre_stages_are_narrow(pole_q30, gains_pm) {
                    bank
                } else {
                    bank + LAGUERRE_WIDE_STAGES
                }
            }
        }
    }

    /// Whether the servo tick runs the term as a kernel: anything but a harmonic and the
    /// axis twin, whose correction the servo synthesises as harmonics.
    pub fn is_kernel(&self) -> bool {
        !matches!(self, Self::Harmonic { .. } | Self::Axis(_) | Self::AxisHarmonic { .. })
    }
}

/// Whether a term's register references are valid given the set of stored registers.
fn register_ok(register: u8, written: u16) -> bool {
    (register as usize) < REGISTER_COUNT && written & (1 << register) != 0
}
