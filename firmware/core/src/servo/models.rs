//! The low-priority side of the servo: the model request the tick hands out, the twin
//! programs (active and staged), the model computation on the request's features (with the
//! analogue-path correction and the axis twin's compensator) and the result handed back to
//! the tick ([`Servo::deliver`](super::Servo::deliver)).

use heapless::Vec;

use crate::analogue_path::AnaloguePath;
use crate::axis::compensate::{Compensator, Phasor, MAX_HIGHER_ORDERS, MAX_ORDERS};
use crate::commands::DefaultCommandRing;
use crate::features::{DefaultScratch, DefaultSpectralRings, FeatureConfig, FeatureError, FeatureSnapshot, Features};
use crate::math::{deg_to_turns, um_to_pm};
use crate::program::{EvalError, ModelOutput, Program, ProgramError, TickTerm, MAX_TERMS, REG_AMP_UM, REG_PHASE_DEG};
use crate::supervisor::{motion, Observation};
use crate::synth::SynthTargets;

/// A snapshot handed from the servo tick to the model update.
#[derive(Clone, Copy, Debug)]
pub struct ModelRequest {
    /// The features' state at the request (its [`FeatureSnapshot::capture`] is what the
    /// features are computed from).
    pub snapshot: FeatureSnapshot,
    /// Tick of the request.
    pub tick: u64,
    /// Tick at which the result takes effect.
    pub due_tick: u64,
    /// The command phase's advance per tick at the request, u32 turns (as `i32`, signed):
    /// the command frequency, for the analogue-path correction.
    pub cmd_step_turns: i32,
    /// The command phase at the request, u32 turns (the axis twin's compensator takes the
    /// phases of the ticks before from it and the step).
    pub cmd_phase_turns: u32,
    /// Whether the feedforward's gain was zero at the request.
    pub gain_zero: bool,
    /// DAC saturations counted up to the request.
    pub clamped_total: u32,
    /// Ticks over which the synthesiser ramps to a result (set once, with the servo): the
    /// output reaches a result's values that long after its due tick.
    pub output_ramp_ticks: u32,
}

impl ModelRequest {
    /// A request for no real window (what an empty request slot holds).
    pub const EMPTY: Self = Self {
        snapshot: FeatureSnapshot::empty(FeatureConfig::DEFAULT),
        tick: 0,
        due_tick: 0,
        cmd_step_turns: 0,
        cmd_phase_turns: 0,
        gain_zero: true,
        clamped_total: 0,
        output_ramp_ticks: 0,
    };
}

/// Why a model update produced no output.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ModelFault {
    /// No program is active.
    NoProgram,
    /// The feature snapshot was overwritten while it was read.
    Features(FeatureError),
    /// The program's evaluation failed.
    Eval(EvalError),
}

// The inner error is part of the message, so it is not also given as the source.
impl core::fmt::Display for ModelFault {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::NoProgram => write!(f, "no program is active"),
            Self::Features(err) => write!(f, "the features could not be computed: {err}"),
            Self::Eval(err) => write!(f, "the program's evaluation failed: {err}"),
        }
    }
}

impl core::error::Error for ModelFault {}

/// What a model update computed.
#[derive(Clone, Debug)]
pub struct ModelResult {
    /// Tick at which it takes effect.
    pub due_tick: u64,
    /// The features it used (zero where they could not be computed).
    pub features: [f32; 12],
    /// The program's outputs and its per-tick terms, or why there are none.
    pub outcome: Result<(ModelOutput, Vec<TickTerm, MAX_TERMS>, u32), ModelFault>,
    /// The outcome's output converted for the synthesiser (silent without one), so that
    /// the servo tick applying it need not convert.
    pub targets: SynthTargets,
    /// For a program whose axis twin compensates: the output and its targets without the
    /// formulas' part, the twin's correction alone. It comes from the command, not from the
    /// accelerometer's features, so it is what the supervisor's gate leaves on.
    pub command_driven: Option<(ModelOutput, SynthTargets)>,
    /// Times the axis twin's compensator diverged and was reset since the last result.
    pub new_axis_resets: u32,
    /// The update as the supervisor judges it.
    pub observation: Observation,
}

