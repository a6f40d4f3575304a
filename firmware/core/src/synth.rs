//! Per-tick synthesis of the predicted dynamic error (the paper's Eq. 4):
//! `DE(t) = A * sin(theta(t) + dphi) + sum of tick terms`, where `theta` is the command phase
//! handed over by the motion controller every tick.
//!
//! Everything here is integer arithmetic: amplitudes in picometres (`i32`), phases in turns
//! where a full turn is 2^32 (`u32`, so phase arithmetic wraps exactly). The sine comes from
//! a 1024-entry table with linear interpolation (worst error 4.8e-6 of full scale, i.e.
//! 48 pm at a 10 um amplitude). A model update never makes the output jump: amplitude and
//! phase offset move to their new values linearly over [`Synth::ramp_ticks`] ticks, the
//! phase along the shorter way round, so the synthesised waveform stays continuous.
//!
//! A change of terms (a program switch) does not step it either: a harmonic that goes ramps
//! out over the same ramp, counted from the switch whatever model updates come meanwhile,
//! lands on zero exactly and is dropped; the terms that take its slot, and new kernel terms
//! (which have no ramp), start with the first update after, so the tick never runs the old
//! harmonics beside new kernel terms (see `Harmonics::retarget_terms`).

use crate::axis::{AxisModel, AxisState};
use crate::program::{ModelOutput, TermInput, TickTerm, LAGUERRE_STAGES, MAX_TERMS};

/// What the servo tick hands the synthesiser: the command and the other axes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TickInput {
    /// Command phase of the motion controller, a full turn is 2^32.
    pub cmd_phase_turns: u32,
    /// Command position of the Z axis, nanometres.
    pub cmd_pos_nm: i32,
    /// X-axis acceleration, micrometres per s^2 (0 where the bus does not carry it).
    pub x_acc_um_per_s2: i32,
    /// Spindle angle, a full turn is 2^32 (0 where the bus does not carry it).
    pub spindle_turns: u32,
}

// The term slots are walked by the bits of a byte (`Synth::apply`).
const _: () = assert!(MAX_TERMS == 8, "Synth::apply indexes term slots with 3 bits");

/// Ticks between two steps of a [`TickTerm::Drift`]'s exponential (its value is held in between).
pub const DRIFT_STEP_TICKS: u32 = 256;

/// Table size (entries per turn).
const SINE_TABLE_BITS: u32 = 10;
const SINE_TABLE_LEN: usize = 1 << SINE_TABLE_BITS;

/// sin(2 pi i / 1024) in Q31, one extra entry so interpolation needs no wrap.
#[cfg(test)]
const SINE_Q31: [i32; SINE_TABLE_LEN + 1] = sine_table();

/// Each table entry with twice the step to the next: `[sin_i, 2 (sin_(i+1) - sin_i)]`, so that
/// the interpolation is one load pair and one high-word multiply (`smmla` on a Cortex-M4).
/// The doubled step (at most 2^24.7) and the fraction in Q31 keep the product exact.
static SINE_SLOPE_Q31: [[i32; 2]; SINE_TABLE_LEN] = sine_slope_table();

/// Builds the table at compile time (f64 in const fn is exact IEEE arithmetic).
const fn sine_table() -> [i32; SINE_TABLE_LEN + 1] {
    let mut table = [0i32; SINE_TABLE_LEN + 1];
    let mut i = 0;
    while i <= SINE_TABLE_LEN {
        // Reduce to [-pi, pi] for the Taylor series.
        let mut x = 2.0 * core::f64::consts::PI * (i as f64) / (SINE_TABLE_LEN as f64);
        if x > core::f64::consts::PI {
            x -= 2.0 * core::f64::consts::PI;
        }
        let mut term = x;
        let mut sum = x;
        let mut n = 1;
        while n < 30 {
            term = -term * x * x / (((2 * n) * (2 * n + 1)) as f64);
            sum += term;
            n += 1;
        }
        let scaled = sum * 2147483647.0;
        table[i] = if scaled >= 0.0 { (scaled + 0.5) as i32 } else { (scaled - 0.5) as i32 };
        i += 1;
    }
    table
}

const fn sine_slope_table() -> [[i32; 2]; SINE_TABLE_LEN] {
    let sine = sine_table();
    let mut table = [[0i32; 2]; SINE_TABLE_LEN];
    let mut i = 0;
    while i < SINE_TABLE_LEN {
        table[i] = [sine[i], 2 * (sine[i + 1] - sine[i])];
        i += 1;
    }
    table
}

/// `(a * b) >> 32`: one `smmul` on a Cortex-M4.
#[inline(always)]
fn mul_hi(a: i32, b: i32) -> i32 {
    ((a as i64 * b as i64) >> 32) as i32
}

/// sin of a phase in turns (2^32 = one turn), in Q31: the table entry of the top 10 bits,
/// linearly interpolated by the next 16, `a + ((b - a) * frac16) >> 16` (floor).
#[inline]
pub fn sin_q31(phase_turns: u32) -> i32 {
    let [a, slope2] = SINE_SLOPE_Q31[(phase_turns >> (32 - SINE_TABLE_BITS)) as usize];
    // The 16 interpolation bits in Q31: frac16 << 15.
    let frac_q31 = ((phase_turns << SINE_TABLE_BITS) >> 1) & 0x7fff_8000;
    // (2 (b - a) * frac16 2^15) >> 32 = ((b - a) * frac16) >> 16, exactly.
    a + mul_hi(slope2, frac_q31 as i32)
}

/// Micrometres (f32) to picometres, saturating at +-1 mm (NaN gives 0).
pub fn um_to_pm(value_um: f32) -> i32 {
    const LIMIT_UM: f32 = 1000.0;
    // `clamp` keeps NaN, and `as` maps NaN to 0.
    (value_um.clamp(-LIMIT_UM, LIMIT_UM) * 1.0e6) as i32
}

/// Degrees (f32) to turns (2^32 per turn), wrapping; NaN gives 0.
///
/// The fraction of a turn is `turns - trunc(turns)` (truncation toward zero), times 2^32,
/// truncated and wrapped. For `|turns| < 2^31`, the usual case, the truncations go through
/// `i32` (single instructions on a Cortex-M4F; `i64` conversions are library calls of ~50
/// instructions each) with the same results as through `i64`.
pub fn deg_to_turns(value_deg: f32) -> u32 {
    const TWO_POW_31: f32 = 2_147_483_648.0;
    if !value_deg.is_finite() {
        return 0;
    }
    let turns = value_deg / 360.0;
    if !(-TWO_POW_31 < turns && turns < TWO_POW_31) {
        return deg_to_turns_wide(turns);
    }
    // Exact: an integer below 2^24 in magnitude, or `turns` itself (already integral).
    let whole = turns as i32 as f32;
    let scaled = (turns - whole) * 4_294_967_296.0; // in (-2^32, 2^32), exact
    if -TWO_POW_31 < scaled && scaled < TWO_POW_31 {
        scaled as i32 as u32
    } else {
        // |scaled| >= 2^31 is a multiple of 2^8: halve exactly, convert, double (wrapping).
        ((scaled * 0.5) as i32 as u32) << 1
    }
}

/// [`deg_to_turns`] for `|turns| >= 2^31` (64-bit truncations, as defined).
#[cold]
fn deg_to_turns_wide(turns: f32) -> u32 {
    let whole = turns as i64 as f32;
    let frac = turns - whole;
    (frac * 4_294_967_296.0) as i64 as u32
}

/// `amp_pm * sin(phase)`, in picometres (any amplitude).
#[inline]
fn harmonic_pm(amp_pm: i32, phase_turns: u32) -> i32 {
    ((amp_pm as i64 * sin_q31(phase_turns) as i64) >> 31) as i32
}

/// Largest amplitude a [`Ramp`] holds, picometres: [`um_to_pm`] saturates at 1 mm.
const RAMP_AMP_LIMIT_PM: i32 = 1_000_000_000;

/// [`harmonic_pm`] for `|amp_pm| < 2^30` (every [`Ramp`]): `(2 amp * sin) >> 32`, the same
/// value with one high-word multiply.
#[inline(always)]
fn ramp_harmonic_pm(amp_pm: i32, phase_turns: u32) -> i32 {
    debug_assert!(amp_pm.unsigned_abs() <= RAMP_AMP_LIMIT_PM as u32);
    mul_hi(amp_pm << 1, sin_q31(phase_turns))
}

/// A value moving linearly to a target over a number of ticks. The per-tick steps are
/// computed once, at the retarget, with 32-bit division (a single instruction on a
/// Cortex-M4; 64-bit division is a library call of a hundred), so a tick only adds. All
/// ramps of a synthesiser are retargeted together, so one tick counter
/// ([`Synth`]`::ramp_left`) serves them all and a settled tick skips them.
///
/// Amplitudes stay within +-[`RAMP_AMP_LIMIT_PM`]: targets come from [`um_to_pm`] and the
/// steps never overshoot (`|k step| < |target - start|` for `k` below the ramp length).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Ramp {
    amp_pm: i32,
    phase_turns: u32,
    amp_target_pm: i32,
    phase_target_turns: u32,
    amp_step_pm: i32,
    phase_step_turns: i32,
}

