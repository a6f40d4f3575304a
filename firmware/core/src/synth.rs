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
    let clamped = if value_um > LIMIT_UM {
        LIMIT_UM
    } else if value_um < -LIMIT_UM {
        -LIMIT_UM
    } else {
        value_um
    };
    // `as` maps NaN to 0.
    (clamped * 1.0e6) as i32
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
    const IDLE: Self = Self { amp_pm: 0, phase_turns: 0, amp_target_pm: 0, phase_target_turns: 0, amp_step_pm: 0, phase_step_turns: 0 };

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

    /// The last step: exactly onto the target.
    #[inline]
    fn finish(&mut self) {
        self.amp_pm = self.amp_target_pm;
        self.phase_turns = self.phase_target_turns;
    }
}

/// Kernel state of a term other than a harmonic.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct KernelState {
    /// Laguerre stage outputs, Q24.
    stages: [i64; LAGUERRE_STAGES],
    /// Command positions of the last 4 ticks (velocity), newest first.
    pos_hist: [i32; 4],
    /// Dahl state, Q30.
    dahl_q30: i32,
    /// The decaying part of a drift, picometres (Q8).
    drift_q8: i64,
    /// `exp(-DRIFT_STEP_TICKS / tau)`, Q23 (so the product stays within 64 bits).
    drift_step_q23: i64,
    /// `sqrt(1 - a^2)` of a Laguerre bank, Q30.
    g_q30: i64,
    /// Whether the command history is valid.
    primed: bool,
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

/// One tick of a kernel term: its contribution in picometres.
#[inline]
fn kernel_pm(term: &TickTerm, st: &mut KernelState, input: &TickInput, ticks: u64) -> i64 {
    match *term {
        TickTerm::Harmonic { .. } => 0,
        TickTerm::Drift { offset_pm, .. } => {
            if ticks % u64::from(DRIFT_STEP_TICKS) == 0 && ticks != 0 {
                st.drift_q8 = (st.drift_q8 * st.drift_step_q23) >> 23;
            }
            offset_pm as i64 + (st.drift_q8 >> 8)
        }
        TickTerm::AxisCoupling { x_gain_pm_per_mps2, spindle_amp_pm, spindle_phase_turns } => {
            let x = (x_gain_pm_per_mps2 as i64 * input.x_acc_um_per_s2 as i64) / 1_000_000;
            x + harmonic_pm(spindle_amp_pm, input.spindle_turns.wrapping_add(spindle_phase_turns)) as i64
        }
        TickTerm::Laguerre { input: kind, pole_q30, gains_pm } => {
            if !st.primed {
                st.pos_hist = [input.cmd_pos_nm; 4];
                st.primed = true;
            }
            let u_q30: i64 = match kind {
                TermInput::VelocitySign { smooth_nm_per_4_ticks } => {
                    let dv = input.cmd_pos_nm as i64 - st.pos_hist[3] as i64;
                    ((dv << 30) / smooth_nm_per_4_ticks.max(1) as i64).clamp(-(1 << 30), 1 << 30)
                }
                TermInput::Dahl { inv_x0_q30 } => {
                    let dx = input.cmd_pos_nm as i64 - st.pos_hist[0] as i64;
                    let u = st.dahl_q30 as i64;
                    let sign = dx.signum();
                    // du = dx / x0 * (1 - u sgn(dx)), kept within [-1, 1].
                    let du = ((dx * inv_x0_q30 as i64).clamp(-(1 << 31), 1 << 31) * ((1 << 30) - sign * u)) >> 30;
                    let next = (u + du).clamp(-(1 << 30), 1 << 30);
                    st.dahl_q30 = next as i32;
                    next
                }
                TermInput::PositionSine { turns_per_nm, phase_turns } => {
                    let phase = (input.cmd_pos_nm as u32).wrapping_mul(turns_per_nm).wrapping_add(phase_turns);
                    (sin_q31(phase) as i64) >> 1
                }
            };
            st.pos_hist = [input.cmd_pos_nm, st.pos_hist[0], st.pos_hist[1], st.pos_hist[2]];
            laguerre_step(&mut st.stages, pole_q30 as i64, st.g_q30, u_q30, &gains_pm)
        }
    }
}