/// The twin programs (active and staged) and the model computation: the low-priority side.
pub struct Models {
    active: Option<Program>,
    staged: Option<Program>,
    scratch: DefaultScratch,
    /// The active program's axis twin, compensating (see [`Models::compute`]).
    compensator: Option<Compensator>,
    /// The next tick of the command ring the compensator has not simulated.
    next_command_tick: Option<u64>,
    /// The compensator's resets already reported.
    compensator_resets_seen: u32,
}

/// Ticks of history a compensator starts on (or restarts on, after the low-priority side
/// fell behind the command ring): 128 ms.
const COMPENSATOR_START_TICKS: u64 = 1024;

impl Default for Models {
    fn default() -> Self {
        Self::new()
    }
}

impl Models {
    /// No program.
    pub const fn new() -> Self {
        Self {
            active: None,
            staged: None,
            scratch: DefaultScratch::new(),
            compensator: None,
            next_command_tick: None,
            compensator_resets_seen: 0,
        }
    }

    /// The active program changed: a new compensator for its axis twin, if it has one.
    fn activated(&mut self) {
        let axis = self.active.as_ref().and_then(|p| {
            p.terms.iter().find_map(|t| if let TickTerm::Axis(params) = t { Some(*params) } else { None })
        });
        // The higher orders the program gives slots for, in slot order.
        let mut higher_orders = Vec::<u32, MAX_HIGHER_ORDERS>::new();
        for term in self.active.iter().flat_map(|p| p.terms.iter()) {
            if let TickTerm::AxisHarmonic { order } = *term {
                // The validator allows no more than fit here.
                let _ = higher_orders.push(u32::from(order));
            }
        }
        // Parameters the validator let through always give a model.
        self.compensator = axis.and_then(|params| Compensator::new(&params, &higher_orders).ok());
        self.next_command_tick = None;
        self.compensator_resets_seen = 0;
    }

    /// Validates `program`; stages it, and activates it if asked. A rejected program changes
    /// nothing.
    pub fn upload(&mut self, program: Program, activate: bool) -> Result<(), ProgramError> {
        program.validate()?;
        if activate {
            self.active = Some(program);
            self.activated();
        } else {
            self.staged = Some(program);
        }
        Ok(())
    }

    /// Activates the staged program. Returns false if none is staged.
    pub fn activate_staged(&mut self) -> bool {
        match self.staged.take() {
            Some(program) => {
                self.active = Some(program);
                self.activated();
                true
            }
            None => false,
        }
    }

    /// Removes the active program.
    pub fn clear(&mut self) {
        self.active = None;
        self.activated();
    }

    /// The active program.
    pub fn active_program(&self) -> Option<&Program> {
        self.active.as_ref()
    }

    /// Id of the active program.
    pub fn active_id(&self) -> Option<u32> {
        self.active.as_ref().map(|p| p.id)
    }

    /// Id of the staged program.
    pub fn staged_id(&self) -> Option<u32> {
        self.staged.as_ref().map(|p| p.id)
    }