impl Ramp {
    const IDLE: Self = Self {
        amp_pm: 0,
        phase_turns: 0,
        amp_target_pm: 0,
        phase_target_turns: 0,
        amp_step_pm: 0,
        phase_step_turns: 0,
    };

    /// Sets the target, reached after `ramp_ticks` steps (at once for 0).
    fn retarget(&mut self, amp_pm: i32, phase_turns: u32, ramp_ticks: u32) {
        self.amp_target_pm = amp_pm;
        self.phase_target_turns = phase_turns;
        if ramp_ticks == 0 {
            self.amp_pm = amp_pm;
            self.phase_turns = phase_turns;
            return;
        }
        let n = ramp_ticks.min(i32::MAX as u32) as i32;
        // |amp| <= 1e9 pm, so the difference fits in i32; clamp anyway.
        let amp_delta = (amp_pm as i64 - self.amp_pm as i64).clamp(i32::MIN as i64, i32::MAX as i64) as i32;
        self.amp_step_pm = amp_delta / n;
        // Shorter way round: the wrapped difference read as signed.
        self.phase_step_turns = (phase_turns.wrapping_sub(self.phase_turns) as i32) / n;
    }

    /// One step of a ramp with more than one tick left.
    #[inline]
    fn step(&mut self) {
        self.amp_pm = self.amp_pm.saturating_add(self.amp_step_pm);
        self.phase_turns = self.phase_turns.wrapping_add(self.phase_step_turns as u32);
    }

    /// `ticks` calls of [`Ramp::step`]: with a constant step the sums are monotonic, so one
    /// saturation at the end is the same as saturating at every step.
    fn step_n(&mut self, ticks: u32) {
        let amp = self.amp_pm as i64 + self.amp_step_pm as i64 * ticks as i64;
        self.amp_pm = amp.clamp(i32::MIN as i64, i32::MAX as i64) as i32;
        self.phase_turns = self.phase_turns.wrapping_add((self.phase_step_turns as u32).wrapping_mul(ticks));
    }

    /// The last step: exactly onto the target.
    #[inline]
    fn finish(&mut self) {
        self.amp_pm = self.amp_target_pm;
        self.phase_turns = self.phase_target_turns;
    }
}

/// Stage outputs of a Laguerre bank.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stages {
    /// Twice the stage outputs (Q25), for a pole of at most [`NARROW_POLE_MAX_Q30`] and
    /// gains of at most 2^32 in sum: they provably stay within `i32`, so a stage is two
    /// 32x32 -> 64-bit multiplies (`smull`, `smlal` on a Cortex-M4) whose high word is the
    /// step (see [`laguerre_step_narrow`]).
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

/// Largest pole (Q30, 0.995) whose Laguerre stages are computed in 32 bits.
///
/// Why they fit: with `|u| <= 1` every stage is bounded by the l1 norm of its impulse
/// response from the input, times `2^24 sqrt(1 - a^2)`, plus the rounding of the shifts
/// (at most one unit per shift, through the same filters). At `a = 0.995` that is below
/// `0.45 * 2^31` for every stage (`narrow_stages_are_bounded_well_inside_i32` computes it),
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

/// Kernel state of a term other than a harmonic.
#[derive(Clone, Copy, Debug, PartialEq)]
struct KernelState {
    /// Laguerre stage outputs, Q24.
    stages: Stages,
    /// Command positions of the last ticks, newest first: as many as the input reads (see
    /// `laguerre_input_q30`).
    pos_hist: [i32; 4],
    /// Dahl state, Q30.
    dahl_q30: i32,
    /// The decaying part of a drift, picometres (Q8).
    drift_q8: i64,
    /// `exp(-DRIFT_STEP_TICKS / tau)`, Q23 (so the product stays within 64 bits).
    drift_step_q23: i64,
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
    axis: Option<(AxisModel, AxisState)>,
}

impl KernelState {
    const REST: Self = Self {
        stages: Stages::Wide([0; LAGUERRE_STAGES]),
        pos_hist: [0; 4],
        dahl_q30: 0,
        drift_q8: 0,
        drift_step_q23: 0,
        g_q30: 0,
        two_pole_q30: 0,
        minus_two_pole_q30: 0,
        primed: false,
        axis: None,
    };

    /// The state a kernel term starts from at machine time `ticks`. Out of line: its 64-bit
    /// float set-up (software arithmetic on a Cortex-M4F) runs where the update is prepared.
    #[cold]
    #[inline(never)]
    fn start(term: &TickTerm, ticks: u64) -> Self {
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
            _ => {}
        }
        state
    }
}

/// `exp(-x)` for the drift's set-up (not per tick).
fn exp_neg(x: f64) -> f64 {
    libm::exp(-x)
}

/// Sets a drift's decaying part for machine time `ticks`.
fn drift_at(state: &mut KernelState, decay_pm: i32, tau_ticks: u32, ticks: u64) {
    let tau = f64::from(tau_ticks.max(DRIFT_STEP_TICKS));
    // Held between steps: the value of the last whole step.
    let steps = ticks / u64::from(DRIFT_STEP_TICKS);
    let t = (steps * u64::from(DRIFT_STEP_TICKS)) as f64;
    state.drift_q8 = (f64::from(decay_pm) * exp_neg(t / tau) * 256.0) as i64;
    state.drift_step_q23 = (exp_neg(f64::from(DRIFT_STEP_TICKS) / tau) * 8388608.0) as i64;
}