/// Advances a Laguerre bank by one tick on input `u` (Q30); returns the weighted output, pm.
/// Stage 0: `y0 = a y0' + sqrt(1 - a^2) u`; stage i: `yi = a yi' + y(i-1)' - a y(i-1)`.
#[inline]
fn laguerre_step(stages: &mut [i64; LAGUERRE_STAGES], a_q30: i64, g_q30: i64, u_q30: i64, gains_pm: &[i32; LAGUERRE_STAGES]) -> i64 {
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
    pub const SILENT: Self = Self { amp_pm: 0, phase_turns: 0, term_amp_pm: [0; MAX_TERMS], term_phase_turns: [0; MAX_TERMS], term_orders: [0; MAX_TERMS], kernel_mask: 0 };

    /// The targets of `output` for the tick terms `terms` (kernel terms have none).
    pub fn new(output: &ModelOutput, terms: &[TickTerm]) -> Self {
        let mut targets = Self { amp_pm: um_to_pm(output.amp_um()), phase_turns: deg_to_turns(output.phase_deg()), ..Self::SILENT };
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
}

impl Harmonics {
    const IDLE: Self = Self { fundamental: Ramp::IDLE, ramps: [Ramp::IDLE; MAX_TERMS], orders: [0; MAX_TERMS], term_count: 0, idle_from: 0 };

    /// What the ticks of a running ramp end in: every visited value on its target.
    fn settle(&mut self) {
        self.fundamental.finish();
        let count = self.term_count.min(MAX_TERMS);
        self.ramps[..count].iter_mut().for_each(Ramp::finish);
    }

    /// Starts the term slots' ramps to `targets` for `count` terms over `ramp` ticks;
    /// `old_kernel_mask` marks the slots that held kernel terms. Returns the slots whose
    /// kernel term must go.
    fn retarget_terms(&mut self, targets: &SynthTargets, count: usize, old_kernel_mask: u32, ramp: u32) -> u32 {
        let mut cleared = 0u32;
        // Last slot holding a harmonic that is or will be audible.
        let mut audible_to = 0;
        // The harmonic slots, by their bits (masked to MAX_TERMS = 8 slots, so no index
        // can be out of bounds).
        let mut harmonics = !targets.kernel_mask & ((1u32 << count) - 1) & 0xff;
        while harmonics != 0 {
            let i = (harmonics.trailing_zeros() & 7) as usize;
            harmonics &= harmonics - 1;
            let order = targets.term_orders[i];
            let phase = targets.term_phase_turns[i];
            if self.orders[i] != order || old_kernel_mask & (1 << i) != 0 {
                // A new kind of term starts from silence at its own phase. (Its kernel state
                // is not read while it is a harmonic, and is reset when it becomes a kernel.)
                self.orders[i] = order;
                self.ramps[i] = Ramp { phase_turns: phase, ..Ramp::IDLE };
                cleared |= 1 << i;
            }
            let slot = &mut self.ramps[i];
            slot.retarget(targets.term_amp_pm[i], phase, ramp);
            if order != 0 && (slot.amp_pm != 0 || slot.amp_target_pm != 0) {
                audible_to = i + 1;
            }
        }
        // Harmonics that disappear ramp out; kernel terms stop at once (they have no ramp).
        let mut idle_from = count;
        for i in count..self.idle_from.max(count) {
            cleared |= 1 << i;
            let slot = &mut self.ramps[i];
            let phase = slot.phase_turns;
            slot.retarget(0, phase, ramp);
            if slot.amp_pm != 0 {
                idle_from = i + 1;
                if self.orders[i] != 0 {
                    audible_to = i + 1;
                }
            }
        }
        self.idle_from = idle_from;
        self.term_count = audible_to.max(count);
        cleared
    }
}

/// What a prepared model update was computed from (see [`Synth::prepare`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Prepared {
    /// [`Synth`]`::generation` when it was prepared.
    generation: u32,
    /// The ramp length it used.
    ramp_ticks: u32,
}

/// The error synthesiser. See the [module docs](self).
///
/// Term slot `i` holds the `i`-th tick term of the program in force: a harmonic (its order
/// and ramp) or a kernel term (its kind and filter state; its ramp stays idle at zero, so
/// the harmonic loop may run over it and add exactly nothing).
#[derive(Clone, Debug, PartialEq)]
pub struct Synth {
    /// The live harmonics (`banks[live]`) and a prepared update (the other one).
    banks: [Harmonics; 2],
    /// Index of the live bank, 0 or 1.
    live: usize,
    /// The kernel term of each slot (`None`: an idle or harmonic slot).
    kernels: [Option<TickTerm>; MAX_TERMS],
    states: [KernelState; MAX_TERMS],
    /// Bit `i` set: slot `i` holds a kernel term.
    kernel_mask: u32,
    /// Ticks left on the ramps (all of them were retargeted together).
    ramp_left: u32,
    /// Model updates applied (wrapping): a prepared update is valid for one generation.
    generation: u32,
    /// The update prepared in the other bank, if any.
    prepared: Option<Prepared>,
    /// Machine time: ticks since the synthesiser started (or [`Synth::set_time_ticks`]).
    ticks: u64,
    /// Ticks over which a model update moves amplitude and phase to their new values.
    pub ramp_ticks: u32,
}

