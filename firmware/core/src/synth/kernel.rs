//! The kernel terms: the tick terms other than harmonics, each a small filter or state
//! stepped once per servo tick (a drift, the X axis and spindle coupling, a Laguerre bank on
//! the velocity sign, a Dahl state or a position sine, a servo-axis twin), and the state
//! each keeps between ticks.
//!
//! Hand-written, because the tick must give the host's numbers bit for bit (`no_std`) and
//! runs at 8 kHz: integer arithmetic (the axis twin aside, see [`crate::axis`]) in 32-bit
//! pieces where they provably fit (a 64-bit division is a library call of about a hundred
//! instructions on a Cortex-M4), each checked bit for bit against the plain 64-bit form it
//! replaces. A term's f64 set-up runs when it starts ([`KernelState::start`]), not per tick.

use super::resonance::Resonance;
use super::TickInput;
use crate::axis::{AxisModel, AxisState};
use crate::math::{harmonic_pm, isqrt_u64, sin_q31};
use crate::program::{laguerre_stages_are_narrow, TermInput, TickTerm, LAGUERRE_STAGES, VELOCITY_SMOOTH_32_BIT_LIMIT};

/// Ticks between two steps of a [`TickTerm::Drift`]'s exponential (its value is held in between).
pub const DRIFT_STEP_TICKS: u32 = 256;

/// Stage outputs of a Laguerre bank.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stages {
    /// Twice the stage outputs (Q25), for a pole of at most
    /// [`NARROW_POLE_MAX_Q30`](crate::program::NARROW_POLE_MAX_Q30) and gains of at most 2^32
    /// in sum: they provably stay within `i32`, so a stage is two 32x32 -> 64-bit multiplies
    /// (`smull`, `smlal` on a Cortex-M4) whose high word is the step (see
    /// [`laguerre_step_narrow`]).
    Narrow([i32; LAGUERRE_STAGES]),
    /// Stage outputs, Q24: any pole, 64-bit arithmetic throughout.
    Wide([i64; LAGUERRE_STAGES]),
}

impl Stages {
    /// All stages at rest, in the representation that the pole `pole_q30` and the gains
    /// `gains_pm` allow.
    fn at_rest(pole_q30: i32, gains_pm: &[i32; LAGUERRE_STAGES]) -> Self {
        if laguerre_stages_are_narrow(pole_q30, gains_pm) {
            Self::Narrow([0; LAGUERRE_STAGES])
        } else {
            Self::Wide([0; LAGUERRE_STAGES])
        }
    }

    /// The same representation, at rest.
    const fn rested(&self) -> Self {
        match self {
            Self::Narrow(_) => Self::Narrow([0; LAGUERRE_STAGES]),
            Self::Wide(_) => Self::Wide([0; LAGUERRE_STAGES]),
        }
    }
}

/// Kernel state of a term other than a harmonic.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct KernelState {
    /// Laguerre stage outputs, Q24.
    stages: Stages,
    /// Command positions of the last ticks, newest first: as many as the input reads (see
    /// `laguerre_input_q30`).
    pos_hist: [i32; 4],
    /// Dahl state, Q30.
    dahl_q30: i32,
    /// The decaying part of a drift, picometres (Q8).
    drift_q8: i64,
    /// A drift's `exp(-DRIFT_STEP_TICKS / tau)`, Q23 (so the product stays within 64 bits);
    /// or a coupling's X gain in picometres per (um/s^2), Q20, set when the term starts, so
    /// that the tick multiplies the acceleration by it instead of dividing the product by
    /// 10^6 (the 64-bit quotient took some 35 instructions of a tick). One field for both:
    /// a larger slot moves the whole servo handler's register allocation.
    scale: i64,
    /// `sqrt(1 - a^2)` of a Laguerre bank, Q30.
    g_q30: i64,
    /// `2a` and `-2a` of a Laguerre bank, Q30: stored, so that the compiler keeps
    /// `2a y + (-2a) y'` as two 32-bit multiply-accumulates instead of turning it into a
    /// 64-bit `2a (y - y')`.
    two_pole_q30: i32,
    minus_two_pole_q30: i32,
    /// Whether the command history is valid.
    primed: bool,
    /// A servo-axis twin's coefficients (computed when the term starts) and state.
    pub(super) axis: Option<(AxisModel, AxisState)>,
    /// A resonance's coefficients (computed when the term starts) and state.
    resonance: Option<Resonance>,
}