/// `p / 1_000_000` truncated toward zero, for `|p| <= 2^62`, with 32-bit divisions (a 64-bit
/// division is a library call of about a hundred instructions on a Cortex-M4): `p / 10^6 =
/// (|p| / 64) / 15625`, the 56-bit quotient dividend taken in chunks of 20, 18 and 18 bits.
#[inline]
fn div_1e6(p: i64) -> i64 {
    const D: u32 = 15_625;
    let n = p.unsigned_abs() >> 6;
    let (n2, n1, n0) = ((n >> 36) as u32, ((n >> 18) & 0x3_ffff) as u32, (n & 0x3_ffff) as u32);
    let (q2, r2) = (n2 / D, n2 % D);
    let m1 = (r2 << 18) | n1;
    let (q1, r1) = (m1 / D, m1 % D);
    let q0 = ((r1 << 18) | n0) / D;
    let q = ((u64::from(q2) << 36) | (u64::from(q1) << 18) | u64::from(q0)) as i64;
    if p < 0 {
        -q
    } else {
        q
    }
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
fn kernel_pm(term: &TickTerm, st: &mut KernelState, input: &TickInput, ticks: u64) -> i64 {
    match term {
        TickTerm::Harmonic { .. } => 0,
        TickTerm::Drift { offset_pm, .. } => {
            if ticks % u64::from(DRIFT_STEP_TICKS) == 0 && ticks != 0 {
                st.drift_q8 = (st.drift_q8 * st.drift_step_q23) >> 23;
            }
            *offset_pm as i64 + (st.drift_q8 >> 8)
        }
        TickTerm::AxisCoupling { x_gain_pm_per_mps2, spindle_amp_pm, spindle_phase_turns } => {
            let x = div_1e6(*x_gain_pm_per_mps2 as i64 * input.x_acc_um_per_s2 as i64);
            x + harmonic_pm(*spindle_amp_pm, input.spindle_turns.wrapping_add(*spindle_phase_turns)) as i64
        }
        TickTerm::Laguerre { input: kind, pole_q30, gains_pm } => laguerre_pm(kind, *pole_q30, gains_pm, st, input),
        TickTerm::Axis(_) => match &mut st.axis {
            Some((model, axis)) => i64::from(model.step(axis, input.cmd_pos_nm)),
            None => 0,
        },
    }
}

/// One tick of a [`TickTerm::Laguerre`] bank (the coefficients by reference: copied, they
/// went through the stack every tick).
#[inline(always)]
fn laguerre_pm(
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
#[inline(always)]
///
/// Each input keeps the command history it reads (`pos_hist`, newest first, filled with the
/// first position it sees): the velocity the last four positions, the Dahl state the last
/// one, the position sine none.
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

/// Integer square root (floor).
fn isqrt_u64(v: u64) -> u64 {
    if v < 2 {
        return v;
    }
    let mut x = (libm::sqrt(v as f64)) as u64;
    while x * x > v {
        x -= 1;
    }
    while (x + 1) * (x + 1) <= v {
        x += 1;
    }
    x
}

/// A model output converted for the synthesiser: the fundamental's and each harmonic
/// term's amplitude (picometres) and phase offset (turns), from the output registers the
/// terms name. Computing these is most of the cost of a model update (float conversions),
/// so the firmware does it with the model evaluation at low priority, and the servo tick
/// that applies the result ([`Synth::apply`]) only starts the ramps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SynthTargets {
    amp_pm: i32,
    phase_turns: u32,
    term_amp_pm: [i32; MAX_TERMS],
    term_phase_turns: [u32; MAX_TERMS],
    /// Harmonic order of each term (0 for kernel terms and beyond the terms).
    term_orders: [u32; MAX_TERMS],
    /// Bit `i` set: term `i` is a kernel term.
    kernel_mask: u32,
}

impl SynthTargets {
    /// Silence: every amplitude zero (what [`ModelOutput::default`] gives).
    pub const SILENT: Self = Self {
        amp_pm: 0,
        phase_turns: 0,
        term_amp_pm: [0; MAX_TERMS],
        term_phase_turns: [0; MAX_TERMS],
        term_orders: [0; MAX_TERMS],
        kernel_mask: 0,
    };

    /// The targets of `output` for the tick terms `terms` (kernel terms have none).
    pub fn new(output: &ModelOutput, terms: &[TickTerm]) -> Self {
        let mut targets =
            Self { amp_pm: um_to_pm(output.amp_um()), phase_turns: deg_to_turns(output.phase_deg()), ..Self::SILENT };
        for (i, term) in terms.iter().take(MAX_TERMS).enumerate() {
            if let TickTerm::Harmonic { order, amp_reg, phase_reg } = *term {
                let register = |r: u8| output.registers.get(r as usize).copied().unwrap_or(0.0);
                targets.term_amp_pm[i] = um_to_pm(register(amp_reg));
                targets.term_phase_turns[i] = deg_to_turns(register(phase_reg));
                targets.term_orders[i] = u32::from(order);
            } else {
                targets.kernel_mask |= 1 << i;
            }
        }
        targets
    }

    /// Makes slot `slot` a harmonic of `order` with amplitude `amp_pm` and phase
    /// `phase_turns`, whatever term the program has there (the servo synthesises the axis
    /// twin's correction so; see `Models::compute`).
    pub fn set_harmonic(&mut self, slot: usize, order: u32, amp_pm: i32, phase_turns: u32) {
        if slot < MAX_TERMS {
            self.term_amp_pm[slot] = amp_pm;
            self.term_phase_turns[slot] = phase_turns;
            self.term_orders[slot] = order;
            self.kernel_mask &= !(1 << slot);
        }
    }
}

/// The harmonic part of a synthesiser: the fundamental's and each term slot's ramp and
/// order. A [`Synth`] holds two: the live one and one where a model update is prepared
/// ahead of its tick ([`Synth::prepare`]), so that applying it is a switch.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Harmonics {
    fundamental: Ramp,
    /// Amplitude and phase offset of each slot's harmonic.
    ramps: [Ramp; MAX_TERMS],
    /// Harmonic order of each slot (0 for kernel slots).
    orders: [u32; MAX_TERMS],
    /// Slots the tick visits.
    term_count: usize,
    /// Slots from here on are settled silent (amplitude, target and steps zero, phase at its
    /// target, no kernel): retargeting them to silence again would change nothing.
    idle_from: usize,
    /// Slots whose harmonic ramps out because the terms changed (a program switch, see
    /// [`Harmonics::retarget_terms`]): model updates leave them be, and the fade's last tick
    /// silences them exactly and stops visiting them (`Synth::ramp_left` counts to it).
    fading: u32,
    /// While slots fade: the other ramps' steps left after the fade's last tick (0: they end
    /// with it).
    rest_ticks: u32,
    /// Terms of the update in force: the slots visited once the fade is over.
    count: usize,
    /// The kernel terms' cells (switched with the bank, so that applying a prepared update
    /// is one switch).
    kernels: KernelIndex,
}

/// What [`Harmonics::retarget_terms`] decided besides the ramps.
struct TermsUpdate {
    /// Kernel slots that run from the update on (those already running and kept, and those
    /// starting from rest).
    kernels: u32,
    /// Ticks to the ramps' next event ([`Harmonics::end_ramps`]).
    ramp_left: u32,
}

impl Harmonics {
    const IDLE: Self = Self {
        fundamental: Ramp::IDLE,
        ramps: [Ramp::IDLE; MAX_TERMS],
        orders: [0; MAX_TERMS],
        term_count: 0,
        idle_from: 0,
        fading: 0,
        rest_ticks: 0,
        count: 0,
        kernels: KernelIndex::INITIAL,
    };

    /// What the ticks of a running ramp end in: every visited value on its target.
    fn settle(&mut self) {
        self.fundamental.finish();
        let count = self.term_count.min(MAX_TERMS);
        self.ramps[..count].iter_mut().for_each(Ramp::finish);
    }

    /// The tick with one ramp tick left: the ramps end, settling on their targets, or a fade
    /// ends ([`Harmonics::end_fade`]) while other ramps run on (this tick holds them, they
    /// step on from the next). Returns the ramp ticks left after it.
    fn end_ramps(&mut self) -> u32 {
        if self.fading != 0 {
            self.end_fade();
            if self.rest_ticks != 0 {
                return self.rest_ticks + 1;
            }
        }
        self.settle();
        0
    }

    /// The fade's last tick: the fading slots' amplitudes land on zero exactly (the step of
    /// a ramp's last tick: its step and the remainder the truncated steps left), and only the
    /// update's own terms are visited from now on.
    #[cold]
    fn end_fade(&mut self) {
        let mut fading = self.fading & 0xff;
        while fading != 0 {
            let i = (fading.trailing_zeros() & 7) as usize;
            fading &= fading - 1;
            // Target and phase step are already zero: settled silent.
            self.ramps[i].amp_pm = 0;
            self.ramps[i].amp_step_pm = 0;
        }
        self.fading = 0;
        self.term_count = self.count;
        self.idle_from = self.count;
    }

    /// Whether slot `i`'s harmonic sounds now or by its ramp's end.
    fn sounds(&self, i: usize) -> bool {
        let ramp = &self.ramps[i & 7];
        self.orders[i & 7] != 0 && (ramp.amp_pm != 0 || ramp.amp_target_pm != 0)
    }

    /// The harmonics of the slots in `slots` (bits) for command phase `cmd_phase_turns`,
    /// stepping their ramps first when `ramping`; picometres.
    #[inline(always)]
    fn harmonic_slots_pm(&mut self, slots: u32, ramping: bool, cmd_phase_turns: u32) -> i64 {
        let mut total = 0i64;
        // Masked to MAX_TERMS = 8 slots: no index can be out of bounds.
        let mut visit = slots & 0xff;
        while visit != 0 {
            let i = (visit.trailing_zeros() & 7) as usize;
            visit &= visit - 1;
            let ramp = &mut self.ramps[i];
            if ramping {
                ramp.step();
            }
            let phase = cmd_phase_turns.wrapping_mul(self.orders[i]).wrapping_add(ramp.phase_turns);
            total += ramp_harmonic_pm(ramp.amp_pm, phase) as i64;
        }
        total
    }