impl Eq for Synth {}

impl Synth {
    /// A silent synthesiser (amplitude zero) that ramps model updates over `ramp_ticks`.
    pub const fn new(ramp_ticks: u32) -> Self {
        const IDLE_STATE: KernelState = KernelState {
            stages: [0; LAGUERRE_STAGES],
            pos_hist: [0; 4],
            dahl_q30: 0,
            drift_q8: 0,
            drift_step_q23: 0,
            g_q30: 0,
            primed: false,
        };
        Self {
            banks: [Harmonics::IDLE; 2],
            live: 0,
            kernels: [None; MAX_TERMS],
            states: [IDLE_STATE; MAX_TERMS],
            kernel_mask: 0,
            ramp_left: 0,
            generation: 0,
            prepared: None,
            ticks: 0,
            ramp_ticks,
        }
    }

    #[inline(always)]
    fn harmonics(&self) -> &Harmonics {
        &self.banks[self.live & 1]
    }

    #[inline(always)]
    fn harmonics_mut(&mut self) -> &mut Harmonics {
        &mut self.banks[self.live & 1]
    }

    /// Takes a new model output: the fundamental from its amplitude and phase registers and
    /// the tick terms' coefficients from theirs. Terms that disappear ramp to zero first.
    /// The same as [`Synth::apply`] of [`SynthTargets::new`].
    pub fn update(&mut self, output: &ModelOutput, terms: &[TickTerm]) {
        self.apply(&SynthTargets::new(output, terms), terms);
    }

    /// Takes a new model output, converted beforehand ([`SynthTargets::new`] of the same
    /// `terms`): starts the ramps to it.
    pub fn apply(&mut self, targets: &SynthTargets, terms: &[TickTerm]) {
        let ramp = self.ramp_ticks;
        let count = terms.len().min(MAX_TERMS);
        self.harmonics_mut().fundamental.retarget(targets.amp_pm, targets.phase_turns, ramp);
        if targets.kernel_mask != 0 {
            self.apply_kernels(targets.kernel_mask, &terms[..count]);
        }
        let old_kernel_mask = self.kernel_mask;
        let cleared = self.harmonics_mut().retarget_terms(targets, count, old_kernel_mask, ramp);
        for (i, kernel) in self.kernels.iter_mut().enumerate() {
            if cleared & (1 << i) != 0 {
                *kernel = None;
            }
        }
        self.ramp_left = ramp;
        self.kernel_mask = targets.kernel_mask;
        self.generation = self.generation.wrapping_add(1);
        self.prepared = None;
    }

    /// Prepares the model update `targets` of `terms` (as [`Synth::apply_prepared`] will
    /// apply it) on the state the running ramps end in, so that the tick applying it has
    /// little to do. Updates with kernel terms, before or after, are not prepared.
    pub fn prepare(&mut self, targets: &SynthTargets, terms: &[TickTerm]) {
        self.prepared = None;
        if self.kernel_mask != 0 || targets.kernel_mask != 0 || self.kernels.iter().any(Option::is_some) {
            return;
        }
        let ramp = self.ramp_ticks;
        let count = terms.len().min(MAX_TERMS);
        let live = self.live & 1;
        let mut next = self.banks[live];
        if self.ramp_left > 0 {
            next.settle();
        }
        next.fundamental.retarget(targets.amp_pm, targets.phase_turns, ramp);
        // No kernel terms anywhere: no kernel to clear.
        next.retarget_terms(targets, count, 0, ramp);
        self.banks[live ^ 1] = next;
        self.prepared = Some(Prepared { generation: self.generation, ramp_ticks: ramp });
    }

