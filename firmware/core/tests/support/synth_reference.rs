//! A plain f64 reference of the servo tick's synthesis and DAC stage, a test oracle for
//! `tick_reference`, written from the definitions (the docs of `sts_twin_core::synth`,
//! `program::TickTerm` and `feedforward`) rather than from the fixed-point code: real numbers
//! for amplitudes, phases, filter states and codes, `f64::sin` and `f64::exp`, and each
//! formula as it is stated.
//!
//! # What a tick computes
//!
//! With the command phase `theta` (turns), the command position `x` (nm), the X acceleration
//! and the spindle angle of the tick, and the machine time `t` (ticks):
//!
//! - the fundamental `A sin(2 pi (theta + phi))` and each harmonic slot's
//!   `A_i sin(2 pi (n_i theta + phi_i))`;
//! - each kernel term: a drift `offset + decay exp(-t_s / tau)` with `t_s` the machine time at
//!   the last whole step of 256 ticks (held in between); an axis coupling
//!   `gain x_acc / 10^6 + A sin(2 pi (spindle + phi))`; a Laguerre bank with pole `a` on an
//!   input `u`: `y_0 = a y_0' + sqrt(1 - a^2) u`, `y_i = a y_i' + y_(i-1)' - a y_(i-1)` (a prime
//!   is the previous tick's value), output `sum w_i y_i`, where `u` is the command velocity over
//!   4 ticks over the smoothing velocity clamped to [-1, 1], the Dahl state
//!   (`du = dx / x0 (1 - u sgn dx)` with the rate `|dx| / x0` at most 2, `u` within [-1, 1]) or
//!   `sin(2 pi (x / period + phi))`;
//! - the sum, clamped to `i32` picometres: the prediction `DE`.
//!
//! A model update moves every amplitude and phase linearly to its new value over the ramp's
//! `n` ticks (the phase the shorter way round), the first step on the update's tick, the
//! target on the `n`-th. When the terms change, a harmonic that goes ramps out over the same
//! ramp, counted from the change, lands on zero and is dropped; later updates leave it be
//! (unless their ramp would end first: then every fading harmonic ramps out afresh with
//! them), and the update's other ramps hold for the fade's last tick. The terms that take a
//! fading harmonic's slot, and new kernel terms, wait for the first update after the fade; a
//! kernel term that stays in its slot runs on, one that goes stops, a new one starts from
//! rest (its first tick sees no earlier motion).
//!
//! The DAC stage: the gain `g` moves by `1/n` per tick towards 1 (enabled, inputs trusted, a
//! model in force) or 0; the target is `-DE g / (K_dv V_code) - offset / V_code` codes
//! (`V_code` the volts per code, full scale over 32767), clamped to the DAC's range; the output
//! moves to it by at most the slew limit per tick, and the code is the output rounded.
//!
//! # Inputs shared with the core
//!
//! The reference takes what the tick is given as the tick's arithmetic receives it, so that it
//! checks the per-tick arithmetic and not conversions tested elsewhere: model outputs as the
//! synthesiser's targets (amplitude in whole picometres and phase in 2^-32 turns, by the core's
//! `um_to_pm` and `deg_to_turns`, which `math`'s tests hold to f64; the way a phase ramps when
//! the change is exactly half a turn, common with whole degrees, depends on its last bit), a
//! pole at its Q30 value, and the gain's step at the stage's resolution of 2^-16 (`1/n`
//! rounded down to it: a ramp of 400 ticks takes 403, a choice of the stage, not an error of
//! a tick).
//!
//! # Bounds
//!
//! Every value comes with a bound on its distance from the core's, derived from the core's
//! fixed-point formats, so that the check is exact in what it allows:
//!
//! - a ramp steps by its change over `n` truncated to whole picometres (phases to whole 2^-32
//!   turns), less than a unit short per step, and lands exactly on its target: after `s` steps
//!   from a value the core held `e` off, it is at most `e (1 - s/n) + s` units off;
//! - a table sine is within 4.8e-6 of `sin` (1024 entries, linear interpolation: `(2 pi /
//!   1024)^2 / 8` = 4.71e-6, and the table's rounding; `math`'s docs), and the product with an
//!   amplitude is floored: `|A| 4.8e-6 + 1` pm per sine, with the amplitude's and phase's
//!   errors on top;
//! - a drift's decaying part is held in Q8 picometres and multiplied every 256 ticks by
//!   `exp(-256 / tau)` in Q23 (floored): after `m` steps the factor's truncation has cost at
//!   most `|decay| m r^(m-1) 2^-23 <= |decay| 2^-23 tau / 256` pm (`r = exp(-256 / tau)`),
//!   the floors at most `1 / (256 (1 - r)) <= (1 + tau / 256) / 256` pm, the start's
//!   truncation and the output's floor 2 pm more;
//! - the coupling's X gain is held in Q20 picometres per um/s^2: `|x_acc| 2^-21 + 1` pm
//!   (`synth::kernel`'s test of it);
//! - a Laguerre stage is held in Q24 and floored once per tick (stage 0 also takes
//!   `sqrt(1 - a^2)` in Q30, floored, and the input's error: the velocity's quotient is
//!   truncated, 2^-30; the Dahl state is floored to Q30 each tick and carried on with the
//!   factor `|1 - rate|`; the position sine is the table's). An error injected into stage `m`
//!   reaches stage `i` through the bank's own filters, so stage `i` is off by at most
//!   `sum_m N_(i-m) D_m`, where `N_j` is the l1 norm of the impulse response from stage 0 to
//!   stage `j` (computed here for the pole) and `D_m` the most injected per tick; the output,
//!   floored, by `sum_i |w_i| (that) + 1` pm;
//! - the prediction by the sum of its parts' bounds; beyond `i32`'s range by more than that,
//!   the core's sum is clamped as the reference's is, and they agree exactly;
//! - the DAC stage's scale is `K_dv V_code` with `V_code` in f32 (2^-24) and its inverse in
//!   Q32, the target's three floors and the offset's truncation are 2^-16 codes each, and the
//!   slew limit is held to 2^-16 code: the output is off by at most what the target is, or
//!   what it was plus the slew limit's rounding while it slews; the code, rounded, by 0.5 more.
//!   Whether the target was clamped and whether the output slewed are told where the values
//!   lie beyond their bounds from the limits.
//!
//! A phase change within its bound of half a turn would leave the way round to bits the
//! reference does not hold: the reference refuses it rather than guess.
//!
//! Not covered: the servo-axis twin and the resonance (f32 models stepped in the tick: no
//! simpler form to compare with here; `axis`'s and `resonance`'s own tests check their
//! responses) and the axis twin's harmonic slots; none is in the golden runs. The reference
//! refuses them.
use std::collections::HashMap;
use std::f64::consts::TAU;
use std::sync::{Mutex, OnceLock};