    /// Starts the term slots' ramps to `targets` for `count` terms over `ramp` ticks, with
    /// `ramp_left` ticks to the ramps' next event before the update. `running` marks the
    /// slots whose kernel term runs, `kept` those of them whose term stays (the same term in
    /// the same slot: it runs on with its state).
    ///
    /// A harmonic that has to go (its slot is beyond the terms, or holds another kind of
    /// term now) ramps out over `ramp` ticks and is then dropped: the fade. It starts when
    /// the terms change (a program switch), and later updates neither restart nor retarget
    /// it, so it ends `ramp` ticks after the switch however often model updates come (they
    /// used to restart it with truncated steps: below `ramp` pm an amplitude never reached
    /// zero). Meanwhile the terms that replace a fading harmonic in its slot, and any
    /// kernel term that is not kept, wait: they start with the first update after the fade
    /// (a harmonic from silence, a kernel from rest), so that the tick never runs the old
    /// harmonics beside new kernel terms and stays within the budget of the programs on
    /// either side (see [`crate::program::tick_cost`]). New harmonics in free slots start at
    /// once, kernel terms that go stop at once (as before: they have no ramp).
    fn retarget_terms(
        &mut self,
        targets: &SynthTargets,
        count: usize,
        running: u32,
        kept: u32,
        ramp_left: u32,
        ramp: u32,
    ) -> TermsUpdate {
        let count = count.min(MAX_TERMS);
        // Masked to MAX_TERMS = 8 slots: no index below can be out of bounds.
        let in_update = ((1u32 << count) - 1) & 0xff;
        let kernel_slots = targets.kernel_mask & in_update;
        let mut fading = self.fading;
        let mut new_fading = 0u32;
        let mut harmonics = !targets.kernel_mask & in_update;
        while harmonics != 0 {
            let i = (harmonics.trailing_zeros() & 7) as usize;
            let bit = harmonics & harmonics.wrapping_neg();
            harmonics &= harmonics - 1;
            let order = targets.term_orders[i];
            let phase = targets.term_phase_turns[i];
            if self.orders[i] == order && running & bit == 0 {
                // The same harmonic, also one that was fading: on from where it is.
                fading &= !bit;
            } else if self.sounds(i) {
                // Another harmonic sounds in the slot: it ramps out first.
                new_fading |= bit & !fading;
                continue;
            } else {
                // A new kind of term starts from silence at its own phase. (Its kernel state
                // is not read while it is a harmonic, and is reset when it becomes a kernel.)
                self.orders[i] = order;
                self.ramps[i] = Ramp { phase_turns: phase, ..Ramp::IDLE };
                fading &= !bit;
            }
            self.ramps[i].retarget(targets.term_amp_pm[i], phase, ramp);
        }
        let mut kernels = kernel_slots & !kept;
        while kernels != 0 {
            let i = (kernels.trailing_zeros() & 7) as usize;
            let bit = kernels & kernels.wrapping_neg();
            kernels &= kernels - 1;
            if self.sounds(i) {
                // A harmonic sounds in the slot: it ramps out first.
                new_fading |= bit & !fading;
            } else {
                // Silent: the slot is the kernel's (its ramp stays idle).
                self.orders[i] = 0;
                self.ramps[i] = Ramp::IDLE;
                fading &= !bit;
            }
        }
        // Beyond the terms: harmonics ramp out, kernel terms stop.
        let mut idle_from = count;
        for i in count..self.idle_from.max(count) {
            let bit = 1 << i;
            if fading & bit != 0 {
                continue;
            }
            if self.sounds(i) {
                new_fading |= bit;
                continue;
            }
            let slot = &mut self.ramps[i];
            let phase = slot.phase_turns;
            slot.retarget(0, phase, ramp);
            if slot.amp_pm != 0 {
                idle_from = i + 1;
            }
        }
        fading |= new_fading;
        let ramp_left = if new_fading != 0 || (fading != 0 && (ramp < ramp_left || ramp_left == 0)) {
            // A fade starts (or the update's ramps would end before the fade does; or no
            // event is due, which a fade always has): every fading harmonic ramps out from
            // where it is, in step with the update's ramps.
            let mut restart = fading & 0xff;
            while restart != 0 {
                let i = (restart.trailing_zeros() & 7) as usize;
                restart &= restart - 1;
                let slot = &mut self.ramps[i];
                let phase = slot.phase_turns;
                slot.retarget(0, phase, ramp);
                if slot.amp_pm == 0 {
                    // At once (no ramp): gone.
                    fading &= !(1 << i);
                }
            }
            self.rest_ticks = 0;
            ramp
        } else if fading != 0 {
            // The fade runs on to its end; the update's ramps go on after it.
            self.rest_ticks = ramp - ramp_left;
            ramp_left
        } else {
            self.rest_ticks = 0;
            ramp
        };
        let fading_to = (32 - fading.leading_zeros()) as usize;
        self.fading = fading;
        self.count = count;
        self.term_count = count.max(fading_to);
        self.idle_from = idle_from.max(fading_to);
        // Kernel terms that are not kept wait while harmonics fade.
        let kernels = if fading != 0 { kernel_slots & kept } else { kernel_slots };
        TermsUpdate { kernels, ramp_left }
    }

    /// The state after `ticks` ticks of synthesis ([`Synth::next_input`]) with `ramp_left`
    /// ticks to the ramps' next event, and the ramp ticks left then.
    fn advanced(mut self, mut ramp_left: u32, mut ticks: u32) -> (Self, u32) {
        while ramp_left != 0 && ticks != 0 {
            if ticks < ramp_left {
                self.step_n(ticks);
                return (self, ramp_left - ticks);
            }
            // Steps up to the event's tick, then the event (which settles every ramp that
            // ends with it: stepping those first would change nothing).
            if self.fading != 0 && self.rest_ticks != 0 {
                self.step_n(ramp_left - 1);
            }
            ticks -= ramp_left;
            ramp_left = self.end_ramps();
        }
        (self, ramp_left)
    }

    /// `ticks` steps of every visited ramp.
    fn step_n(&mut self, ticks: u32) {
        self.fundamental.step_n(ticks);
        let count = self.term_count.min(MAX_TERMS);
        self.ramps[..count].iter_mut().for_each(|ramp| ramp.step_n(ticks));
    }
}

/// A kernel term slot's storage: the term (`None`: the slot holds none) and its state.
#[derive(Clone, Copy, Debug, PartialEq)]
struct KernelSlot {
    term: Option<TickTerm>,
    state: KernelState,
}

impl KernelSlot {
    const EMPTY: Self = Self { term: None, state: KernelState::REST };

    /// Resets of the axis twin state this cell holds (0 for other terms).
    fn axis_resets(&self) -> u32 {
        self.state.axis.as_ref().map_or(0, |(_, state)| state.resets)
    }
}

/// Storage cells per term slot: the live one and one for a prepared restart.
const CELLS: usize = 2 * MAX_TERMS;
const _: () = assert!(CELLS == 16, "kernel cells are indexed with 4 bits");

/// Which storage cell each term slot uses, and the cells of the kernel terms in force.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct KernelIndex {
    /// Slot `i` lives in cell `2i` or `2i + 1` (the other one receives a prepared restart).
    cell_of_slot: [u8; MAX_TERMS],
    /// The cells of the slots holding kernel terms, `kernel_count` of them: first the
    /// `laguerre_count` Laguerre banks, then the others, each in slot order (the tick runs
    /// the banks in a loop of their own, without dispatching on the kind).
    kernel_cells: [u8; MAX_TERMS],
    kernel_count: u32,
    laguerre_count: u32,
    /// Bit `i` set: slot `i` holds a kernel term.
    kernel_mask: u32,
}

impl KernelIndex {
    const INITIAL: Self = Self {
        cell_of_slot: [0, 2, 4, 6, 8, 10, 12, 14],
        kernel_cells: [0; MAX_TERMS],
        kernel_count: 0,
        laguerre_count: 0,
        kernel_mask: 0,
    };

    /// Sets the kernel slots to `mask` (of `terms`), listing their cells.
    fn set_kernels(&mut self, mask: u32, terms: &[TickTerm]) {
        self.kernel_mask = mask;
        let mut count = 0;
        for laguerre in [true, false] {
            for (slot, (&cell, term)) in self.cell_of_slot.iter().zip(terms).enumerate() {
                if mask & (1 << slot) != 0 && matches!(term, TickTerm::Laguerre { .. }) == laguerre {
                    self.kernel_cells[count] = cell;
                    count += 1;
                }
            }
            if laguerre {
                self.laguerre_count = count as u32;
            }
        }
        self.kernel_count = count as u32;
    }
}

/// What a prepared model update was computed from (see [`Synth::prepare`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Prepared {
    /// [`Synth`]`::generation` when it was prepared.
    generation: u32,
    /// The ramp length it used.
    ramp_ticks: u32,
    /// The machine time ([`Synth`]`::ticks`) at which it applies.
    at_ticks: u64,
    /// `Synth::ramp_left` after it.
    ramp_left: u32,
}

/// The error synthesiser. See the [module docs](self).
///
/// Term slot `i` holds the `i`-th tick term of the program in force: a harmonic (its order
/// and ramp) or a kernel term (its kind and filter state; its ramp stays idle at zero, so
/// the harmonic loop may run over it and add exactly nothing).
///
/// `repr(C)`, the per-tick fields first and the kernel cells (2.9 KB) last, for short
/// offsets (see [`crate::servo::Servo`]).
#[derive(Clone, Debug, PartialEq)]
#[repr(C)]
pub struct Synth {
    /// Machine time: ticks since the synthesiser started (or [`Synth::set_time_ticks`]).
    ticks: u64,
    /// Index of the live bank, 0 or 1.
    live: usize,
    /// Ticks left to the ramps' next event: their end (all of them were retargeted
    /// together), or the end of a fade while others run on (see `Harmonics::end_ramps`).
    ramp_left: u32,
    /// Model updates applied (wrapping): a prepared update is valid for one generation.
    generation: u32,
    /// Ticks over which a model update moves amplitude and phase to their new values.
    pub ramp_ticks: u32,
    /// The update prepared in the other bank and cells, if any.
    prepared: Option<Prepared>,
    /// The live harmonics (`banks[live]`) and a prepared update (the other one).
    banks: [Harmonics; 2],
    /// Kernel terms and their states, two cells per slot (see [`KernelIndex`]).
    cells: [KernelSlot; CELLS],
    /// Axis twin resets of the states overwritten so far (the cells hold the others').
    axis_resets_retired: u32,
}

impl Eq for Synth {}