    /// Applies a model update: the one [`Synth::prepare`]d, by switching banks, when nothing
    /// changed since and the ramps have settled (the state it was prepared on); otherwise as
    /// [`Synth::apply`]. Either way the result is that of [`Synth::apply`], bit for bit,
    /// provided `targets` and `terms` are those last prepared (when something else is to be
    /// applied, call [`Synth::apply`]).
    #[inline]
    pub fn apply_prepared(&mut self, targets: &SynthTargets, terms: &[TickTerm]) {
        let ready = Some(Prepared { generation: self.generation, ramp_ticks: self.ramp_ticks });
        if self.prepared == ready && self.ramp_left == 0 {
            self.live ^= 1;
            self.ramp_left = self.ramp_ticks;
            self.generation = self.generation.wrapping_add(1);
            self.prepared = None;
        } else {
            self.apply(targets, terms);
        }
    }

    /// The kernel terms of an update (bits of `mask`): a changed one restarts from rest, an
    /// unchanged one keeps its state (kernel terms carry their own coefficients).
    #[inline(never)]
    fn apply_kernels(&mut self, mask: u32, terms: &[TickTerm]) {
        let ticks = self.ticks;
        for (i, term) in terms.iter().enumerate() {
            if mask & (1 << i) != 0 && self.kernels[i] != Some(*term) {
                self.start_kernel(i, term, ticks);
            }
        }
    }