use sts_twin_core::feedforward::FeedforwardParams;
use sts_twin_core::math::{deg_to_turns, um_to_pm};
use sts_twin_core::program::{ModelOutput, TermInput, TickTerm, LAGUERRE_STAGES, MAX_TERMS};
use sts_twin_core::synth::{TickInput, DRIFT_STEP_TICKS};

/// 2^32: a full turn of a phase in `u32` turns.
const TURN: f64 = 4_294_967_296.0;

/// Largest distance of the core's table sine from `sin` (see the module docs).
const SINE_ERROR: f64 = 4.8e-6;

/// A value of the reference and a bound on its distance from the core's.
#[derive(Clone, Copy, Debug)]
pub struct Bounded {
    pub value: f64,
    pub bound: f64,
}

impl Bounded {
    /// Whether the core's `value` lies within the bound.
    pub fn admits(&self, value: f64) -> bool {
        (value - self.value).abs() <= self.bound
    }
}

/// `x` of a phase change, turns, taken the shorter way round: within [-1/2, 1/2), half a turn
/// going back (as the core's signed 32-bit difference does).
fn shorter_way(x: f64) -> f64 {
    x - (x + 0.5).floor()
}

/// A model output's amplitude register as the synthesiser receives it, picometres.
fn amp_pm(value_um: f32) -> f64 {
    f64::from(um_to_pm(value_um))
}