impl Synth {
    /// A silent synthesiser (amplitude zero) that ramps model updates over `ramp_ticks`.
    pub const fn new(ramp_ticks: u32) -> Self {
        Self {
            banks: [Harmonics::IDLE; 2],
            live: 0,
            cells: [KernelSlot::EMPTY; CELLS],
            ramp_left: 0,
            generation: 0,
            prepared: None,
            ticks: 0,
            ramp_ticks,
            axis_resets_retired: 0,
        }
    }

    /// Servo-axis twin states reset after diverging, since the synthesiser started (wrapping;
    /// counted off the tick: the tick only counts in the state it steps).
    pub fn axis_resets(&self) -> u32 {
        self.cells.iter().fold(self.axis_resets_retired, |sum, cell| sum.wrapping_add(cell.axis_resets()))
    }

    /// Keeps the count of the state in `cell`, which is about to be overwritten.
    fn retire(&mut self, cell: usize) {
        self.axis_resets_retired = self.axis_resets_retired.wrapping_add(self.cells[cell].axis_resets());
    }

    #[inline(always)]
    fn harmonics(&self) -> &Harmonics {
        &self.banks[self.live & 1]
    }

    #[inline(always)]
    fn harmonics_mut(&mut self) -> &mut Harmonics {
        &mut self.banks[self.live & 1]
    }

    /// The live storage of term slot `i`.
    fn slot(&self, i: usize) -> &KernelSlot {
        &self.cells[self.harmonics().kernels.cell_of_slot[i & 7] as usize & (CELLS - 1)]
    }

    fn slot_mut(&mut self, i: usize) -> &mut KernelSlot {
        let cell = self.harmonics().kernels.cell_of_slot[i & 7] as usize & (CELLS - 1);
        &mut self.cells[cell]
    }

    /// Takes a new model output: the fundamental from its amplitude and phase registers and
    /// the tick terms' coefficients from theirs. Terms that disappear ramp to zero first.
    /// The same as [`Synth::apply`] of [`SynthTargets::new`].
    pub fn update(&mut self, output: &ModelOutput, terms: &[TickTerm]) {
        self.apply(&SynthTargets::new(output, terms), terms);
    }

    /// Takes a new model output, converted beforehand ([`SynthTargets::new`] of the same
    /// `terms`): starts the ramps to it. When the terms change, harmonics that go ramp out
    /// first and the terms taking their place wait for them (see `Harmonics::retarget_terms`).
    pub fn apply(&mut self, targets: &SynthTargets, terms: &[TickTerm]) {
        let ramp = self.ramp_ticks;
        let count = terms.len().min(MAX_TERMS);
        let kept = self.kept_kernels(targets, &terms[..count]);
        let (live, ramp_left) = (self.live & 1, self.ramp_left);
        let h = &mut self.banks[live];
        h.fundamental.retarget(targets.amp_pm, targets.phase_turns, ramp);
        let running = h.kernels.kernel_mask;
        let update = h.retarget_terms(targets, count, running, kept, ramp_left, ramp);
        self.change_kernels(running & !kept, update.kernels & !kept, &terms[..count]);
        self.ramp_left = update.ramp_left;
        self.harmonics_mut().kernels.set_kernels(update.kernels, &terms[..count]);
        self.generation = self.generation.wrapping_add(1);
        self.prepared = None;
    }

    /// The kernel slots of `terms` whose term runs in its slot now (and so runs on).
    fn kept_kernels(&self, targets: &SynthTargets, terms: &[TickTerm]) -> u32 {
        let mut kept = 0;
        for (i, term) in terms.iter().enumerate() {
            if targets.kernel_mask & (1 << i) != 0 && self.slot(i).term == Some(*term) {
                kept |= 1 << i;
            }
        }
        kept
    }

    /// Applies an update's kernel changes to the live cells: the terms of the slots `stop`
    /// go, those of `start` (of `terms`) start from rest.
    #[inline(never)]
    fn change_kernels(&mut self, stop: u32, start: u32, terms: &[TickTerm]) {
        let ticks = self.ticks;
        for i in 0..MAX_TERMS {
            match terms.get(i) {
                Some(term) if start & (1 << i) != 0 => {
                    self.retire(self.harmonics().kernels.cell_of_slot[i & 7] as usize & (CELLS - 1));
                    *self.slot_mut(i) = KernelSlot { term: Some(*term), state: KernelState::start(term, ticks) };
                }
                _ if stop & (1 << i) != 0 => self.slot_mut(i).term = None,
                _ => {}
            }
        }
    }

    /// Prepares the model update `targets` of `terms` (as [`Synth::apply_prepared`] will
    /// apply it) for `ticks_ahead` ticks from now: on the state the running ramps will be in
    /// then, with any kernel term that starts then set up in its slot's spare cell. The tick
    /// applying it then only switches banks and cells.
    pub fn prepare(&mut self, targets: &SynthTargets, terms: &[TickTerm], ticks_ahead: u32) {
        let ramp = self.ramp_ticks;
        let count = terms.len().min(MAX_TERMS);
        let at_ticks = self.ticks.wrapping_add(u64::from(ticks_ahead));
        let live = self.live & 1;
        let (mut next, ramp_left) = self.banks[live].advanced(self.ramp_left, ticks_ahead);
        // (The cells do not change before then: only an update changes them.)
        let kept = self.kept_kernels(targets, &terms[..count]);
        next.fundamental.retarget(targets.amp_pm, targets.phase_turns, ramp);
        let running = next.kernels.kernel_mask;
        let update = next.retarget_terms(targets, count, running, kept, ramp_left, ramp);
        // As `change_kernels`, in the spare cells.
        let (stop, start) = (running & !kept, update.kernels & !kept);
        for i in 0..MAX_TERMS {
            if (stop | start) & (1 << i) != 0 {
                let spare = (next.kernels.cell_of_slot[i] ^ 1) as usize & (CELLS - 1);
                self.cells[spare] = match terms.get(i) {
                    Some(term) if start & (1 << i) != 0 => {
                        self.retire(spare);
                        KernelSlot { term: Some(*term), state: KernelState::start(term, at_ticks) }
                    }
                    _ => KernelSlot { term: None, ..self.cells[spare] },
                };
                next.kernels.cell_of_slot[i] = spare as u8;
            }
        }
        next.kernels.set_kernels(update.kernels, &terms[..count]);
        self.banks[live ^ 1] = next;
        self.prepared =
            Some(Prepared { generation: self.generation, ramp_ticks: ramp, at_ticks, ramp_left: update.ramp_left });
    }

    /// Applies a model update: the one [`Synth::prepare`]d, by switching banks and cells,
    /// when it is applied at the machine time it was prepared for and nothing changed since;
    /// otherwise as [`Synth::apply`]. Either way the result is that of [`Synth::apply`], bit
    /// for bit, provided `targets` and `terms` are those last prepared (when something else
    /// is to be applied, call [`Synth::apply`]).
    #[inline]
    pub fn apply_prepared(&mut self, targets: &SynthTargets, terms: &[TickTerm]) {
        if !self.switch_prepared() {
            self.apply(targets, terms);
        }
    }

    /// Applies the update [`Synth::prepare`]d, by switching banks and cells, if it was
    /// prepared for this machine time and nothing changed since; returns whether it did
    /// (otherwise nothing changes: apply the update with [`Synth::apply`]).
    #[inline]
    pub fn switch_prepared(&mut self) -> bool {
        match self.prepared {
            Some(p)
                if p.generation == self.generation && p.ramp_ticks == self.ramp_ticks && p.at_ticks == self.ticks =>
            {
                self.live ^= 1;
                self.ramp_left = p.ramp_left;
                self.generation = self.generation.wrapping_add(1);
                self.prepared = None;
                true
            }
            _ => false,
        }
    }

    /// Ramps everything to silence (no model in force).
    pub fn silence(&mut self) {
        self.apply(&SynthTargets::SILENT, &[]);
    }

    /// The predicted dynamic error at this tick, picometres, for command phase `cmd_phase_turns`
    /// (kernel terms see a command position of zero and no other axes; see [`Synth::next_input`]).
    #[inline]
    pub fn next(&mut self, cmd_phase_turns: u32) -> i32 {
        self.next_input(&TickInput { cmd_phase_turns, ..TickInput::default() })
    }