    /// Puts kernel term `term` into slot `i`, from rest. Out of line: its 64-bit float set-up
    /// (software arithmetic on a Cortex-M4F) must not be hoisted into every model update.
    #[cold]
    #[inline(never)]
    fn start_kernel(&mut self, i: usize, term: &TickTerm, ticks: u64) {
        let harmonics = self.harmonics_mut();
        harmonics.orders[i] = 0;
        harmonics.ramps[i] = Ramp::IDLE;
        self.kernels[i] = Some(*term);
        let state = &mut self.states[i];
        *state = KernelState::default();
        match *term {
            TickTerm::Drift { decay_pm, tau_ticks, .. } => drift_at(state, decay_pm, tau_ticks, ticks),
            TickTerm::Laguerre { pole_q30, .. } => {
                let one = 1i64 << 30;
                let a = i64::from(pole_q30);
                state.g_q30 = isqrt_u64(((one - a) * (one + a)) as u64) as i64;
            }
            _ => {}
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
        let count = self.banks[live].term_count.min(MAX_TERMS);
        // Kernel slots have an idle ramp (amplitude 0, steps 0) and add 0 in the harmonic sum.
        let mut total = if self.ramp_left > 1 {
            // Ramping: step and synthesise in one pass.
            self.ramp_left -= 1;
            let h = &mut self.banks[live];
            h.fundamental.step();
            let mut total = ramp_harmonic_pm(h.fundamental.amp_pm, cmd_phase_turns.wrapping_add(h.fundamental.phase_turns)) as i64;
            for (ramp, &order) in h.ramps[..count].iter_mut().zip(&h.orders[..count]) {
                ramp.step();
                let phase = cmd_phase_turns.wrapping_mul(order).wrapping_add(ramp.phase_turns);
                total += ramp_harmonic_pm(ramp.amp_pm, phase) as i64;
            }
            total
        } else {
            if self.ramp_left == 1 {
                self.finish_ramps();
            }
            let h = &self.banks[live];
            let mut total = ramp_harmonic_pm(h.fundamental.amp_pm, cmd_phase_turns.wrapping_add(h.fundamental.phase_turns)) as i64;
            for (ramp, &order) in h.ramps[..count].iter().zip(&h.orders[..count]) {
                let phase = cmd_phase_turns.wrapping_mul(order).wrapping_add(ramp.phase_turns);
                total += ramp_harmonic_pm(ramp.amp_pm, phase) as i64;
            }
            total
        };
        let ticks = self.ticks;
        if self.kernel_mask != 0 {
            total = total.wrapping_add(self.kernels_pm(count, input, ticks));
        }
        self.ticks = ticks.wrapping_add(1);
        total.clamp(i32::MIN as i64, i32::MAX as i64) as i32
    }

    /// The ramps' last tick: every value onto its target.
    #[inline(never)]
    fn finish_ramps(&mut self) {
        self.ramp_left = 0;
        self.harmonics_mut().settle();
    }

    /// The kernel terms' sum for this tick, picometres.
    #[inline(never)]
    fn kernels_pm(&mut self, count: usize, input: &TickInput, ticks: u64) -> i64 {
        let mut total = 0i64;
        for (kernel, state) in self.kernels[..count].iter().zip(self.states[..count].iter_mut()) {
            if let Some(kernel) = kernel {
                total = total.wrapping_add(kernel_pm(kernel, state, input, ticks));
            }
        }
        total
    }

    /// Sets the machine time (ticks since the machine started), e.g. to replay a measurement
    /// group that started at a known machine time; drift terms jump to their value then.
    pub fn set_time_ticks(&mut self, ticks: u64) {
        self.ticks = ticks;
        for (kernel, state) in self.kernels.iter().zip(self.states.iter_mut()) {
            if let Some(TickTerm::Drift { decay_pm, tau_ticks, .. }) = *kernel {
                drift_at(state, decay_pm, tau_ticks, ticks);
            }
        }
    }

    /// Restarts the kernel terms' filter states (a new motion from rest), keeping the model.
    pub fn restart_kernels(&mut self) {
        for (kernel, state) in self.kernels.iter().zip(self.states.iter_mut()) {
            if kernel.is_some() {
                let keep = *state;
                *state = KernelState { drift_q8: keep.drift_q8, drift_step_q23: keep.drift_step_q23, g_q30: keep.g_q30, ..KernelState::default() };
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
        let mut values = std::vec![0.0f32, -0.0, 1e-30, -1e-30, 359.99997, -359.99997, 180.0, -180.0, 7.7e11, -7.7e11, 3e12, f32::MAX, f32::MIN];
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
        for round in 0..40 {
            let ramp_ticks = [0, 1, 7, 80][round % 4];
            let mut plain = Synth::new(ramp_ticks);
            let mut prepared = Synth::new(ramp_ticks);
            let mut theta = 0u32;
            for update in 0..30 {
                let term_count = (rng(&mut seed) % 9) as usize;
                let mut out = output((rng(&mut seed) % 5000) as f32 * 1e-3, (rng(&mut seed) % 720) as f32 - 360.0);
                let mut terms = std::vec::Vec::new();
                for i in 0..term_count {
                    let amp_reg = 2 + 2 * (i % 3) as u8;
                    out.registers[amp_reg as usize] = (rng(&mut seed) % 3000) as f32 * 1e-3;
                    out.registers[amp_reg as usize + 1] = (rng(&mut seed) % 720) as f32 - 360.0;
                    // Orders change now and then: slots are recreated.
                    let order = 2 + (rng(&mut seed) % 3) as u8;
                    terms.push(TickTerm::Harmonic { order, amp_reg, phase_reg: amp_reg + 1 });
                }
                let targets = if update % 7 == 6 { SynthTargets::SILENT } else { SynthTargets::new(&out, &terms) };
                let terms: &[TickTerm] = if update % 7 == 6 { &[] } else { &terms };
                // Prepared some ticks before its tick, sometimes while the ramps still run,
                // sometimes with a ramp longer than the wait (the fallback).
                let wait = rng(&mut seed) % 120;
                prepared.prepare(&targets, terms);
                for _ in 0..wait {
                    theta = theta.wrapping_add(0x0147_ae14);
                    assert_eq!(plain.next(theta), prepared.next(theta));
                }
                plain.apply(&targets, terms);
                prepared.apply_prepared(&targets, terms);
                for _ in 0..(rng(&mut seed) % 100) {
                    theta = theta.wrapping_add(0x0147_ae14);
                    assert_eq!(plain.next(theta), prepared.next(theta), "round {round} update {update}");
                }
                assert_eq!(plain.harmonics(), prepared.harmonics());
                assert_eq!(plain.ramp_left, prepared.ramp_left);
            }
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
        let term = TickTerm::AxisCoupling { x_gain_pm_per_mps2: 800_000, spindle_amp_pm: 50_000, spindle_phase_turns: 0 };
        synth.update(&ModelOutput::default(), &[term]);
        // 0.25 m/s^2 -> 0.2 um; spindle at a quarter turn -> +50 nm.
        let out = synth.next_input(&TickInput { x_acc_um_per_s2: 250_000, spindle_turns: 1 << 30, ..TickInput::default() });
        assert!((out - 250_000).abs() < 20, "{out}");
    }

    #[test]
    fn laguerre_term_is_linear_and_starts_from_rest() {
        let run = |gain: i32| {
            let mut synth = Synth::new(0);
            let mut gains = [0i32; LAGUERRE_STAGES];
            gains[0] = gain;
            gains[3] = -gain / 2;
            let term = TickTerm::Laguerre { input: TermInput::VelocitySign { smooth_nm_per_4_ticks: 8 }, pole_q30: (0.93 * (1u64 << 30) as f64) as i32, gains_pm: gains };
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