/// A model output's phase register as the synthesiser receives it, turns.
fn phase_turns(value_deg: f32) -> f64 {
    f64::from(deg_to_turns(value_deg)) / TURN
}

/// An amplitude and a phase moving linearly to their targets (see the module docs).
#[derive(Clone, Copy, Debug, Default)]
struct Ramp {
    /// Where the ramp started and where it goes: picometres and turns.
    amp_from: f64,
    amp_to: f64,
    phase_from: f64,
    phase_to: f64,
    /// The phase's change, the shorter way round.
    phase_by: f64,
    /// Ramp length and steps taken.
    len: u32,
    steps: u32,
    /// The core's distance at the start, at most: picometres and 2^-32 turns.
    amp_err_from: f64,
    phase_err_from: f64,
}

impl Ramp {
    /// Silent at phase `phase`, settled.
    fn silent(phase: f64) -> Self {
        Self { phase_from: phase, phase_to: phase, ..Self::default() }
    }

    /// The part of the way covered (1 once settled).
    fn fraction(&self) -> f64 {
        if self.steps >= self.len {
            1.0
        } else {
            f64::from(self.steps) / f64::from(self.len)
        }
    }

    fn amp(&self) -> f64 {
        match self.fraction() {
            1.0 => self.amp_to,
            f => self.amp_from + (self.amp_to - self.amp_from) * f,
        }
    }

    fn phase(&self) -> f64 {
        match self.fraction() {
            1.0 => self.phase_to,
            f => self.phase_from + self.phase_by * f,
        }
    }

    /// Bounds on the core's distance now: amplitude (pm) and phase (2^-32 turns).
    fn errors(&self) -> (f64, f64) {
        match self.fraction() {
            1.0 => (0.0, 0.0),
            f => {
                let steps = f64::from(self.steps);
                (self.amp_err_from * (1.0 - f) + steps, self.phase_err_from * (1.0 - f) + steps)
            }
        }
    }

    /// Sounds now or by its end.
    fn sounds(&self) -> bool {
        self.amp() != 0.0 || self.amp_to != 0.0
    }

    /// Starts the way to `amp` and `phase` over `len` ticks from where it is.
    fn retarget(&mut self, amp: f64, phase: f64, len: u32) {
        let (amp_from, phase_from) = (self.amp(), self.phase());
        let (amp_err_from, phase_err_from) = self.errors();
        let phase_by = shorter_way(phase - phase_from);
        // Half a turn either way: the core's way depends on bits the reference does not hold.
        assert!(
            phase_err_from == 0.0 || (phase_by.abs() - 0.5).abs() * TURN > phase_err_from,
            "a phase change of half a turn within the phase's bound: the way round is ambiguous"
        );
        *self = Self {
            amp_from,
            amp_to: amp,
            phase_from,
            phase_to: phase,
            phase_by,
            len,
            steps: 0,
            amp_err_from,
            phase_err_from,
        };
    }

    /// One tick's step.
    fn step(&mut self) {
        self.steps = (self.steps + 1).min(self.len);
    }

    /// On the target.
    fn settle(&mut self) {
        self.steps = self.len;
    }

    /// Its sine at `order` times the command phase `theta`, picometres, with its bound.
    fn harmonic(&self, order: u32, theta: f64) -> Bounded {
        let amp = self.amp();
        let (amp_err, phase_err) = self.errors();
        if amp == 0.0 && amp_err == 0.0 {
            // Silent in the core too.
            return Bounded { value: 0.0, bound: 0.0 };
        }
        let angle = (f64::from(order) * theta + self.phase()).rem_euclid(1.0);
        Bounded {
            value: amp * (TAU * angle).sin(),
            bound: amp_err + amp.abs() * (SINE_ERROR + TAU * phase_err / TURN) + 1.0,
        }
    }
}