impl KernelState {
    pub(super) const REST: Self = Self {
        stages: Stages::Wide([0; LAGUERRE_STAGES]),
        pos_hist: [0; 4],
        dahl_q30: 0,
        drift_q8: 0,
        scale: 0,
        g_q30: 0,
        two_pole_q30: 0,
        minus_two_pole_q30: 0,
        primed: false,
        axis: None,
        resonance: None,
    };

    /// The state a kernel term starts from at machine time `ticks`. Out of line: its 64-bit
    /// float set-up (software arithmetic on a Cortex-M4F) runs where the update is prepared.
    #[cold]
    #[inline(never)]
    pub(super) fn start(term: &TickTerm, ticks: u64) -> Self {
        let mut state = Self::REST;
        match *term {
            TickTerm::Drift { decay_pm, tau_ticks, .. } => drift_at(&mut state, decay_pm, tau_ticks, ticks),
            TickTerm::Laguerre { pole_q30, ref gains_pm, .. } => {
                let one = 1i64 << 30;
                let a = i64::from(pole_q30);
                state.g_q30 = isqrt_u64(((one - a) * (one + a)) as u64) as i64;
                state.stages = Stages::at_rest(pole_q30, gains_pm);
                state.two_pole_q30 = pole_q30.wrapping_mul(2);
                state.minus_two_pole_q30 = pole_q30.wrapping_mul(-2);
            }
            // The discretisation (f64, software on the target) runs here, once per program.
            // Parameters the validator let through always give a model.
            TickTerm::Axis(ref params) => {
                state.axis = AxisModel::new(params).ok().map(|model| (model, AxisState::INITIAL))
            }
            TickTerm::Resonance { .. } => state.resonance = Resonance::new(term),
            TickTerm::AxisCoupling { x_gain_pm_per_mps2, .. } => state.scale = x_gain_q20(x_gain_pm_per_mps2),
            _ => {}
        }
        state
    }

    /// The state restarted from rest (a new motion), keeping the term's set-up (filter
    /// coefficients, the drift's time, the axis twin's model) and the count of axis twin
    /// resets.
    #[inline]
    pub(super) fn restarted(self) -> Self {
        let axis = self.axis.map(|(model, state)| {
            let mut rest = AxisState::INITIAL;
            rest.resets = state.resets;
            (model, rest)
        });
        let resonance = self.resonance.map(Resonance::rested);
        Self { stages: self.stages.rested(), pos_hist: [0; 4], dahl_q30: 0, primed: false, axis, resonance, ..self }
    }
}

/// `x_gain_pm_per_mps2 / 10^6` in Q20, rounded to nearest (half away from zero): within half a
/// unit of 2^-20 pm per um/s^2, so a tick's X part lies within `|x_acc| 2^-21 + 1` pm of the
/// exact product (5 pm at 10 m/s^2).
fn x_gain_q20(x_gain_pm_per_mps2: i32) -> i64 {
    let scaled = i64::from(x_gain_pm_per_mps2) << 20;
    let half = if scaled < 0 { -500_000 } else { 500_000 };
    (scaled + half) / 1_000_000
}

/// `exp(-x)` for the drift's set-up (not per tick).
fn exp_neg(x: f64) -> f64 {
    libm::exp(-x)
}

/// Sets a drift's decaying part for machine time `ticks`.
pub(super) fn drift_at(state: &mut KernelState, decay_pm: i32, tau_ticks: u32, ticks: u64) {
    let tau = f64::from(tau_ticks.max(DRIFT_STEP_TICKS));
    // Held between steps: the value of the last whole step, less the step that the tick at
    // `ticks` itself takes when it falls on one (`kernel_pm` steps at every multiple but 0).
    let steps = ticks.saturating_sub(1) / u64::from(DRIFT_STEP_TICKS);
    let t = (steps * u64::from(DRIFT_STEP_TICKS)) as f64;
    state.drift_q8 = (f64::from(decay_pm) * exp_neg(t / tau) * 256.0) as i64;
    state.scale = (exp_neg(f64::from(DRIFT_STEP_TICKS) / tau) * 8388608.0) as i64;
}