    /// The predicted dynamic error at this tick, picometres, from everything the tick knows.
    #[inline]
    pub fn next_input(&mut self, input: &TickInput) -> i32 {
        let cmd_phase_turns = input.cmd_phase_turns;
        let live = self.live & 1;
        let kernel_mask = self.banks[live].kernels.kernel_mask;
        let ramping = self.ramp_left > 1;
        if ramping {
            self.ramp_left -= 1;
        } else if self.ramp_left == 1 {
            self.finish_ramps();
        }
        // (After the ramps' event: the end of a fade no longer visits the faded slots.)
        let count = self.banks[live].term_count.min(MAX_TERMS);
        let h = &mut self.banks[live];
        if ramping {
            h.fundamental.step();
        }
        let mut total =
            ramp_harmonic_pm(h.fundamental.amp_pm, cmd_phase_turns.wrapping_add(h.fundamental.phase_turns)) as i64;
        if kernel_mask == 0 {
            // Kernel-free: every visited slot is a harmonic (or an idle one), in one pass.
            if ramping {
                for (ramp, &order) in h.ramps[..count].iter_mut().zip(&h.orders[..count]) {
                    ramp.step();
                    let phase = cmd_phase_turns.wrapping_mul(order).wrapping_add(ramp.phase_turns);
                    total += ramp_harmonic_pm(ramp.amp_pm, phase) as i64;
                }
            } else {
                for (ramp, &order) in h.ramps[..count].iter().zip(&h.orders[..count]) {
                    let phase = cmd_phase_turns.wrapping_mul(order).wrapping_add(ramp.phase_turns);
                    total += ramp_harmonic_pm(ramp.amp_pm, phase) as i64;
                }
            }
            self.ticks = self.ticks.wrapping_add(1);
        } else {
            // Kernel slots' ramps are idle (amplitude and steps zero) and would add exactly
            // nothing: the harmonic pass skips them.
            total =
                total.wrapping_add(h.harmonic_slots_pm(((1u32 << count) - 1) & !kernel_mask, ramping, cmd_phase_turns));
            let ticks = self.ticks;
            total = total.wrapping_add(self.kernels_pm(input, ticks));
            self.ticks = ticks.wrapping_add(1);
        }
        total.clamp(i32::MIN as i64, i32::MAX as i64) as i32
    }

    /// The tick with one ramp tick left: the ramps' end, or a fade's (see
    /// `Harmonics::end_ramps`).
    #[inline(never)]
    fn finish_ramps(&mut self) {
        self.ramp_left = self.harmonics_mut().end_ramps();
    }

    /// The kernel terms' sum for this tick, picometres.
    #[inline(always)]
    fn kernels_pm(&mut self, input: &TickInput, ticks: u64) -> i64 {
        let mut total = 0i64;
        let Self { banks, live, cells, .. } = self;
        let kernels = &banks[*live & 1].kernels;
        let count = (kernels.kernel_count as usize).min(MAX_TERMS);
        let banks = (kernels.laguerre_count as usize).min(count);
        for &cell in &kernels.kernel_cells[..banks] {
            let KernelSlot { term, state } = &mut cells[cell as usize & (CELLS - 1)];
            if let Some(TickTerm::Laguerre { input: kind, pole_q30, gains_pm }) = term {
                total = total.wrapping_add(laguerre_pm(kind, *pole_q30, gains_pm, state, input));
            }
        }
        for &cell in &kernels.kernel_cells[banks..count] {
            let KernelSlot { term, state } = &mut cells[cell as usize & (CELLS - 1)];
            if let Some(term) = term {
                total = total.wrapping_add(kernel_pm(term, state, input, ticks));
            }
        }
        total
    }

    /// Sets the machine time (ticks since the machine started), e.g. to replay a measurement
    /// group that started at a known machine time; drift terms jump to their value then.
    pub fn set_time_ticks(&mut self, ticks: u64) {
        self.ticks = ticks;
        for i in 0..MAX_TERMS {
            let slot = self.slot_mut(i);
            if let Some(TickTerm::Drift { decay_pm, tau_ticks, .. }) = slot.term {
                drift_at(&mut slot.state, decay_pm, tau_ticks, ticks);
            }
        }
    }

    /// Restarts the kernel terms' filter states (a new motion from rest), keeping the model
    /// and the count of axis twin resets ([`Synth::axis_resets`]).
    pub fn restart_kernels(&mut self) {
        for i in 0..MAX_TERMS {
            let slot = self.slot_mut(i);
            if slot.term.is_some() {
                let keep = slot.state;
                let axis = keep.axis.map(|(model, state)| {
                    let mut rest = AxisState::INITIAL;
                    rest.resets = state.resets;
                    (model, rest)
                });
                slot.state = KernelState {
                    stages: keep.stages.rested(),
                    pos_hist: [0; 4],
                    dahl_q30: 0,
                    primed: false,
                    axis,
                    ..keep
                };
            }
        }
    }

    /// The amplitude currently in force (after ramping), picometres.
    pub fn amp_pm(&self) -> i32 {
        self.harmonics().fundamental.amp_pm
    }