/// The l1 norms of the impulse responses from stage 0 of a Laguerre bank with pole
/// `pole_q30` to each stage (without the input's gain `sqrt(1 - a^2)`). The responses decay
/// as `a^k` times a polynomial of degree 7: after `60 / (1 - a)` ticks what is left is below
/// 1e-15 of the norm.
fn laguerre_norms(pole_q30: i32) -> [f64; LAGUERRE_STAGES] {
    static NORMS: OnceLock<Mutex<HashMap<i32, [f64; LAGUERRE_STAGES]>>> = OnceLock::new();
    let cache = NORMS.get_or_init(|| Mutex::new(HashMap::new()));
    if let Some(norms) = cache.lock().unwrap().get(&pole_q30) {
        return *norms;
    }
    let a = f64::from(pole_q30) / f64::from(1u32 << 30);
    let ticks = (60.0 / (1.0 - a)).ceil() as usize + 1000;
    let mut y = [0.0f64; LAGUERRE_STAGES];
    let mut norms = [0.0f64; LAGUERRE_STAGES];
    for k in 0..ticks {
        let old = y;
        y[0] = a * old[0] + if k == 0 { 1.0 } else { 0.0 };
        for i in 1..LAGUERRE_STAGES {
            y[i] = a * old[i] + old[i - 1] - a * y[i - 1];
        }
        for (norm, y) in norms.iter_mut().zip(&y) {
            *norm += y.abs();
        }
    }
    // The tail, and the sums' own rounding, with room to spare.
    let norms = norms.map(|n| n * (1.0 + 1e-9));
    cache.lock().unwrap().insert(pole_q30, norms);
    norms
}

/// A Laguerre bank's input, its filter and its bound.
#[derive(Clone, Debug)]
struct LaguerreBank {
    input: TermInput,
    a: f64,
    /// `sqrt(1 - a^2)`.
    g: f64,
    gains: [f64; LAGUERRE_STAGES],
    norms: [f64; LAGUERRE_STAGES],
    stages: [f64; LAGUERRE_STAGES],
    /// The command positions of the last 4 ticks, newest first (empty before the first tick).
    positions: Vec<i32>,
    /// The Dahl state and the bound on the core's distance from it.
    dahl: f64,
    dahl_err: f64,
    /// The largest bound on the input's distance from the core's so far.
    input_err: f64,
}

/// A Q24 stage's floor, per tick.
const STAGE_LSB: f64 = 1.0 / 16_777_216.0;
/// Q30: the input's and `sqrt(1 - a^2)`'s resolution.
const Q30_LSB: f64 = 1.0 / 1_073_741_824.0;

impl LaguerreBank {
    fn new(input: TermInput, pole_q30: i32, gains_pm: &[i32; LAGUERRE_STAGES]) -> Self {
        let a = f64::from(pole_q30) / f64::from(1u32 << 30);
        Self {
            input,
            a,
            g: (1.0 - a * a).sqrt(),
            gains: gains_pm.map(f64::from),
            norms: laguerre_norms(pole_q30),
            stages: [0.0; LAGUERRE_STAGES],
            positions: Vec::new(),
            dahl: 0.0,
            dahl_err: 0.0,
            input_err: 0.0,
        }
    }

    /// At rest (a new motion): no stage output, no earlier command.
    fn restart(&mut self) {
        self.stages = [0.0; LAGUERRE_STAGES];
        self.positions.clear();
        self.dahl = 0.0;
        self.dahl_err = 0.0;
    }