    /// Finishes the features of `request`, evaluates the active program on them and corrects
    /// the phases for the analogue path (`path`, see [`crate::analogue_path`]) at the command
    /// frequency of the request.
    ///
    /// A program with an axis twin compensates through it: the compensator simulates the
    /// axis on the ticks' commands up to the request (`commands`) and learns its correction
    /// ([`crate::axis::compensate`]); its fundamental is added to the program's (after the
    /// path correction: the compensator's simulation already contains the path) and its
    /// third harmonic takes the axis term's slot, so that the servo tick runs harmonics only.
    pub fn compute(
        &mut self,
        rings: &DefaultSpectralRings,
        commands: &DefaultCommandRing,
        request: &ModelRequest,
        path: &AnaloguePath,
    ) -> ModelResult {
        let mut result = ModelResult {
            due_tick: request.due_tick,
            features: [0.0; 12],
            outcome: Err(ModelFault::NoProgram),
            targets: SynthTargets::SILENT,
            command_driven: None,
            new_axis_resets: 0,
            observation: Observation {
                tick: request.tick,
                window_ticks: request.snapshot.capture().cfg.window_samples,
                gain_zero: request.gain_zero,
                clamped_total: request.clamped_total,
                estimate: None,
                program_id: None,
            },
        };
        self.compensate(commands, request);
        if let Some(compensator) = &self.compensator {
            result.new_axis_resets = compensator.resets().wrapping_sub(self.compensator_resets_seen);
            self.compensator_resets_seen = compensator.resets();
        }
        let capture = request.snapshot.capture();
        let features: Features = match rings.finish(&capture, &mut self.scratch) {
            Ok(features) => features,
            Err(err) => {
                result.outcome = Err(ModelFault::Features(err));
                return result;
            }
        };
        result.features = features.as_array();
        result.observation.estimate = motion::estimate(
            rings,
            &capture,
            result.features[crate::features::VARIANCE_M2PS4],
            request.cmd_step_turns,
            request.cmd_phase_turns,
        );
        if let Some(program) = &self.active {
            result.outcome = match program.evaluate(&result.features) {
                Ok(mut output) => {
                    correct_for_path(
                        &mut output,
                        &program.terms,
                        path,
                        request.cmd_step_turns,
                        capture.cfg.sample_rate_hz,
                    );
                    match &mut self.compensator {
                        Some(compensator) => {
                            let ratios = path_ratios(compensator, path, capture.cfg.sample_rate_hz);
                            // The output reaches this result a ramp after its due tick.
                            let lead_ticks = (request.due_tick.saturating_sub(request.tick) as u32)
                                .saturating_add(request.output_ramp_ticks);
                            let mut command_output = output;
                            command_output.registers[REG_AMP_UM as usize] = 0.0;
                            let command_targets = compensated_targets(
                                &mut command_output,
                                &program.terms,
                                compensator,
                                ratios,
                                lead_ticks,
                            );
                            result.command_driven = Some((command_output, command_targets));
                            result.targets =
                                compensated_targets(&mut output, &program.terms, compensator, ratios, lead_ticks)
                        }
                        None => result.targets = SynthTargets::new(&output, &program.terms),
                    }
                    result.observation.program_id = Some(program.id);
                    Ok((output, program.terms.clone(), program.id))
                }
                Err(err) => Err(ModelFault::Eval(err)),
            };
        }
        result
    }

    /// Runs the compensator over the commands since its last run, up to the request's tick,
    /// and learns from them.
    fn compensate(&mut self, commands: &DefaultCommandRing, request: &ModelRequest) {
        let Some(compensator) = &mut self.compensator else {
            return;
        };
        let last = request.tick;
        let start = match self.next_command_tick {
            Some(next) if next <= last + 1 && last + 1 - next <= COMPENSATOR_START_TICKS => next,
            _ => last + 1 - (last + 1).min(COMPENSATOR_START_TICKS),
        };
        // The phases of the ticks before the request, from its phase and step (exact for a
        // command at a steady frequency, as in a cut).
        let step = request.cmd_step_turns as u32;
        // A tick missing after simulated ones (this side fell behind and the ring moved on,
        // or the program started): the simulation restarts from rest at the next one.
        let mut continuous = self.next_command_tick == Some(start);
        for tick in start..=last {
            match commands.get(tick as u32) {
                Some(pos_nm) => {
                    if !continuous {
                        compensator.restart();
                        continuous = true;
                    }
                    compensator
                        .tick(pos_nm, request.cmd_phase_turns.wrapping_sub(step.wrapping_mul((last - tick) as u32)));
                }
                None => continuous = false,
            }
        }
        let tick = last + 1;
        self.next_command_tick = Some(tick);
        compensator.learn(request.cmd_step_turns);
    }
}