/// The saturated sign of a velocity, `clamp((dv << 30) / smooth, -2^30, 2^30)` for a
/// smoothing velocity `smooth >= 1`: at the clamp without dividing, below it with two 32-bit
/// divisions of 15 quotient bits each when `smooth < 2^17` (always, for a real machine),
/// with the 64-bit division otherwise.
#[inline]
fn velocity_sign_q30(dv: i64, smooth: i64) -> i64 {
    let magnitude = dv.unsigned_abs();
    let q = if magnitude >= smooth as u64 {
        // |dv| / smooth >= 1: clamped.
        1 << 30
    } else if smooth < VELOCITY_SMOOTH_32_BIT_LIMIT as i64 {
        // magnitude < smooth < 2^17: (magnitude << 15) and (remainder << 15) fit in 32 bits.
        let s = smooth as u32;
        let high = (magnitude as u32) << 15;
        let (q1, r1) = (high / s, high % s);
        i64::from((q1 << 15) + (r1 << 15) / s)
    } else {
        return velocity_sign_wide(dv, smooth);
    };
    if dv < 0 {
        -q
    } else {
        q
    }
}

/// [`velocity_sign_q30`] with the 64-bit division (out of line: never for a real machine).
#[cold]
#[inline(never)]
fn velocity_sign_wide(dv: i64, smooth: i64) -> i64 {
    ((dv << 30) / smooth).clamp(-(1 << 30), 1 << 30)
}

/// The Dahl state after a command move `dx` (nm) from state `u` (Q30, within [-1, 1]) with
/// `1 / x0` = `inv_x0_q30`: `du = dx / x0 * (1 - u sgn(dx))` (the rate clamped to [-2, 2]),
/// kept within [-1, 1], in Q30 as first written ([`dahl_step_wide`]) but in 32-bit pieces:
/// the rate's magnitude and `1 - u sgn(dx)` are both at most 2^31, so their product is one
/// unsigned 32x32 -> 64-bit multiply, and the floor of a negative product is the negated
/// ceiling of its magnitude.
#[inline(always)]
fn dahl_step_q30(dx: i64, u: i32, inv_x0_q30: i32) -> i32 {
    const ONE: u32 = 1 << 30;
    if inv_x0_q30 <= 0 || !(-(ONE as i32)..=ONE as i32).contains(&u) {
        // Not a validated term's: as first written.
        return dahl_step_wide(dx, u, inv_x0_q30);
    }
    if dx == 0 {
        // No move, no change (u is within [-1, 1]).
        return u;
    }
    let magnitude = dx.unsigned_abs();
    // |dx / x0| in Q30, at most 2 (2^31).
    let rate =
        if magnitude >> 31 != 0 { 1 << 31 } else { (magnitude * u64::from(inv_x0_q30 as u32)).min(1 << 31) as u32 };
    let negative = dx < 0;
    // 1 - u sgn(dx), in [0, 2].
    let room = if negative { ONE.wrapping_add(u as u32) } else { ONE.wrapping_sub(u as u32) };
    let product = u64::from(rate) * u64::from(room);
    let next = if negative {
        // floor(-p / 2^30) = -ceil(p / 2^30); the sum only falls.
        (u as i64 - ((product + u64::from(ONE - 1)) >> 30) as i64).max(-(ONE as i64))
    } else {
        (u as i64 + (product >> 30) as i64).min(ONE as i64)
    };
    next as i32
}

/// [`dahl_step_q30`] as first written, in 64 bits.
fn dahl_step_wide(dx: i64, u: i32, inv_x0_q30: i32) -> i32 {
    let u = u as i64;
    let sign = dx.signum();
    let du = ((dx * inv_x0_q30 as i64).clamp(-(1 << 31), 1 << 31) * ((1 << 30) - sign * u)) >> 30;
    (u + du).clamp(-(1 << 30), 1 << 30) as i32
}