    /// The input this tick and the bound on the core's distance from it.
    fn input(&mut self, pos: i32) -> (f64, f64) {
        match self.input {
            TermInput::VelocitySign { smooth_nm_per_4_ticks } => {
                // Before the first tick the command stood where it first is.
                if self.positions.is_empty() {
                    self.positions = vec![pos; 4];
                }
                let velocity = f64::from(pos) - f64::from(self.positions[3]);
                self.positions.insert(0, pos);
                self.positions.truncate(4);
                let smooth = f64::from(smooth_nm_per_4_ticks.max(1));
                ((velocity / smooth).clamp(-1.0, 1.0), Q30_LSB)
            }
            TermInput::Dahl { inv_x0_q30 } => {
                let last = self.positions.first().copied().unwrap_or(pos);
                self.positions = vec![pos];
                let dx = f64::from(pos) - f64::from(last);
                if dx != 0.0 {
                    let rate = (dx.abs() * f64::from(inv_x0_q30) * Q30_LSB).min(2.0);
                    let sign = dx.signum();
                    let next = self.dahl + sign * rate * (1.0 - sign * self.dahl);
                    // The core's state, floored to Q30 each tick, carries its distance on
                    // with the step's factor `1 - rate`; beyond [-1, 1] both are clamped.
                    let err = (1.0 - rate).abs() * self.dahl_err + Q30_LSB;
                    self.dahl_err = if next.abs() >= 1.0 + err { 0.0 } else { err };
                    self.dahl = next.clamp(-1.0, 1.0);
                }
                (self.dahl, self.dahl_err)
            }
            TermInput::PositionSine { turns_per_nm, phase_turns } => {
                // The position's phase, exact modulo a turn.
                let turns = (i128::from(pos) * i128::from(turns_per_nm) + i128::from(phase_turns)).rem_euclid(1 << 32);
                ((TAU * turns as f64 / TURN).sin(), SINE_ERROR + Q30_LSB)
            }
        }
    }

    fn next(&mut self, pos: i32) -> Bounded {
        let (u, u_err) = self.input(pos);
        self.input_err = self.input_err.max(u_err);
        let old = self.stages;
        self.stages[0] = self.a * old[0] + self.g * u;
        for i in 1..LAGUERRE_STAGES {
            self.stages[i] = self.a * old[i] + old[i - 1] - self.a * self.stages[i - 1];
        }
        let value = self.gains.iter().zip(&self.stages).map(|(w, y)| w * y).sum();
        // Injected per tick: into stage 0 the input's error through the gain, the gain's
        // truncation to Q30 and the floors; into every other stage its floor.
        let injected = |m: usize| if m == 0 { self.g * self.input_err + 2.0 * Q30_LSB + STAGE_LSB } else { STAGE_LSB };
        let mut bound = 1.0;
        for i in 0..LAGUERRE_STAGES {
            let stage_err: f64 = (0..=i).map(|m| self.norms[i - m] * injected(m)).sum();
            bound += self.gains[i].abs() * stage_err;
        }
        Bounded { value, bound }
    }
}

/// A kernel term running in a slot.
#[derive(Clone, Debug)]
enum Kernel {
    Drift { offset: f64, decay: f64, tau: f64 },
    Coupling { x_gain: f64, spindle_amp: f64, spindle_phase: u32 },
    Laguerre(Box<LaguerreBank>),
}

impl Kernel {
    /// The term, started from rest.
    fn start(term: &TickTerm) -> Self {
        match *term {
            TickTerm::Drift { offset_pm, decay_pm, tau_ticks } => Self::Drift {
                offset: f64::from(offset_pm),
                decay: f64::from(decay_pm),
                tau: f64::from(tau_ticks.max(DRIFT_STEP_TICKS)),
            },
            TickTerm::AxisCoupling { x_gain_pm_per_mps2, spindle_amp_pm, spindle_phase_turns } => Self::Coupling {
                x_gain: f64::from(x_gain_pm_per_mps2),
                spindle_amp: f64::from(spindle_amp_pm),
                spindle_phase: spindle_phase_turns,
            },
            TickTerm::Laguerre { input, pole_q30, ref gains_pm } => {
                Self::Laguerre(Box::new(LaguerreBank::new(input, pole_q30, gains_pm)))
            }
            _ => panic!("the reference has no form of {term:?}"),
        }
    }

    fn restart(&mut self) {
        if let Self::Laguerre(bank) = self {
            bank.restart();
        }
    }