/// `G(h f) / H(h f)` per order of the compensator: its simulated path, as the table was
/// measured, over the measured one (see [`crate::analogue_path`]), 1 where the table does not
/// reach or the twin has no response yet. An unmeasured gain takes the twin's, so that the phase alone is corrected.
fn path_ratios(compensator: &mut Compensator, path: &AnaloguePath, sample_rate_hz: f32) -> [Phasor; MAX_ORDERS] {
    if path.count == 0 {
        return [Phasor::ONE; MAX_ORDERS];
    }
    let (step_turns, responses) = compensator.path_responses(path.amp_um * 1e3);
    let freq_hz = step_turns as f32 * (sample_rate_hz / 4_294_967_296.0);
    let orders = compensator.orders();
    core::array::from_fn(|i| {
        let twin = responses[i];
        let twin_gain = twin.amplitude();
        let order = orders.get(i).copied().unwrap_or(0);
        match path.response_at(freq_hz * order as f32) {
            Some((gain, phase_deg)) if twin_gain > 0.0 => {
                let gain = gain.unwrap_or(twin_gain);
                let phase_rad = phase_deg * (core::f32::consts::PI / 180.0);
                twin * Phasor { re: libm::cosf(phase_rad) * gain, im: libm::sinf(phase_rad) * gain }.inverse()
            }
            _ => Phasor::ONE,
        }
    })
}

/// The synthesiser's targets of a program whose axis twin compensates: its fundamental plus
/// the compensator's (a correction `u` cancels the error `-u`), each harmonic of which is
/// taken through `ratios` (its simulated path over the measured one), the axis term's slot
/// the compensator's third harmonic and each [`TickTerm::AxisHarmonic`] slot its order. The
/// output's fundamental registers are updated to the sum.
fn compensated_targets(
    output: &mut ModelOutput,
    terms: &[TickTerm],
    compensator: &Compensator,
    ratios: [Phasor; MAX_ORDERS],
    lead_ticks: u32,
) -> SynthTargets {
    let mut correction_nm = compensator.output_correction_nm(lead_ticks);
    for (correction, ratio) in correction_nm.iter_mut().zip(ratios) {
        *correction = *correction * ratio;
    }
    // amp sin(theta + phase) = (amp cos phase) sin theta + (amp sin phase) cos theta.
    let (amp_um, phase_rad) = (output.amp_um(), output.phase_deg() * (core::f32::consts::PI / 180.0));
    let (amp_um, phase_deg) = amp_phase_deg(
        amp_um * libm::cosf(phase_rad) - correction_nm[0].re * 1e-3,
        amp_um * libm::sinf(phase_rad) - correction_nm[0].im * 1e-3,
    );
    output.registers[REG_AMP_UM as usize] = amp_um;
    output.registers[REG_PHASE_DEG as usize] = phase_deg;
    let mut targets = SynthTargets::new(output, terms);
    let orders = compensator.orders();
    for (slot, term) in terms.iter().enumerate() {
        let order = match *term {
            TickTerm::Axis(_) => orders[1],
            TickTerm::AxisHarmonic { order } => u32::from(order),
            _ => continue,
        };
        if let Some(i) = orders.iter().position(|&o| o == order) {
            let (amp_um, phase_deg) = amp_phase_deg(-correction_nm[i].re * 1e-3, -correction_nm[i].im * 1e-3);
            targets.set_harmonic(slot, order, um_to_pm(amp_um), deg_to_turns(phase_deg));
        }
    }
    targets
}