/// One tick of a kernel term: its contribution in picometres.
#[inline(always)]
pub(super) fn kernel_pm(term: &TickTerm, st: &mut KernelState, input: &TickInput, ticks: u64) -> i64 {
    match term {
        TickTerm::Harmonic { .. } | TickTerm::AxisHarmonic { .. } => 0,
        TickTerm::Drift { offset_pm, .. } => {
            if ticks.is_multiple_of(u64::from(DRIFT_STEP_TICKS)) && ticks != 0 {
                st.drift_q8 = (st.drift_q8 * st.scale) >> 23;
            }
            *offset_pm as i64 + (st.drift_q8 >> 8)
        }
        TickTerm::AxisCoupling { spindle_amp_pm, spindle_phase_turns, .. } => {
            // At most 2^32 x 2^31 in magnitude: within 64 bits.
            let x = (st.scale * i64::from(input.x_acc_um_per_s2)) >> 20;
            x + harmonic_pm(*spindle_amp_pm, input.spindle_turns.wrapping_add(*spindle_phase_turns)) as i64
        }
        TickTerm::Laguerre { input: kind, pole_q30, gains_pm } => laguerre_pm(kind, *pole_q30, gains_pm, st, input),
        TickTerm::Axis(_) => match &mut st.axis {
            Some((model, axis)) => i64::from(model.step(axis, input.cmd_pos_nm)),
            None => 0,
        },
        TickTerm::Resonance { .. } => match &mut st.resonance {
            Some(resonance) => resonance.step(input.cmd_pos_nm),
            None => 0,
        },
    }
}

/// One tick of a [`TickTerm::Laguerre`] bank (the coefficients by reference: copied, they
/// went through the stack every tick).
#[inline(always)]
pub(super) fn laguerre_pm(
    kind: &TermInput,
    pole_q30: i32,
    gains_pm: &[i32; LAGUERRE_STAGES],
    st: &mut KernelState,
    input: &TickInput,
) -> i64 {
    let u_q30 = laguerre_input_q30(kind, st, input);
    let (g_q30, two_a_q30, minus_two_a_q30) = (st.g_q30, st.two_pole_q30, st.minus_two_pole_q30);
    match &mut st.stages {
        Stages::Narrow(stages) => {
            laguerre_step_narrow(stages, two_a_q30, minus_two_a_q30, g_q30 as i32, u_q30 as i32, gains_pm)
        }
        Stages::Wide(stages) => laguerre_step(stages, pole_q30 as i64, g_q30, u_q30, gains_pm),
    }
}

/// The signal driving a Laguerre bank this tick, Q30 (at most 1 in magnitude: the narrow
/// stages rely on it).
///
/// Each input keeps the command history it reads (`pos_hist`, newest first, filled with the
/// first position it sees): the velocity the last four positions, the Dahl state the last
/// one, the position sine none.
#[inline(always)]
fn laguerre_input_q30(kind: &TermInput, st: &mut KernelState, input: &TickInput) -> i64 {
    let pos = input.cmd_pos_nm;
    let u_q30 = match *kind {
        TermInput::VelocitySign { smooth_nm_per_4_ticks } => {
            if !st.primed {
                st.pos_hist = [pos; 4];
                st.primed = true;
            }
            let dv = pos as i64 - st.pos_hist[3] as i64;
            st.pos_hist = [pos, st.pos_hist[0], st.pos_hist[1], st.pos_hist[2]];
            velocity_sign_q30(dv, smooth_nm_per_4_ticks.max(1) as i64)
        }
        TermInput::Dahl { inv_x0_q30 } => {
            let last = if st.primed { st.pos_hist[0] } else { pos };
            st.pos_hist[0] = pos;
            st.primed = true;
            let next = dahl_step_q30(pos as i64 - last as i64, st.dahl_q30, inv_x0_q30);
            st.dahl_q30 = next;
            next as i64
        }
        TermInput::PositionSine { turns_per_nm, phase_turns } => {
            let phase = (input.cmd_pos_nm as u32).wrapping_mul(turns_per_nm).wrapping_add(phase_turns);
            (sin_q31(phase) as i64) >> 1
        }
    };
    debug_assert!(u_q30.abs() <= 1 << 30);
    u_q30
}