    /// This tick's value at machine time `ticks`.
    fn next(&mut self, input: &TickInput, ticks: u64) -> Bounded {
        match self {
            Self::Drift { offset, decay, tau } => {
                let step = f64::from(DRIFT_STEP_TICKS);
                let held = (ticks / u64::from(DRIFT_STEP_TICKS)) as f64 * step;
                Bounded {
                    value: *offset + *decay * (-held / *tau).exp(),
                    bound: decay.abs() * (*tau / step) / 8_388_608.0 + (1.0 + *tau / step) / 256.0 + 2.0,
                }
            }
            Self::Coupling { x_gain, spindle_amp, spindle_phase } => {
                let x_acc = f64::from(input.x_acc_um_per_s2);
                let angle = (f64::from(input.spindle_turns) + f64::from(*spindle_phase)) / TURN;
                Bounded {
                    value: *x_gain * x_acc / 1e6 + *spindle_amp * (TAU * angle).sin(),
                    bound: x_acc.abs() / 2_097_152.0 + 1.0 + spindle_amp.abs() * SINE_ERROR + 1.0,
                }
            }
            Self::Laguerre(bank) => bank.next(input.cmd_pos_nm),
        }
    }
}

/// A term slot: a harmonic (its order and ramp, fading or not) or a running kernel term.
#[derive(Clone, Debug, Default)]
struct Slot {
    /// The harmonic's order (0: none).
    order: u32,
    ramp: Ramp,
    /// Ramping out because the terms changed.
    fading: bool,
    kernel: Option<(TickTerm, Kernel)>,
}

impl Slot {
    fn sounds(&self) -> bool {
        self.order != 0 && self.ramp.sounds()
    }
}

/// The synthesiser in f64 (see the module docs).
#[derive(Clone, Debug)]
pub struct SynthReference {
    /// Ticks over which a model update ramps.
    pub ramp_ticks: u32,
    /// Machine time.
    ticks: u64,
    fundamental: Ramp,
    slots: [Slot; MAX_TERMS],
    /// Ticks to the ramps' next event: their end, or the end of a fade while other ramps run
    /// on; and those ramps' ticks after the fade's end.
    ramp_left: u32,
    rest_ticks: u32,
}

impl SynthReference {
    pub fn new(ramp_ticks: u32) -> Self {
        Self {
            ramp_ticks,
            ticks: 0,
            fundamental: Ramp::default(),
            slots: Default::default(),
            ramp_left: 0,
            rest_ticks: 0,
        }
    }

    /// A model update: `output`'s registers for `terms`.
    pub fn update(&mut self, output: &ModelOutput, terms: &[TickTerm]) {
        let n = self.ramp_ticks;
        let terms = &terms[..terms.len().min(MAX_TERMS)];
        let register = |r: u8| output.registers.get(usize::from(r)).copied().unwrap_or(0.0);
        self.fundamental.retarget(amp_pm(output.amp_um()), phase_turns(output.phase_deg()), n);
        let mut fade_starts = false;
        for (i, slot) in self.slots.iter_mut().enumerate() {
            match terms.get(i) {
                Some(&TickTerm::Harmonic { order, amp_reg, phase_reg }) => {
                    let (order, amp, phase) =
                        (u32::from(order), amp_pm(register(amp_reg)), phase_turns(register(phase_reg)));
                    if slot.order == order && slot.kernel.is_none() {
                        // The same harmonic, also one that was fading: on from where it is.
                        slot.fading = false;
                        slot.ramp.retarget(amp, phase, n);
                    } else if slot.sounds() {
                        // Another harmonic sounds here: it ramps out first, this one waits.
                        fade_starts |= !slot.fading;
                        slot.fading = true;
                    } else {
                        // From silence at its own phase (a kernel term here stops).
                        *slot = Slot { order, ramp: Ramp::silent(phase), fading: false, kernel: None };
                        slot.ramp.retarget(amp, phase, n);
                    }
                }
                Some(term @ (TickTerm::Axis(_) | TickTerm::AxisHarmonic { .. } | TickTerm::Resonance { .. })) => {
                    panic!("the reference has no form of {term:?}")
                }
                Some(term) => {
                    if slot.kernel.as_ref().is_some_and(|(running, _)| running == term) {
                        // Runs on.
                    } else if slot.sounds() {
                        fade_starts |= !slot.fading;
                        slot.fading = true;
                    } else {
                        slot.order = 0;
                        slot.ramp = Ramp::default();
                        slot.fading = false;
                    }
                }
                None if slot.fading => {}
                None if slot.sounds() => {
                    // Beyond the terms: a harmonic ramps out.
                    fade_starts = true;
                    slot.fading = true;
                }
                None => {
                    let phase = slot.ramp.phase();
                    slot.ramp.retarget(0.0, phase, n);
                }
            }
        }
        let fading = self.slots.iter().any(|slot| slot.fading);
        if fade_starts || (fading && (n < self.ramp_left || self.ramp_left == 0)) {
            // Every fading harmonic ramps out from where it is, with the update's ramps.
            for slot in self.slots.iter_mut().filter(|slot| slot.fading) {
                let phase = slot.ramp.phase();
                slot.ramp.retarget(0.0, phase, n);
                if slot.ramp.amp() == 0.0 {
                    // At once: gone.
                    slot.fading = false;
                }
            }
            self.ramp_left = n;
            self.rest_ticks = 0;
        } else if fading {
            // The fade runs on to its end; the update's ramps go on after it.
            self.rest_ticks = n - self.ramp_left;
        } else {
            self.ramp_left = n;
            self.rest_ticks = 0;
        }
        // Kernel terms: those that stay run on, those that go stop, new ones start from rest
        // unless harmonics fade.
        let fading = self.slots.iter().any(|slot| slot.fading);
        for (i, slot) in self.slots.iter_mut().enumerate() {
            let term = terms.get(i).filter(|term| !matches!(term, TickTerm::Harmonic { .. }));
            match (term, &slot.kernel) {
                (Some(term), Some((running, _))) if running == term => {}
                (Some(term), _) if !fading => slot.kernel = Some((*term, Kernel::start(term))),
                _ => slot.kernel = None,
            }
        }
    }