/// `re sin + im cos` as `amp sin(theta + phase)`: `(amp, phase_deg)`.
fn amp_phase_deg(re: f32, im: f32) -> (f32, f32) {
    (libm::sqrtf(re * re + im * im), libm::atan2f(im, re) * (180.0 / core::f32::consts::PI))
}

/// Subtracts the analogue path's phase at the command frequency from the fundamental's
/// phase, and at `n` times it from each order-`n` harmonic term's phase (a phase register
/// shared by several terms is corrected once, for the first).
fn correct_for_path(
    output: &mut ModelOutput,
    terms: &[TickTerm],
    path: &AnaloguePath,
    cmd_step_turns: i32,
    sample_rate_hz: f32,
) {
    if path.count == 0 {
        return;
    }
    let freq_hz = cmd_step_turns as f32 * (sample_rate_hz / 4_294_967_296.0);
    // A command running backwards sees the conjugate response.
    let phase_at = |f_hz: f32| if f_hz < 0.0 { -path.phase_deg_at(-f_hz) } else { path.phase_deg_at(f_hz) };
    let mut corrected = 1u32 << REG_PHASE_DEG;
    output.registers[REG_PHASE_DEG as usize] -= phase_at(freq_hz);
    for term in terms {
        if let TickTerm::Harmonic { order, phase_reg, .. } = *term {
            let bit = 1u32.checked_shl(u32::from(phase_reg)).unwrap_or(0);
            if let Some(reg) = output.registers.get_mut(phase_reg as usize).filter(|_| corrected & bit == 0) {
                *reg -= phase_at(freq_hz * f32::from(order));
                corrected |= bit;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 40 Hz at 8 kHz as the command's phase step.
    const STEP_40HZ: i32 = (4_294_967_296.0f64 * 40.0 / 8000.0) as i64 as i32;

    #[test]
    fn a_model_fault_says_why_with_the_inner_error() {
        let fault = ModelFault::Eval(EvalError::NonFiniteFeature { index: 3 });
        assert_eq!(fault.to_string(), "the program's evaluation failed: input feature 3 is not finite");
        let fault: &dyn core::error::Error = &ModelFault::Features(FeatureError::Torn);
        assert!(fault.to_string().ends_with(&FeatureError::Torn.to_string()));
    }

    #[test]
    fn the_path_phase_is_taken_off_the_fundamental_and_each_harmonic_once() {
        let path = AnaloguePath::from_points(&[(40.0, -6.0), (80.0, -30.0), (120.0, -90.0)]).unwrap();
        let mut output = ModelOutput::default();
        output.registers[REG_PHASE_DEG as usize] = 10.0;
        output.registers[3] = 1.0;
        output.registers[5] = 2.0;
        let terms = [
            TickTerm::Harmonic { order: 2, amp_reg: 2, phase_reg: 3 },
            TickTerm::Harmonic { order: 3, amp_reg: 4, phase_reg: 5 },
            // Shares term 1's phase register: corrected once only.
            TickTerm::Harmonic { order: 3, amp_reg: 6, phase_reg: 3 },
        ];
        correct_for_path(&mut output, &terms, &path, STEP_40HZ, 8000.0);
        assert!((output.registers[REG_PHASE_DEG as usize] - 16.0).abs() < 1e-3);
        assert!((output.registers[3] - 31.0).abs() < 1e-3);
        assert!((output.registers[5] - 92.0).abs() < 1e-3);
        // A command running backwards sees the conjugate; an empty table changes nothing.
        let mut backwards = ModelOutput::default();
        correct_for_path(&mut backwards, &[], &path, -STEP_40HZ, 8000.0);
        assert!((backwards.registers[REG_PHASE_DEG as usize] + 6.0).abs() < 1e-3);
        let mut untouched = output;
        correct_for_path(&mut untouched, &terms, &AnaloguePath::NONE, STEP_40HZ, 8000.0);
        assert_eq!(untouched, output);
    }

    #[test]
    fn the_axis_correction_is_taken_through_the_twins_path_over_the_measured_one() {
        let mut compensator = Compensator::new(&crate::axis::default_machine(), &[]).unwrap();
        let unit = Phasor::ONE;
        // Nothing measured by the twin yet: no change.
        let path = AnaloguePath::from_responses(8.0, &[(40.0, 2.0, -6.0), (100.0, 5.0, -170.0)]).unwrap();
        assert_eq!(path_ratios(&mut compensator, &path, 8000.0), [unit; MAX_ORDERS]);
        compensator.learn(STEP_40HZ);
        let (_, twin) = compensator.path_responses(8000.0);
        let ratios = path_ratios(&mut compensator, &path, 8000.0);
        // 40 Hz is in the table: G / H; 120 Hz (the third order) is beyond it: 1.
        let (gain, phase_deg) = (ratios[0].amplitude(), libm::atan2f(ratios[0].im, ratios[0].re).to_degrees());
        let twin_phase_deg = libm::atan2f(twin[0].im, twin[0].re).to_degrees();
        assert!((gain - twin[0].amplitude() / 2.0).abs() < 1e-5, "{gain}");
        assert!((phase_deg - (twin_phase_deg + 6.0)).abs() < 1e-3, "{phase_deg}");
        assert_eq!(ratios[1], unit);
        // A table that equals the twin's path changes nothing; phases alone keep the gain.
        let same = AnaloguePath::from_responses(8.0, &[(40.0, twin[0].amplitude(), twin_phase_deg)]).unwrap();
        let ratio = path_ratios(&mut compensator, &same, 8000.0)[0];
        assert!((ratio.re - 1.0).abs() < 1e-5 && ratio.im.abs() < 1e-5, "{ratio:?}");
        let phases = AnaloguePath::from_points(&[(40.0, twin_phase_deg - 2.0)]).unwrap();
        let ratio = path_ratios(&mut compensator, &phases, 8000.0)[0];
        assert!((ratio.amplitude() - 1.0).abs() < 1e-5, "{ratio:?}");
        assert!((libm::atan2f(ratio.im, ratio.re).to_degrees() - 2.0).abs() < 1e-3, "{ratio:?}");
        assert_eq!(path_ratios(&mut compensator, &AnaloguePath::NONE, 8000.0), [unit; MAX_ORDERS]);
    }

    /// With friction the response to a sine at rest depends on its amplitude; the twin's is
    /// simulated with the table's, effects included.
    #[test]
    fn the_twins_path_is_simulated_as_the_table_was_measured() {
        let friction = crate::axis::Friction {
            coulomb_mps2: 3.0 / 45.0,
            static_mps2: 4.5 / 45.0,
            stribeck_mps: 2e-4,
            smooth_mps: 1e-5,
        };
        let params = crate::axis::AxisParams { friction: Some(friction), ..crate::axis::default_machine() };
        let mut compensator = Compensator::new(&params, &[]).unwrap();
        // Not in the updates that measure the learning's responses (one order each): none yet.
        for _ in 0..compensator.orders().len() {
            compensator.learn(STEP_40HZ);
            assert_eq!(compensator.path_responses(8000.0).1, [Phasor::ZERO; MAX_ORDERS]);
        }
        compensator.learn(STEP_40HZ);
        let phase_at = |c: &mut Compensator, amp_nm: f32| {
            let g = c.path_responses(amp_nm).1[0];
            libm::atan2f(g.im, g.re).to_degrees()
        };
        let (small, large) = (phase_at(&mut compensator, 1000.0), phase_at(&mut compensator, 8000.0));
        // Friction lags a small sine at rest more than a large one.
        assert!(small < large - 5.0, "1 um {small} deg, 8 um {large} deg");
        let linear = phase_at(&mut Compensator::new(&crate::axis::default_machine(), &[]).unwrap(), 8000.0);
        assert_eq!(linear, 0.0, "no learning yet: no response");
    }
}