/// Advances a Laguerre bank by one tick on input `u` (Q30); returns the weighted output, pm.
/// Stage 0: `y0 = a y0' + sqrt(1 - a^2) u`; stage i: `yi = a yi' + y(i-1)' - a y(i-1)`.
#[inline(never)]
fn laguerre_step(
    stages: &mut [i64; LAGUERRE_STAGES],
    a_q30: i64,
    g_q30: i64,
    u_q30: i64,
    gains_pm: &[i32; LAGUERRE_STAGES],
) -> i64 {
    let mut prev_old = stages[0];
    let mut prev_new = (a_q30 * stages[0] + ((g_q30 * u_q30) >> 6)) >> 30;
    stages[0] = prev_new;
    let mut out = gains_pm[0] as i64 * prev_new;
    for i in 1..LAGUERRE_STAGES {
        let old = stages[i];
        let new = ((a_q30 * old - a_q30 * prev_new) >> 30) + prev_old;
        stages[i] = new;
        out += gains_pm[i] as i64 * new;
        prev_old = old;
        prev_new = new;
    }
    out >> 24
}

/// [`laguerre_step`] on doubled stages (`stages2[i] = 2 y_i`, see [`Stages::Narrow`]) with
/// `two_a = 2a` and `minus_two_a = -2a`: the same output, bit for bit. `2a * 2y - 2a * 2y'` is
/// `4 (a y - a y')` exactly (below 2^63), so its high word is `(a y - a y') >> 30`, and twice
/// the new stage is that doubled plus `2 y(i-1)'`; the weighted sum of the doubled stages is
/// twice the weighted sum, so shifting it by 25 gives the same as shifting the sum by 24.
#[inline(always)]
fn laguerre_step_narrow(
    stages2: &mut [i32; LAGUERRE_STAGES],
    two_a_q30: i32,
    minus_two_a_q30: i32,
    g_q30: i32,
    u_q30: i32,
    gains_pm: &[i32; LAGUERRE_STAGES],
) -> i64 {
    debug_assert_eq!(minus_two_a_q30, two_a_q30.wrapping_neg());
    let two_a = two_a_q30 as i64;
    let minus_two_a = minus_two_a_q30 as i64;
    // Stage 0: 4 (a y0 + floor(g u / 64)), whose high word is the new stage.
    let input4 = ((g_q30 as i64 * u_q30 as i64) >> 6) << 2;
    let mut prev_old2 = stages2[0];
    let mut prev_new2 = (((input4 + two_a * prev_old2 as i64) >> 32) as i32) << 1;
    stages2[0] = prev_new2;
    // The stages first, then their weighted sum: fewer values live at once (a Cortex-M4 has
    // 13 registers; fused, the weights and stage values were spilled to the stack).
    for stage2 in stages2[1..].iter_mut() {
        let old2 = *stage2;
        let step = ((two_a * old2 as i64 + minus_two_a * prev_new2 as i64) >> 32) as i32;
        let new2 = (step << 1).wrapping_add(prev_old2);
        *stage2 = new2;
        prev_old2 = old2;
        prev_new2 = new2;
    }
    let mut out2 = 0i64;
    for (&stage2, &gain) in stages2.iter().zip(gains_pm) {
        out2 += gain as i64 * stage2 as i64;
    }
    out2 >> 25
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::program::ModelOutput;
    use crate::program::NARROW_POLE_MAX_Q30;
    use crate::synth::tests::rng;
    use crate::synth::Synth;

    #[test]
    fn the_velocity_sign_without_64_bit_division_is_exact() {
        let mut seed = 3u64;
        let wide = |dv: i64, smooth: i64| ((dv << 30) / smooth).clamp(-(1 << 30), 1 << 30);
        for k in 0..300_000u64 {
            let r = rng(&mut seed);
            let smooth = match k % 4 {
                0 => 1 + (r % 300) as i64,
                1 => 1 + (r % (1 << 17)) as i64,
                2 => ((1 << 17) - 1 - (r % 3)) as i64,
                _ => 1 + (r >> 33) as i64,
            };
            let dv = match (r >> 8) % 4 {
                0 => (rng(&mut seed) % (2 * smooth as u64 + 1)) as i64 - smooth,
                1 => smooth * if r & 1 == 0 { 1 } else { -1 },
                2 => (rng(&mut seed) as i32 as i64) - (rng(&mut seed) as i32 as i64),
                _ => (smooth - 1) * if r & 1 == 0 { 1 } else { -1 },
            };
            assert_eq!(velocity_sign_q30(dv, smooth), wide(dv, smooth), "dv {dv} smooth {smooth}");
        }
    }

    #[test]
    fn the_dahl_step_is_the_64_bit_one_bit_for_bit() {
        let mut seed = 17u64;
        let one = 1i32 << 30;
        for k in 0..1_000_000u64 {
            let r = rng(&mut seed);
            let dx = match k % 5 {
                0 => (rng(&mut seed) % 2001) as i64 - 1000,
                1 => (rng(&mut seed) as i32 as i64) - (rng(&mut seed) as i32 as i64),
                2 => [0, 1, -1, 1 << 31, -(1 << 31), (1 << 32) - 1, 1 - (1 << 32)][(r % 7) as usize],
                _ => (rng(&mut seed) % 200_001) as i64 - 100_000,
            };
            let u = match (r >> 8) % 4 {
                0 => [one, -one, 0, one - 1, 1 - one][(r >> 16) as usize % 5],
                _ => (rng(&mut seed) % (2 * one as u64 + 1)) as i64 as i32 - one,
            };
            let inv = match (r >> 24) % 4 {
                0 => [1, i32::MAX, 1 << 30, 1 << 20][(r >> 32) as usize % 4],
                1 => 1 + (rng(&mut seed) % (1 << 31)) as i32,
                _ => 1 + (rng(&mut seed) % (1 << 22)) as i32,
            };
            assert_eq!(dahl_step_q30(dx, u, inv), dahl_step_wide(dx, u, inv), "dx {dx} u {u} inv {inv}");
        }
        // Not a validated term's: as first written.
        assert_eq!(dahl_step_q30(5, 3, -4), dahl_step_wide(5, 3, -4));
    }

    /// l1 norms of the impulse responses from a stage-0 input to each stage of a Laguerre
    /// bank with pole `a` (without the `sqrt(1 - a^2)` input gain), summed until the tail is
    /// negligible (a geometric bound on it is added).
    fn laguerre_l1_norms(a: f64) -> [f64; LAGUERRE_STAGES] {
        let mut x = [0.0f64; LAGUERRE_STAGES];
        let mut norms = [0.0f64; LAGUERRE_STAGES];
        for k in 0..2_000_000 {
            let old = x;
            x[0] = a * old[0] + if k == 0 { 1.0 } else { 0.0 };
            for i in 1..LAGUERRE_STAGES {
                x[i] = a * old[i] + old[i - 1] - a * x[i - 1];
            }
            for i in 0..LAGUERRE_STAGES {
                norms[i] += x[i].abs();
            }
            if k > 10_000 && x.iter().all(|v| v.abs() < 1e-12) {
                break;
            }
        }
        // What is left decays at least as fast as a^k times a polynomial; 1e-12 per stage
        // over 1/(1 - a)^8 more ticks stays far below 1.
        norms.map(|n| n + 1e-12 / (1.0 - a).powi(8) * 1e-6 + 1.0)
    }

    #[test]
    fn narrow_stages_are_bounded_well_inside_i32() {
        let a = f64::from(NARROW_POLE_MAX_Q30) / (1u64 << 30) as f64;
        let gamma = (1.0 - a * a).sqrt();
        let norms = laguerre_l1_norms(a);
        for i in 0..LAGUERRE_STAGES {
            // Input |u| <= 1 enters stage 0 as at most 2^24 gamma (+1 for its floor); each
            // stage's shift adds at most one unit, through the filters after it.
            let bound = norms[i] * ((1u64 << 24) as f64 * gamma + 1.0) + norms[..i].iter().sum::<f64>();
            assert!(bound < 0.45 * 2f64.powi(31), "stage {i}: {bound:e}");
        }
    }

    #[test]
    fn narrow_and_wide_laguerre_banks_agree_bit_for_bit() {
        let mut seed = 9u64;
        let full = [i32::MAX, i32::MIN + 1, 1_000_000, -7, 123_456, -98_765, 3, i32::MAX / 2];
        // Gains of 2^32 in sum, the most the narrow stages take.
        let at_limit = [1 << 30, -(1 << 30), 1 << 29, -(1 << 29), 1 << 29, 0, -(1 << 28), 1 << 28];
        let typical = [180_000, -95_000, 61_000, -40_000, 22_000, -15_000, 9_000, -4_000];
        for (pole_q30, gains) in [
            (NARROW_POLE_MAX_Q30, at_limit),
            (NARROW_POLE_MAX_Q30 - 1, typical),
            (998_579_896, at_limit),
            (536_870_912, typical),
            (1, at_limit),
            (998_579_896, full),
        ] {
            let narrow_ok = matches!(Stages::at_rest(pole_q30, &gains), Stages::Narrow(_));
            assert_eq!(narrow_ok, gains != full, "pole {pole_q30}");
            let one = 1i64 << 30;
            let a = i64::from(pole_q30);
            let g_q30 = isqrt_u64(((one - a) * (one + a)) as u64) as i64;
            let mut narrow2 = [0i32; LAGUERRE_STAGES];
            let mut wide = [0i64; LAGUERRE_STAGES];
            let mut largest = 0i64;
            // Bang-bang inputs held for stretches of the bank's own time scale (the worst
            // case for the stages' peaks), then noise at full scale.
            let mut u = 1i64 << 30;
            for k in 0..400_000u32 {
                if k < 200_000 {
                    if rng(&mut seed).is_multiple_of((1 + 2 * one as u64 / (one - a).max(1) as u64 / 4).max(1)) {
                        u = -u;
                    }
                } else {
                    u = (rng(&mut seed) % (2 * one as u64 + 1)) as i64 - one;
                }
                let w = laguerre_step(&mut wide, a, g_q30, u, &gains);
                for y in &wide {
                    largest = largest.max(y.abs());
                }
                if !narrow_ok {
                    continue;
                }
                let n = laguerre_step_narrow(&mut narrow2, pole_q30 * 2, pole_q30 * -2, g_q30 as i32, u as i32, &gains);
                assert_eq!(n, w, "pole {pole_q30} tick {k}");
                for (x, y) in narrow2.iter().zip(&wide) {
                    assert_eq!(i64::from(*x), 2 * *y);
                }
            }
            assert!(largest < 1 << 30, "pole {pole_q30}: {largest}");
        }
    }

    #[test]
    fn drift_follows_its_exponential_over_machine_time() {
        let mut synth = Synth::new(0);
        let term = TickTerm::Drift { offset_pm: 800_000, decay_pm: -800_000, tau_ticks: 8000 * 900 };
        synth.set_time_ticks(8000 * 300);
        synth.update(&ModelOutput::default(), &[term]);
        let want = |t_s: f64| 0.8e6 * (1.0 - libm::exp(-t_s / 900.0));
        let first = synth.next_input(&TickInput::default()) as f64;
        assert!((first - want(300.0)).abs() < 50.0, "{first} vs {}", want(300.0));
        for _ in 0..8000 * 10 {
            synth.next_input(&TickInput::default());
        }
        let later = synth.next_input(&TickInput::default()) as f64;
        assert!((later - want(310.0)).abs() < 100.0, "{later} vs {}", want(310.0));
    }

    #[test]
    fn a_drift_started_on_a_step_is_not_a_step_ahead() {
        // A short time constant, where one step is 23% of the decaying part.
        let tau_ticks = 1000;
        for start in [0u64, 1, 255, 256, 257, 512, 1000, 1024] {
            let mut synth = Synth::new(0);
            synth.set_time_ticks(start);
            synth.update(&ModelOutput::default(), &[TickTerm::Drift { offset_pm: 0, decay_pm: 1_000_000, tau_ticks }]);
            let steps = start / u64::from(DRIFT_STEP_TICKS);
            let want = 1e6 * libm::exp(-((steps * u64::from(DRIFT_STEP_TICKS)) as f64) / f64::from(tau_ticks));
            let got = synth.next_input(&TickInput::default()) as f64;
            assert!((got - want).abs() < 2.0, "start {start}: {got} pm, want {want}");
        }
    }

    #[test]
    fn axis_coupling_scales_the_x_acceleration_and_adds_the_spindle_sine() {
        let mut synth = Synth::new(0);
        let term =
            TickTerm::AxisCoupling { x_gain_pm_per_mps2: 800_000, spindle_amp_pm: 50_000, spindle_phase_turns: 0 };
        synth.update(&ModelOutput::default(), &[term]);
        // 0.25 m/s^2 -> 0.2 um; spindle at a quarter turn -> +50 nm.
        let out =
            synth.next_input(&TickInput { x_acc_um_per_s2: 250_000, spindle_turns: 1 << 30, ..TickInput::default() });
        assert!((out - 250_000).abs() < 20, "{out}");
    }

    #[test]
    fn the_couplings_x_part_is_the_exact_product_within_its_bound() {
        let mut seed = 11u64;
        let mut next = || {
            seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            (seed >> 32) as u32 as i32
        };
        let edges = [0, 1, -1, 999_999, -1_000_000, 800_000, i32::MAX, i32::MIN];
        for k in 0..20_000 {
            let gain = if k < edges.len() { edges[k] } else { next() };
            let acc = if k % 3 == 0 { next() } else { next() >> 8 };
            let mut synth = Synth::new(0);
            let term = TickTerm::AxisCoupling { x_gain_pm_per_mps2: gain, spindle_amp_pm: 0, spindle_phase_turns: 0 };
            synth.update(&ModelOutput::default(), &[term]);
            let out = synth.next_input(&TickInput { x_acc_um_per_s2: acc, ..TickInput::default() });
            let exact = i64::from(gain) as f64 * f64::from(acc) / 1e6;
            let expected = exact.clamp(f64::from(i32::MIN), f64::from(i32::MAX));
            let bound = f64::from(acc).abs() / f64::from(1u32 << 21) + 1.0;
            assert!((f64::from(out) - expected).abs() <= bound, "{gain} x {acc}: {out} vs {exact}");
        }
    }

    #[test]
    fn laguerre_term_is_linear_and_starts_from_rest() {
        let run = |gain: i32| {
            let mut synth = Synth::new(0);
            let mut gains = [0i32; LAGUERRE_STAGES];
            gains[0] = gain;
            gains[3] = -gain / 2;
            let term = TickTerm::Laguerre {
                input: TermInput::VelocitySign { smooth_nm_per_4_ticks: 8 },
                pole_q30: (0.93 * (1u64 << 30) as f64) as i32,
                gains_pm: gains,
            };
            synth.update(&ModelOutput::default(), &[term]);
            (0..4000)
                .map(|k| {
                    let pos = (5000.0 * libm::sin(2.0 * core::f64::consts::PI * 10.0 * k as f64 / 8000.0)) as i32;
                    synth.next_input(&TickInput { cmd_pos_nm: pos, ..TickInput::default() }) as i64
                })
                .collect::<std::vec::Vec<i64>>()
        };
        let one = run(100_000);
        let two = run(200_000);
        assert_eq!(one[0], 0, "a bank at rest with the command at rest outputs nothing");
        assert!(one.iter().map(|v| v.abs()).max().unwrap() > 50_000);
        for (a, b) in one.iter().zip(&two) {
            assert!((2 * a - b).abs() <= 2, "{a} {b}");
        }
    }
}