    /// Sets the machine time.
    pub fn set_time_ticks(&mut self, ticks: u64) {
        self.ticks = ticks;
    }

    /// Every kernel term at rest (a new motion), the model kept.
    pub fn restart_kernels(&mut self) {
        for (_, kernel) in self.slots.iter_mut().filter_map(|slot| slot.kernel.as_mut()) {
            kernel.restart();
        }
    }

    /// The ramps' event: a fade's last tick (the fading harmonics land on zero and are
    /// dropped; the other ramps, held this tick, go on from the next) or their end.
    fn end_ramps(&mut self) {
        if self.slots.iter().any(|slot| slot.fading) {
            for slot in self.slots.iter_mut().filter(|slot| slot.fading) {
                slot.ramp = Ramp::silent(slot.ramp.phase());
                slot.fading = false;
            }
            if self.rest_ticks != 0 {
                self.ramp_left = self.rest_ticks + 1;
                return;
            }
        }
        self.fundamental.settle();
        for slot in &mut self.slots {
            slot.ramp.settle();
        }
        self.ramp_left = 0;
    }

    /// The prediction at this tick, picometres.
    pub fn next_input(&mut self, input: &TickInput) -> Bounded {
        let ramping = self.ramp_left > 1;
        if ramping {
            self.ramp_left -= 1;
            self.fundamental.step();
            for slot in &mut self.slots {
                slot.ramp.step();
            }
        } else if self.ramp_left == 1 {
            self.end_ramps();
        }
        let theta = f64::from(input.cmd_phase_turns) / TURN;
        let mut parts = vec![self.fundamental.harmonic(1, theta)];
        for slot in &mut self.slots {
            match &mut slot.kernel {
                Some((_, kernel)) => parts.push(kernel.next(input, self.ticks)),
                None if slot.order != 0 => parts.push(slot.ramp.harmonic(slot.order, theta)),
                None => {}
            }
        }
        self.ticks += 1;
        let value: f64 = parts.iter().map(|part| part.value).sum();
        let bound: f64 = parts.iter().map(|part| part.bound).sum();
        let (low, high) = (f64::from(i32::MIN), f64::from(i32::MAX));
        // Beyond the range by more than the bound, the core's sum is clamped too: exactly.
        let bound = if value - bound > high || value + bound < low { 0.0 } else { bound };
        Bounded { value: value.clamp(low, high), bound }
    }
}