    /// The phase offset currently in force, turns.
    pub fn phase_turns(&self) -> u32 {
        self.harmonics().fundamental.phase_turns
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_twin_resets_are_counted_across_restarts_and_replacements() {
        // A derivative gain far beyond what the tick can carry: it diverges on any motion.
        let unstable = TickTerm::Axis(crate::axis::AxisParams { kd_per_s: 9e5, ..crate::axis::default_machine() });
        let mut synth = Synth::new(0);
        synth.update(&ModelOutput::default(), &[unstable]);
        let run = |synth: &mut Synth| {
            for k in 0..2000 {
                let cmd_pos_nm =
                    (3000.0 * libm::sin(2.0 * core::f64::consts::PI * 40.0 * f64::from(k) / 8000.0)) as i32;
                synth.next_input(&TickInput { cmd_phase_turns: 0, cmd_pos_nm, x_acc_um_per_s2: 0, spindle_turns: 0 });
            }
            synth.axis_resets()
        };
        let first = run(&mut synth);
        assert!(first > 0);
        // A restart from rest keeps the count, and the next motion adds to it.
        synth.restart_kernels();
        assert_eq!(synth.axis_resets(), first);
        let second = run(&mut synth);
        assert!(second > first);
        // Replacing the term (another program) keeps the old state's count.
        synth.update(&ModelOutput::default(), &[]);
        synth.update(&ModelOutput::default(), &[TickTerm::Axis(crate::axis::default_machine())]);
        assert_eq!(synth.axis_resets(), second);
    }

    fn output(amp_um: f32, phase_deg: f32) -> ModelOutput {
        let mut out = ModelOutput::default();
        out.registers[0] = amp_um;
        out.registers[1] = phase_deg;
        out
    }

    #[test]
    fn the_sine_table_is_accurate() {
        let mut worst = 0.0f64;
        for k in 0..100_000u64 {
            let phase = (k * 42_949_673 + 12345) as u32;
            let exact = (2.0 * core::f64::consts::PI * phase as f64 / 4_294_967_296.0).sin();
            let got = sin_q31(phase) as f64 / 2147483648.0;
            worst = worst.max((exact - got).abs());
        }
        assert!(worst < 5e-6, "worst sine error {worst}");
    }

    fn rng(seed: &mut u64) -> u64 {
        *seed ^= *seed << 13;
        *seed ^= *seed >> 7;
        *seed ^= *seed << 17;
        *seed
    }

    #[test]
    fn the_sine_interpolation_is_the_plain_one_bit_for_bit() {
        let plain = |phase: u32| {
            let index = (phase >> 22) as usize;
            let frac = ((phase >> 6) & 0xffff) as i64;
            let a = SINE_Q31[index] as i64;
            let b = SINE_Q31[index + 1] as i64;
            (a + (((b - a) * frac) >> 16)) as i32
        };
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        for k in 0..200_000u64 {
            let phase = if k < 4096 { (k as u32) << 20 | (k as u32 & 0x3f) } else { rng(&mut seed) as u32 };
            assert_eq!(sin_q31(phase), plain(phase), "phase {phase:#x}");
        }
        for phase in [0u32, u32::MAX, 0x7fff_ffff, 0x8000_0000, 0x003f_ffc0, 0xffc0_0000] {
            assert_eq!(sin_q31(phase), plain(phase));
        }
    }

    #[test]
    fn the_ramp_harmonic_is_the_plain_one_bit_for_bit() {
        let mut seed = 7u64;
        for k in 0..200_000 {
            let amp = match k % 4 {
                0 => RAMP_AMP_LIMIT_PM,
                1 => -RAMP_AMP_LIMIT_PM,
                _ => (rng(&mut seed) % (2 * RAMP_AMP_LIMIT_PM as u64 + 1)) as i64 as i32 - RAMP_AMP_LIMIT_PM,
            };
            let phase = rng(&mut seed) as u32;
            assert_eq!(ramp_harmonic_pm(amp, phase), harmonic_pm(amp, phase), "amp {amp} phase {phase:#x}");
        }
    }

    #[test]
    fn degrees_convert_as_through_64_bits() {
        let wide = |value_deg: f32| if value_deg.is_finite() { deg_to_turns_wide(value_deg / 360.0) } else { 0 };
        let mut seed = 11u64;
        let mut values = std::vec![
            0.0f32,
            -0.0,
            1e-30,
            -1e-30,
            359.99997,
            -359.99997,
            180.0,
            -180.0,
            7.7e11,
            -7.7e11,
            3e12,
            f32::MAX,
            f32::MIN
        ];
        for k in 0..300_000 {
            let bits = rng(&mut seed) as u32;
            values.push(match k % 3 {
                0 => f32::from_bits(bits),
                1 => (bits as i32 as f32) * 1e-3,
                _ => (bits as i32 as f32) * 400.0,
            });
        }
        for v in values {
            assert_eq!(deg_to_turns(v), wide(v), "{v:e}");
        }
    }

    #[test]
    fn degrees_convert_to_wrapping_turns() {
        assert_eq!(deg_to_turns(90.0), 1 << 30);
        assert_eq!(deg_to_turns(-90.0), 3 << 30);
        assert_eq!(deg_to_turns(450.0), 1 << 30);
        assert_eq!(deg_to_turns(f32::NAN), 0);
        assert_eq!(um_to_pm(1.5), 1_500_000);
        assert_eq!(um_to_pm(f32::INFINITY), 1_000_000_000);
        assert_eq!(um_to_pm(f32::NAN), 0);
    }

    #[test]
    fn a_settled_model_synthesises_eq4() {
        let mut synth = Synth::new(0);
        synth.update(&output(2.0, 30.0), &[]);
        for k in 0..200u32 {
            let theta = k.wrapping_mul(0x0123_4567);
            let got = synth.next(theta) as f64 * 1e-6;
            let angle = 2.0 * core::f64::consts::PI * theta as f64 / 4_294_967_296.0 + 30f64.to_radians();
            assert!((got - 2.0 * angle.sin()).abs() < 2e-5, "tick {k}: {got}");
        }
    }

    #[test]
    fn model_updates_never_step_the_waveform() {
        let mut synth = Synth::new(80);
        synth.update(&output(3.0, 10.0), &[]);
        let step = 4_294_967_296u64 / 200; // 40 Hz at 8 kHz
        let mut theta = 0u32;
        let mut last = synth.next(theta);
        let mut worst = 0i64;
        for k in 0..2000u32 {
            if k == 500 {
                synth.update(&output(1.0, 170.0), &[]);
            }
            if k == 1200 {
                synth.update(&output(5.0, -170.0), &[]);
            }
            theta = theta.wrapping_add(step as u32);
            let now = synth.next(theta);
            worst = worst.max((now as i64 - last as i64).abs());
            last = now;
        }
        // The largest change per tick of a 5 um, 40 Hz sine is 2 pi 40 * 5 um / 8 kHz = 0.157 um;
        // ramps over 80 ticks add well under that again.
        assert!(worst < 250_000, "largest per-tick change {worst} pm");
        assert_eq!(synth.amp_pm(), 5_000_000);
    }

    #[test]
    fn prepared_updates_synthesise_what_applied_ones_do_bit_for_bit() {
        let mut seed = 0x5eed_u64;
        let kernels = [
            TickTerm::Drift { offset_pm: 200_000, decay_pm: -300_000, tau_ticks: 5000 },
            TickTerm::AxisCoupling {
                x_gain_pm_per_mps2: 700_000,
                spindle_amp_pm: 40_000,
                spindle_phase_turns: 3 << 28,
            },
            TickTerm::Laguerre {
                input: TermInput::VelocitySign { smooth_nm_per_4_ticks: 300 },
                pole_q30: 998_579_896,
                gains_pm: [90_000, -40_000, 20_000, 0, 0, 0, 0, 0],
            },
            TickTerm::Laguerre {
                input: TermInput::Dahl { inv_x0_q30: 1 << 20 },
                pole_q30: 1_072_668_082,
                gains_pm: [50_000, 0, -20_000, 0, 0, 0, 0, 9_000],
            },
        ];
        for round in 0..60 {
            let ramp_ticks = [0, 1, 7, 80][round % 4];
            let mut plain = Synth::new(ramp_ticks);
            let mut prepared = Synth::new(ramp_ticks);
            let mut theta = 0u32;
            let mut pos = 0i32;
            let mut tick = |plain: &mut Synth, prepared: &mut Synth, what: &str| {
                theta = theta.wrapping_add(0x0147_ae14);
                pos = pos.wrapping_add(((theta >> 20) % 301) as i32 - 150);
                let input = TickInput {
                    cmd_phase_turns: theta,
                    cmd_pos_nm: pos,
                    x_acc_um_per_s2: (theta >> 8) as i32,
                    spindle_turns: theta.wrapping_mul(3),
                };
                assert_eq!(plain.next_input(&input), prepared.next_input(&input), "round {round}: {what}");
            };
            for update in 0..30 {
                let term_count = (rng(&mut seed) % 9) as usize;
                let mut out = output((rng(&mut seed) % 5000) as f32 * 1e-3, (rng(&mut seed) % 720) as f32 - 360.0);
                let mut terms = std::vec::Vec::new();
                for i in 0..term_count {
                    let amp_reg = 2 + 2 * (i % 3) as u8;
                    out.registers[amp_reg as usize] = (rng(&mut seed) % 3000) as f32 * 1e-3;
                    out.registers[amp_reg as usize + 1] = (rng(&mut seed) % 720) as f32 - 360.0;
                    // Orders and kinds change now and then: slots are recreated.
                    let kind = rng(&mut seed) % 8;
                    terms.push(match kind {
                        0..=3 => kernels[kind as usize],
                        _ => TickTerm::Harmonic {
                            order: 2 + (rng(&mut seed) % 3) as u8,
                            amp_reg,
                            phase_reg: amp_reg + 1,
                        },
                    });
                }
                let targets = if update % 7 == 6 { SynthTargets::SILENT } else { SynthTargets::new(&out, &terms) };
                let terms: &[TickTerm] = if update % 7 == 6 { &[] } else { &terms };
                // Prepared some ticks before its tick, usually for that tick (while the ramps
                // still run or after they settled), sometimes for another one (the fallback).
                let wait = rng(&mut seed) % 120;
                let ahead = if rng(&mut seed) % 5 == 0 { (wait + 1 + rng(&mut seed) % 3) as u32 } else { wait as u32 };
                prepared.prepare(&targets, terms, ahead);
                for _ in 0..wait {
                    tick(&mut plain, &mut prepared, "before the update");
                }
                plain.apply(&targets, terms);
                prepared.apply_prepared(&targets, terms);
                for _ in 0..(rng(&mut seed) % 100) {
                    tick(&mut plain, &mut prepared, "after the update");
                }
                // (The kernels' cells differ: a prepared restart uses the spare one.)
                let without_cells = |h: &Harmonics| Harmonics {
                    kernels: KernelIndex { cell_of_slot: [0; MAX_TERMS], kernel_cells: [0; MAX_TERMS], ..h.kernels },
                    ..*h
                };
                assert_eq!(without_cells(plain.harmonics()), without_cells(prepared.harmonics()));
                assert_eq!(plain.ramp_left, prepared.ramp_left);
                for i in 0..MAX_TERMS {
                    // (The state of an empty slot is never read: a kernel starts from rest.)
                    assert_eq!(plain.slot(i).term, prepared.slot(i).term, "round {round} slot {i}");
                    if plain.slot(i).term.is_some() {
                        assert_eq!(plain.slot(i).state, prepared.slot(i).state, "round {round} slot {i}");
                    }
                }
            }
        }
    }

    #[test]
    fn the_divisions_without_64_bit_division_are_exact() {
        let mut seed = 3u64;
        let mut values = std::vec![
            0i64,
            1,
            -1,
            999_999,
            1_000_000,
            -1_000_000,
            1 << 62,
            -(1 << 62),
            (1 << 62) - 1,
            4_611_686_018_427_387_903
        ];
        for k in 0..200_000 {
            let r = rng(&mut seed);
            values.push(match k % 3 {
                0 => (r as i32 as i64) * (rng(&mut seed) as i32 as i64),
                1 => (r >> 2) as i64 * if r & 1 == 0 { 1 } else { -1 },
                _ => (r % 10_000_000_000) as i64 - 5_000_000_000,
            });
        }
        for &p in &values {
            assert_eq!(div_1e6(p), p / 1_000_000, "{p}");
        }
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

    #[test]
    fn a_ramps_steps_at_once_are_its_steps_one_by_one() {
        let mut seed = 5u64;
        for _ in 0..20_000 {
            let mut ramp = Ramp::IDLE;
            ramp.amp_pm = (rng(&mut seed) % 2_000_000_001) as i32 - 1_000_000_000;
            ramp.phase_turns = rng(&mut seed) as u32;
            let n = 1 + (rng(&mut seed) % 400) as u32;
            ramp.retarget((rng(&mut seed) % 2_000_000_001) as i32 - 1_000_000_000, rng(&mut seed) as u32, n);
            let ticks = (rng(&mut seed) % u64::from(n)) as u32;
            let mut one_by_one = ramp;
            for _ in 0..ticks {
                one_by_one.step();
            }
            ramp.step_n(ticks);
            assert_eq!(ramp, one_by_one);
        }
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
                    if rng(&mut seed) % (1 + 2 * one as u64 / (one - a).max(1) as u64 / 4).max(1) == 0 {
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
    fn harmonic_terms_add_at_their_order_and_ramp_out() {
        let mut synth = Synth::new(0);
        let mut out = output(0.0, 0.0);
        out.registers[2] = 1.0;
        out.registers[3] = 0.0;
        let term = TickTerm::Harmonic { order: 3, amp_reg: 2, phase_reg: 3 };
        synth.update(&out, &[term]);
        // theta = 30 degrees -> sin(90 degrees) = 1 um.
        assert!((synth.next(deg_to_turns(30.0)) - 1_000_000).abs() < 50);
        synth.ramp_ticks = 10;
        synth.update(&out, &[]);
        for _ in 0..10 {
            synth.next(0);
        }
        assert_eq!(synth.next(deg_to_turns(30.0)), 0);
    }

    /// Harmonic terms of `orders`, their coefficients in the register pairs 2..8 in turn.
    fn harmonic_terms(orders: &[u8]) -> std::vec::Vec<TickTerm> {
        orders
            .iter()
            .enumerate()
            .map(|(k, &order)| TickTerm::Harmonic {
                order,
                amp_reg: 2 + 2 * (k % 3) as u8,
                phase_reg: 3 + 2 * (k % 3) as u8,
            })
            .collect()
    }

    /// A model output for [`harmonic_terms`]: amplitudes of 1.5 um, 50 pm (a ramp's step over
    /// 80 ticks truncates to zero) and 0.7 um.
    fn harmonic_output() -> ModelOutput {
        let mut out = output(2.0, 20.0);
        out.registers[2..8].copy_from_slice(&[1.5, 40.0, 5e-5, -100.0, 0.7, 170.0]);
        out
    }

    #[test]
    fn harmonics_that_go_reach_zero_exactly_and_are_dropped_under_updates_faster_than_the_ramp() {
        // The schedules of the 2,000 and 800 sample windows: an update every 112 ticks (the
        // ramps settle in between) and every 48 (they never do).
        for interval in [112u32, 48] {
            let mut synth = Synth::new(80);
            synth.update(&harmonic_output(), &harmonic_terms(&[2, 3, 4, 5, 6, 7, 8, 9]));
            for _ in 0..100 {
                synth.next(0);
            }
            let two = harmonic_terms(&[2, 3]);
            let mut theta = 0u32;
            for k in 0..3000u32 {
                if k % interval == 0 {
                    synth.update(&harmonic_output(), &two);
                }
                theta = theta.wrapping_add(0x0147_ae14);
                synth.next(theta);
                let h = synth.harmonics();
                if k < 79 {
                    // Ramping out (the 50 pm ones too: they hold until the last tick).
                    assert_eq!(h.term_count, 8, "interval {interval} tick {k}");
                    assert!(
                        h.ramps[2..].iter().all(|r| r.amp_pm != 0 && r.amp_target_pm == 0),
                        "interval {interval} tick {k}"
                    );
                } else {
                    // From the fade's last tick (80 ticks from the switch) on: exactly zero and
                    // no longer visited, however often the updates came.
                    assert_eq!((h.term_count, h.idle_from, h.fading), (2, 2, 0), "interval {interval} tick {k}");
                    assert!(
                        h.ramps[2..].iter().all(|r| r.amp_pm == 0
                            && r.amp_step_pm == 0
                            && r.amp_target_pm == 0
                            && r.phase_step_turns == 0),
                        "interval {interval} tick {k}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_switch_to_kernel_terms_ramps_the_harmonics_out_before_the_kernels_start() {
        let sine = |phase_turns| TickTerm::Laguerre {
            input: TermInput::PositionSine { turns_per_nm: 4295, phase_turns },
            pole_q30: 998_579_896,
            gains_pm: [180_000, -95_000, 61_000, -40_000, 22_000, -15_000, 9_000, -4_000],
        };
        let banks = [sine(0), sine(1 << 30)];
        let out = harmonic_output();
        let eight = harmonic_terms(&[2, 3, 4, 5, 6, 7, 8, 9]);
        // A held command: the harmonics change only by their ramps. Per tick a ramp moves its
        // amplitude by its step (at most 1.5 um / 80), on its last tick by the remainder of
        // the truncated steps too (below 80 pm); the sine's rounding adds a picometre.
        let input = TickInput { cmd_phase_turns: 0x2345_6789, cmd_pos_nm: 1234, ..TickInput::default() };
        let bound: i64 = eight.iter().map(|_| 1_500_000 / 80 + 80 + 1).sum();
        for interval in [112u32, 48] {
            let mut synth = Synth::new(80);
            synth.update(&out, &eight);
            for _ in 0..100 {
                synth.next_input(&input);
            }
            let mut last = synth.next_input(&input);
            let (mut fade_end, mut kernels_start) = (None, None);
            for k in 0..1000u32 {
                if k % interval == 0 {
                    synth.update(&out, &banks);
                }
                let now = synth.next_input(&input);
                let h = synth.harmonics();
                if h.fading == 0 {
                    fade_end.get_or_insert(k);
                }
                if h.kernels.kernel_count == 0 {
                    assert!(
                        (i64::from(now) - i64::from(last)).abs() <= bound,
                        "interval {interval} tick {k}: {last} -> {now}"
                    );
                } else {
                    // Only once the old harmonics are gone (silent, not visited).
                    assert_eq!((h.fading, h.term_count), (0, 2), "interval {interval} tick {k}");
                    assert!(h.ramps.iter().all(|r| r.amp_pm == 0), "interval {interval} tick {k}");
                    kernels_start.get_or_insert(k);
                }
                last = now;
            }
            // The fade ends on the 80th tick after the switch, the banks start with the first
            // update after it.
            assert_eq!(fade_end, Some(79), "interval {interval}");
            assert_eq!(kernels_start, Some(79_u32.div_ceil(interval) * interval), "interval {interval}");
            assert_eq!(synth.harmonics().kernels.kernel_count, 2);
        }
    }

    #[test]
    fn a_kept_kernel_term_runs_on_through_a_switch_and_a_new_order_waits_for_the_old_one() {
        let bank = TickTerm::Laguerre {
            input: TermInput::VelocitySign { smooth_nm_per_4_ticks: 300 },
            pole_q30: 998_579_896,
            gains_pm: [90_000, -40_000, 20_000, 0, 0, 0, 0, 0],
        };
        let drift = TickTerm::Drift { offset_pm: 200_000, decay_pm: -300_000, tau_ticks: 5000 };
        let harmonic = |order, amp_reg| TickTerm::Harmonic { order, amp_reg, phase_reg: amp_reg + 1 };
        let out = harmonic_output();
        let (before, after) = ([bank, harmonic(2, 2), harmonic(3, 6)], [bank, harmonic(5, 2), drift]);
        let mut synth = Synth::new(80);
        // The bank alone, never switched: the kept bank's state must stay the same as its.
        let mut alone = Synth::new(80);
        synth.update(&out, &before);
        alone.update(&out, &[bank]);
        let mut pos = 0i32;
        let mut tick = |synth: &mut Synth, alone: &mut Synth, k: u32| {
            pos = pos.wrapping_add(((k * 37) % 301) as i32 - 150);
            let input =
                TickInput { cmd_phase_turns: k.wrapping_mul(0x0147_ae14), cmd_pos_nm: pos, ..TickInput::default() };
            synth.next_input(&input);
            alone.next_input(&input);
        };
        for k in 0..200 {
            tick(&mut synth, &mut alone, k);
        }
        for k in 0..300u32 {
            if k % 48 == 0 {
                synth.update(&out, &after);
            }
            tick(&mut synth, &mut alone, 200 + k);
            assert_eq!(synth.slot(0).state, alone.slot(0).state, "tick {k}");
            let h = synth.harmonics();
            let (slot_1, slot_2) = (h.ramps[1], h.ramps[2]);
            if k < 79 {
                // Both old harmonics fade (the second order's slot now a drift's); the bank runs.
                assert_eq!((h.fading, h.kernels.kernel_mask, h.orders[1]), (0b110, 0b1, 2), "tick {k}");
                assert!(slot_1.amp_pm != 0 && slot_2.amp_pm != 0, "tick {k}");
            } else if k < 96 {
                // Gone; the fifth order and the drift wait for the next update.
                assert_eq!((h.fading, h.kernels.kernel_mask, h.term_count), (0, 0b1, 3), "tick {k}");
                assert_eq!((slot_1.amp_pm, slot_2.amp_pm), (0, 0), "tick {k}");
            } else {
                // The update at tick 96 starts both: the fifth order ramps in from silence.
                assert_eq!((h.orders[1], h.kernels.kernel_mask), (5, 0b101), "tick {k}");
                if k < 96 + 79 {
                    let target = slot_1.amp_target_pm;
                    assert!(
                        slot_1.amp_pm.abs() <= target.abs() && slot_1.amp_pm != target,
                        "tick {k}: {} of {target}",
                        slot_1.amp_pm
                    );
                }
            }
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