/// One tick of the DAC stage: the code (unrounded) and, where the reference can tell within
/// its bounds, whether the target was clamped and whether the output slewed.
#[derive(Clone, Copy, Debug)]
pub struct DacTick {
    pub code: Bounded,
    pub saturated: Option<bool>,
    pub slewing: Option<bool>,
}

/// The DAC stage in f64 (see the module docs).
#[derive(Clone, Debug)]
pub struct DacReference {
    /// Picometres of correction per code.
    pm_per_code: f64,
    offset_codes: f64,
    slew_codes: f64,
    gain_step: f64,
    /// The core's relative error of the scale, and its errors of the offset and the slew
    /// limit, codes.
    scale_err: f64,
    offset_err: f64,
    slew_err: f64,
    gain: f64,
    /// The output, codes, and the bound on the core's distance from it.
    output: f64,
    output_err: f64,
}

/// The stage's resolution: 2^-16 of a code, and of the gain.
const Q16_LSB: f64 = 1.0 / 65_536.0;

impl DacReference {
    pub fn new(params: &FeedforwardParams) -> Self {
        let volts_per_code = f64::from(params.dac_full_scale_v) / 32767.0;
        let pm_per_code = f64::from(params.k_dv_um_per_v) * 1e6 * volts_per_code;
        let offset_codes = f64::from(params.offset_v) / volts_per_code;
        let slew_codes = f64::from(params.slew_v_per_tick) / volts_per_code;
        let ramp = params.enable_ramp_ticks.max(1);
        // The volts per code in f32 (2^-24), the codes per picometre in Q32.
        let f32_err = 1.0 / 16_777_216.0;
        Self {
            pm_per_code,
            offset_codes,
            slew_codes,
            gain_step: f64::from((65_536 / ramp).max(1)) * Q16_LSB,
            scale_err: f32_err + pm_per_code.abs() / TURN + 1e-15,
            offset_err: offset_codes.abs() * f32_err + Q16_LSB,
            slew_err: slew_codes * f32_err + Q16_LSB,
            gain: 0.0,
            output: 0.0,
            output_err: 0.0,
        }
    }

    /// One tick on the prediction `de` (picometres), with compensation wanted (`active`:
    /// enabled, inputs trusted, a model in force) or not.
    pub fn tick(&mut self, de: Bounded, active: bool) -> DacTick {
        let gain_target = if active { 1.0 } else { 0.0 };
        self.gain = if self.gain < gain_target {
            (self.gain + self.gain_step).min(gain_target)
        } else {
            (self.gain - self.gain_step).max(gain_target)
        };
        // Clamped far outside the DAC's range before the gain (2^24 codes).
        let limit = 16_777_216.0;
        let correction = (-de.value / self.pm_per_code).clamp(-limit, limit);
        let unclamped = correction * self.gain - self.offset_codes;
        let target_err = (de.bound / self.pm_per_code.abs()
            + (de.value.abs() + de.bound) / self.pm_per_code.abs() * self.scale_err)
            * self.gain
            + self.offset_err
            + 3.0 * Q16_LSB;
        let (low, high) = (-32768.0, 32767.0);
        let saturated = if unclamped > high + target_err || unclamped < low - target_err {
            Some(true)
        } else if unclamped < high - target_err && unclamped > low + target_err {
            Some(false)
        } else {
            None
        };
        let target = unclamped.clamp(low, high);
        let delta = target - self.output;
        let margin = target_err + self.output_err + self.slew_err;
        let slewing = if delta.abs() > self.slew_codes + margin {
            Some(true)
        } else if delta.abs() < self.slew_codes - margin {
            Some(false)
        } else {
            None
        };
        self.output += delta.clamp(-self.slew_codes, self.slew_codes);
        // Both at the target, or one slew step from where they were.
        self.output_err = match slewing {
            Some(false) => target_err,
            _ => target_err.max(self.output_err + self.slew_err),
        };
        DacTick { code: Bounded { value: self.output, bound: 0.5 + self.output_err }, saturated, slewing }
    }
}
