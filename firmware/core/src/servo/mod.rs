//! The whole per-tick pipeline, as the firmware runs it and the host simulates it.
//!
//! Two contexts share the work:
//! - [`Servo::tick`] runs in the servo-rate interrupt: input health, the feature update, the
//!   error synthesis and the feedforward. Every model interval (see [`ModelTiming`]) it
//!   hands out a [`ModelRequest`] (a snapshot of the features' state).
//! - [`Models::compute`] runs at a lower priority: it finishes the features and evaluates the
//!   active twin program. Its [`ModelResult`] is handed back with [`Servo::deliver`] and takes
//!   effect exactly one model latency after the request, whenever it was
//!   computed, so the output is a function of the input stream alone: the firmware and the
//!   host produce the same DAC codes bit for bit. A result that comes later than that is
//!   applied at once (or up to two ticks later, not to fall on a tick that ends or starts a
//!   feature block or requests a model update; the firmware adds a few ticks to prepare it
//!   outside the critical section it shares with the tick) and counted as late.
//!
//! Faults never step the output and never stop the loop: a stuck or saturated accelerometer,
//! or a missing host, marks the inputs untrusted ([`DEGRADED_STUCK`] ...) and the feedforward
//! ramps to zero compensation until the inputs have been healthy for a whole feature window
//! and a model result computed on such a window is in force.
//!
//! The tick side is here ([`Servo`]); the low-priority side, from the request to the result,
//! is in `models` ([`Models`]), and when model updates happen in `timing` ([`ModelTiming`]).

mod models;
mod timing;

use serde::{Deserialize, Serialize};

use crate::analogue_path::AnaloguePath;
use crate::bus::{
    InputSlot, OutputSlot, OUT_FLAG_DEGRADED, OUT_FLAG_ENABLED, OUT_FLAG_MODEL_ACTIVE, OUT_FLAG_SATURATED,
    OUT_FLAG_SLEWING,
};
use crate::commands::DefaultCommandRing;
use crate::features::{DefaultFeatureState, DefaultSpectralRings, FeatureConfig, FeatureError, BLOCK_SAMPLES};
use crate::feedforward::{Feedforward, FeedforwardParams, ParamError};
use crate::program::{ModelOutput, TickTerm};
use crate::supervisor::{Supervisor, SupervisorParamError, SupervisorParams, SupervisorState};
use crate::synth::{PreparedUpdate, Synth, SynthTargets, SynthView};
use timing::first_request_countdown;

pub use crate::counters::Counters;
pub use models::{ModelFault, ModelRequest, ModelResult, Models};
pub use timing::ModelTiming;

/// Degraded: the accelerometer code has not changed for [`ServoConfig::stuck_limit_ticks`].
pub const DEGRADED_STUCK: u16 = 1 << 0;
/// Degraded: the accelerometer sat at full scale for [`ServoConfig::saturation_limit_ticks`].
pub const DEGRADED_SATURATED: u16 = 1 << 1;
/// Degraded: the host's samples did not arrive (bus underrun).
pub const DEGRADED_NO_INPUT: u16 = 1 << 2;
/// Degraded: the last model evaluation failed.
pub const DEGRADED_MODEL: u16 = 1 << 3;
/// Degraded: inputs are healthy again but the feature window still holds bad samples.
pub const DEGRADED_RECOVERING: u16 = 1 << 4;
/// Held off by the supervisor: compensation was not helping, shook the structure or
/// saturated the DAC ([`crate::supervisor`]), until the operating point changes.
pub const DEGRADED_SUPERVISED: u16 = 1 << 5;
/// Held off by the supervisor's gate: the accelerometer sees mostly noise.
pub const DEGRADED_GATED: u16 = 1 << 6;
/// The supervisor's bits: not about the inputs, so kept while they recover. In the
/// degraded bits, so that the tick needs nothing more to ramp compensation out.
const SUPERVISOR_BITS: u16 = DEGRADED_SUPERVISED | DEGRADED_GATED;

/// Timing and fault-detection settings of the servo pipeline.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ServoConfig {
    /// Longest interval between model updates, ticks (800 = 10 Hz at 8 kHz). See
    /// [`ModelTiming`] for the interval in force.
    pub model_interval_ticks: u32,
    /// Longest time from a model request to its result taking effect, ticks.
    pub model_latency_ticks: u32,
    /// Shortest interval between model updates, ticks.
    pub min_model_interval_ticks: u32,
    /// Model updates per feature window (the interval is the window over this, within the
    /// bounds above).
    pub model_updates_per_window: u32,
    /// Ticks over which the synthesiser moves to a new model output.
    pub synth_ramp_ticks: u32,
    /// Unchanged accelerometer codes before the sensor counts as stuck or dead.
    pub stuck_limit_ticks: u32,
    /// Consecutive full-scale codes before the sensor counts as saturated.
    pub saturation_limit_ticks: u32,
    /// Bus underruns in a row before the inputs count as missing.
    pub underrun_limit_ticks: u32,
}

impl Default for ServoConfig {
    fn default() -> Self {
        Self {
            model_interval_ticks: 800,
            model_latency_ticks: 400,
            min_model_interval_ticks: 48,
            model_updates_per_window: 16,
            synth_ramp_ticks: 80,
            stuck_limit_ticks: 800,
            saturation_limit_ticks: 16,
            underrun_limit_ticks: 8,
        }
    }
}

/// Why the servo started on defaults.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum InitError {
    /// The feedforward parameters were invalid.
    Params(ParamError),
    /// The feature settings were invalid.
    Features(FeatureError),
}

// The inner error is part of the message, so it is not also given as the source.
impl core::fmt::Display for InitError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Params(err) => write!(f, "invalid feedforward parameters, started on the defaults: {err}"),
            Self::Features(err) => write!(f, "invalid feature settings, started on the defaults: {err}"),
        }
    }
}

impl core::error::Error for InitError {}

/// Where [`Servo::tick`] leaves a model request: written in place, field by field (block
/// moves rather than a library `memcpy` of the ~110 bytes), and taken out at low priority.
#[derive(Clone, Copy, Debug)]
struct RequestSlot {
    request: ModelRequest,
    full: bool,
}

impl RequestSlot {
    /// An empty slot for a synthesiser that ramps to each result over `ramp_ticks`.
    const fn new(ramp_ticks: u32) -> Self {
        Self { request: ModelRequest { output_ramp_ticks: ramp_ticks, ..ModelRequest::EMPTY }, full: false }
    }

    /// Takes the request out, if there is one.
    fn take(&mut self) -> Option<ModelRequest> {
        let full = core::mem::replace(&mut self.full, false);
        full.then_some(self.request)
    }
}

/// What applying a pending result does besides the synthesiser's update (decided when it
/// is delivered, so that the tick applying it need not look at it).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum PendingEffect {
    /// The program's output takes effect.
    Output { program_id: u32 },
    /// No program is active: silence.
    NoProgram,
    /// The evaluation failed: silence, counted.
    Fault,
}

/// The supervisor's verdict on a model result ([`Servo::judge`]), for the rest of its
/// delivery.
#[derive(Clone, Copy, Debug)]
pub struct Judgement {
    effect: PendingEffect,
    /// The axis twin's correction alone takes effect (the gate holds the formulas off).
    command_driven: bool,
    /// The degraded bits applying the result sets, and the trips to count.
    supervision: (u16, u32),
}

impl Judgement {
    /// The synthesiser's update to `result` this verdict leaves: its targets and terms.
    fn update_of<'a>(&self, result: &'a ModelResult) -> (&'a SynthTargets, &'a [TickTerm]) {
        match &result.outcome {
            Ok((_, terms, _)) => match &result.command_driven {
                Some((_, command_targets)) if self.command_driven => (command_targets, terms),
                _ => (&result.targets, terms),
            },
            Err(_) => (&SynthTargets::SILENT, &[]),
        }
    }
}

/// What preparing a delivery reads of the servo ([`Servo::delivery_view`]).
#[derive(Clone, Copy, Debug)]
pub struct DeliveryView {
    /// The tick that applies the result.
    apply_tick: u64,
    /// Ticks from the view to it.
    ticks_ahead: u32,
    synth: SynthView,
}

/// A delivery's synthesiser update, prepared outside the servo ([`Servo::prepare_delivery`]).
#[derive(Clone, Copy, Debug)]
pub struct PreparedDelivery {
    apply_tick: u64,
    update: PreparedUpdate,
}

/// Largest margin of [`Servo::delivery_view`]. It looks ahead for the first model countdown
/// hit only; the next one is an interval later (48 ticks by default). Missing a busy tick
/// costs that tick time, never the result's exactness: it is applied on the tick it was
/// prepared for.
pub const MAX_LATE_MARGIN_TICKS: u32 = 16;

/// Input-health tracking of the accelerometer and the bus.
#[derive(Clone, Copy, Debug, Default)]
struct Health {
    last_code: i16,
    same_run: u32,
    saturated_run: u32,
    underrun_run: u32,
    /// Healthy ticks still needed before the inputs are trusted again.
    recovering_ticks: u32,
    degraded: u16,
}

/// The servo-interrupt side of the twin. See the [module docs](self).
///
/// `repr(C)` with the fields every tick touches first, then the 90 KB feature state (whose
/// per-sample fields come first): they then lie within 4 KB of the start, where a Cortex-M4
/// load or store needs one instruction (three beyond, with the offset built in a register).
/// The model results' parts, touched only when one is delivered or applied, come last.
#[repr(C)]
pub struct Servo {
    counters: Counters,
    health: Health,
    config: ServoConfig,
    /// Ticks until the next model request.
    model_countdown: u32,
    /// The previous tick's command phase, u32 turns.
    prev_cmd_phase_turns: u32,
    /// Model interval and latency for the feature window in force.
    timing: ModelTiming,
    awaiting_due: Option<u64>,
    /// [`Counters::fault_sum`] of `counters`, kept up to date where they change.
    fault_total: u32,
    /// The tick that applies the pending result (`u64::MAX`: none): its due tick, or a late
    /// one's (see [`Servo::delivery_view`]); next to the other per-tick fields.
    pending_due_tick: u64,
    /// Slot `applied` of `last_outputs` and `result_features` is the result in force; the
    /// other one is pending when `pending_due_tick` says so. Applying it is a switch.
    applied: usize,
    /// What applying the pending result does besides the synthesiser's update.
    pending_effect: PendingEffect,
    /// The supervisor's degraded bits that applying the pending result sets, and its new
    /// trips to count (decided when the result is delivered).
    pending_supervision: (u16, u32),
    model_active: bool,
    last_dac: i16,
    program_id: Option<u32>,
    feedforward: Feedforward,
    feature_config: FeatureConfig,
    /// The model request waiting for the low-priority side ([`Servo::take_request`]).
    request: RequestSlot,
    synth: Synth,
    features: DefaultFeatureState,
    /// The features of each result slot's model update.
    result_features: [[f32; 12]; 2],
    /// The last model output applied, per result slot (an error result carries the previous
    /// one over).
    last_outputs: [ModelOutput; 2],
    /// [`Synth::axis_resets`] when last taken into `counters`.
    axis_resets_seen: u32,
    /// Whether the program in force has an axis twin, whose compensator needs the ticks'
    /// commands ([`Models::compute`]): the tick then stores them in the command ring.
    push_commands: bool,
    /// The same for the pending result's program, taking effect with it.
    pending_push_commands: bool,
    supervisor: Supervisor,
}

impl Servo {
    /// A servo pipeline with the given settings. Invalid feedforward parameters or feature
    /// settings are replaced by the defaults, and the error is returned alongside, so that
    /// the firmware always boots into a safe, working state.
    pub fn new(
        feature_config: FeatureConfig,
        config: ServoConfig,
        params: FeedforwardParams,
    ) -> (Self, Result<(), InitError>) {
        let (feedforward, params_check) = Feedforward::new(params);
        let (features, feature_config, features_check) = match DefaultFeatureState::new(feature_config) {
            Ok(state) => (state, feature_config, Ok(())),
            Err(err) => match DefaultFeatureState::new(FeatureConfig::DEFAULT) {
                Ok(state) => (state, FeatureConfig::DEFAULT, Err(InitError::Features(err))),
                // The default configuration fits the default capacity (tested).
                Err(_) => unreachable!("the default feature configuration is valid"),
            },
        };
        let timing = ModelTiming::new(&config, feature_config.window_samples);
        let (supervisor, _) = Supervisor::new(SupervisorParams::default(), 0);
        let servo = Self {
            features,
            feature_config,
            synth: Synth::new(config.synth_ramp_ticks),
            feedforward,
            config,
            counters: Counters::default(),
            health: Health::default(),
            request: RequestSlot::new(config.synth_ramp_ticks),
            result_features: [[0.0; 12]; 2],
            applied: 0,
            pending_effect: PendingEffect::NoProgram,
            pending_due_tick: u64::MAX,
            awaiting_due: None,
            fault_total: 0,
            model_active: false,
            pending_supervision: (0, 0),
            supervisor,
            program_id: None,
            last_outputs: [ModelOutput::default(); 2],
            axis_resets_seen: 0,
            push_commands: false,
            pending_push_commands: false,
            last_dac: 0,
            model_countdown: first_request_countdown(&timing),
            timing,
            prev_cmd_phase_turns: 0,
        };
        let check = params_check.map_err(InitError::Params).and(features_check);
        (servo, check)
    }

    /// Replaces the feature settings; the window restarts empty and any model result in
    /// flight is dropped (it was computed on the old settings). Invalid settings change nothing.
    pub fn set_feature_config(&mut self, config: FeatureConfig) -> Result<(), FeatureError> {
        if let Err(e) = self.features.reconfigure(config) {
            self.counters.rejected_feature_configs += 1;
            self.fault_total = self.fault_total.wrapping_add(1);
            return Err(e);
        }
        self.feature_config = config;
        self.timing = ModelTiming::new(&self.config, config.window_samples);
        self.model_countdown = first_request_countdown(&self.timing);
        self.pending_due_tick = u64::MAX;
        self.awaiting_due = None;
        self.supervisor.window_restarted(self.counters.ticks, self.feedforward.gain_is_zero());
        Ok(())
    }

    /// The model interval and latency in force.
    pub fn model_timing(&self) -> ModelTiming {
        self.timing
    }

    /// The feature settings in force.
    pub fn feature_config(&self) -> &FeatureConfig {
        &self.feature_config
    }

    /// One servo tick on `input`. Every model interval it leaves a [`ModelRequest`] for the
    /// low-priority side ([`Servo::take_request`]; one not yet taken is replaced) and returns
    /// true with the output.
    pub fn tick(
        &mut self,
        rings: &DefaultSpectralRings,
        commands: &DefaultCommandRing,
        input: &InputSlot,
    ) -> (OutputSlot, bool) {
        let tick = self.counters.ticks;
        self.counters.ticks += 1;
        if self.push_commands {
            commands.push(tick as u32, input.cmd_pos_nm);
        }
        self.health.underrun_run = 0;
        self.check_input(input.acc_code);
        self.features.push_with_command(rings, input.acc_code, input.cmd_pos_nm);
        let prev_cmd_phase_turns = self.prev_cmd_phase_turns;
        self.prev_cmd_phase_turns = input.cmd_phase_turns;

        let mut requested = false;
        // A countdown, not `tick % interval`: a 64-bit remainder is a library call of a
        // hundred instructions on a Cortex-M4, every tick.
        self.model_countdown = self.model_countdown.saturating_sub(1);
        let countdown_hit = self.model_countdown == 0;
        if countdown_hit {
            self.model_countdown = self.timing.interval_ticks;
            let snapshot = self.features.snapshot();
            // Only a full window gives the features the model was trained on.
            if snapshot.samples() >= self.feature_config.window_samples {
                let due_tick = tick + self.timing.latency_ticks as u64;
                let cmd_step_turns = input.cmd_phase_turns.wrapping_sub(prev_cmd_phase_turns) as i32;
                // Block moves; the capture is made from the snapshot at low priority.
                let slot = &mut self.request;
                snapshot.copy_to(&mut slot.request.snapshot);
                slot.request.tick = tick;
                slot.request.due_tick = due_tick;
                slot.request.cmd_step_turns = cmd_step_turns;
                slot.request.cmd_phase_turns = input.cmd_phase_turns;
                slot.request.gain_zero = self.feedforward.gain_is_zero();
                slot.request.clamped_total = self.counters.dac_saturations;
                slot.full = true;
                requested = true;
                self.awaiting_due = Some(due_tick);
            }
        }
        // This tick's own extra work: a feature block's end or start, or a model request
        // (see `Servo::next_tick_is_busy`).
        let busy = countdown_hit || self.features.last_push_was_busy();
        self.apply_due(tick, busy);

        // Kernel terms (effects) see the command position, the X acceleration and the spindle.
        let de_pm = self.synth.next_input(&crate::synth::TickInput {
            cmd_phase_turns: input.cmd_phase_turns,
            cmd_pos_nm: input.cmd_pos_nm,
            x_acc_um_per_s2: input.x_acc_um_per_s2,
            spindle_turns: input.spindle_turns,
        });
        let trusted = self.health.degraded == 0;
        let ff = self.feedforward.tick(de_pm, trusted && self.model_active);
        self.counters.dac_saturations += ff.saturated as u32;
        self.fault_total = self.fault_total.wrapping_add(ff.saturated as u32);
        self.counters.slew_limited_ticks += ff.slewing as u32;
        self.last_dac = ff.dac_code;
        let flags = (self.feedforward.enabled() as u16 * OUT_FLAG_ENABLED)
            | ((self.health.degraded != 0) as u16 * OUT_FLAG_DEGRADED)
            | (ff.saturated as u16 * OUT_FLAG_SATURATED)
            | (ff.slewing as u16 * OUT_FLAG_SLEWING)
            | (self.model_active as u16 * OUT_FLAG_MODEL_ACTIVE);
        let output = OutputSlot {
            tick: tick as u32,
            dac_code: ff.dac_code,
            flags,
            de_pred_pm: de_pm,
            fault_count: self.fault_count(),
        };
        (output, requested)
    }

    /// A tick period without input (the host's sample did not arrive): the output holds,
    /// the underrun is counted, and after a few in a row the inputs count as missing, so that
    /// compensation ramps out once they return (the feature window has a gap). The tick
    /// itself is not consumed: the next input is still tick `counters().ticks`.
    pub fn underrun(&mut self) -> OutputSlot {
        self.counters.bus_underruns += 1;
        self.fault_total = self.fault_total.wrapping_add(1);
        self.health.underrun_run += 1;
        if self.health.underrun_run >= self.config.underrun_limit_ticks {
            self.degrade(DEGRADED_NO_INPUT);
        }
        OutputSlot {
            tick: self.counters.ticks as u32,
            dac_code: self.last_dac,
            flags: OUT_FLAG_DEGRADED,
            de_pred_pm: 0,
            fault_count: self.fault_count(),
        }
    }

    fn degrade(&mut self, reason: u16) {
        if self.health.degraded & !(DEGRADED_RECOVERING | SUPERVISOR_BITS) == 0 {
            self.counters.degraded_entries += 1;
        }
        self.health.degraded |= reason;
        self.health.recovering_ticks = self.recovery_ticks();
    }

    /// Healthy ticks before the inputs are trusted again: a window without bad samples, then
    /// the first model result computed on such a window (an interval and the latency) and
    /// the synthesiser's ramp to it, so that compensation resumes with a prediction made from
    /// healthy samples only (not one from a window that still held the fault).
    fn recovery_ticks(&self) -> u32 {
        self.feature_config
            .window_samples
            .saturating_add(self.timing.interval_ticks)
            .saturating_add(self.timing.latency_ticks)
            .saturating_add(self.config.synth_ramp_ticks)
    }

    fn check_input(&mut self, code: i16) {
        let h = &mut self.health;
        h.same_run = if code == h.last_code { h.same_run.saturating_add(1) } else { 0 };
        h.last_code = code;
        let full_scale = code == i16::MAX || code <= -i16::MAX;
        h.saturated_run = if full_scale { h.saturated_run.saturating_add(1) } else { 0 };
        if h.same_run == self.config.stuck_limit_ticks {
            self.counters.input_stuck += 1;
            self.fault_total = self.fault_total.wrapping_add(1);
            self.degrade(DEGRADED_STUCK);
        }
        if self.health.saturated_run == self.config.saturation_limit_ticks {
            self.counters.input_saturated += 1;
            self.fault_total = self.fault_total.wrapping_add(1);
            self.degrade(DEGRADED_SATURATED);
        }
        let h = &self.health;
        let bad_now = h.same_run >= self.config.stuck_limit_ticks || h.saturated_run > 0;
        if h.degraded != 0 {
            if bad_now {
                // (Computed only here: three saturating additions on every tick otherwise.)
                self.health.recovering_ticks = self.recovery_ticks();
            } else {
                let h = &mut self.health;
                // Inputs are healthy again: wait for a model result from a window of them.
                h.degraded = (h.degraded & (DEGRADED_MODEL | SUPERVISOR_BITS)) | DEGRADED_RECOVERING;
                h.recovering_ticks = h.recovering_ticks.saturating_sub(1);
                if h.recovering_ticks == 0 {
                    h.degraded &= !DEGRADED_RECOVERING;
                }
            }
        }
    }

    /// Applies the pending result on the tick its delivery prepared it for: its due tick, or
    /// for a result that came late, the first tick from its delivery that neither ends nor
    /// starts a feature block nor requests a model update (`busy`; see
    /// [`Servo::delivery_view`]). On time it never falls on such a tick (requests and results
    /// come half a block away from the block ends, in whole blocks), and so the most
    /// expensive ticks never add up.
    fn apply_due(&mut self, tick: u64, busy: bool) {
        // The pending result's parts are not looked at: its tick is kept with the per-tick
        // fields.
        if tick >= self.pending_due_tick {
            if tick == self.pending_due_tick || !busy {
                self.apply_pending();
            }
        } else if self.pending_due_tick == u64::MAX && self.awaiting_due.is_some_and(|due| tick > due) {
            // The result is late; it will be applied when it arrives.
            self.counters.model_late += 1;
            self.awaiting_due = None;
        }
    }

    /// Applies the pending result: a switch of result slots (nothing is copied). Out of
    /// line: inlined, its register needs made every tick dearer.
    #[inline(never)]
    fn apply_pending(&mut self) {
        let slot = (self.applied ^ 1) & 1;
        self.awaiting_due = None;
        // Prepared at delivery for this tick (see `deliver`): a switch.
        if !self.synth.switch_prepared() {
            self.apply_unprepared();
        }
        match self.pending_effect {
            PendingEffect::Output { program_id } => {
                self.push_commands = self.pending_push_commands;
                self.counters.model_updates += 1;
                self.health.degraded &= !DEGRADED_MODEL;
                self.model_active = true;
                self.program_id = Some(program_id);
            }
            PendingEffect::NoProgram => {
                self.push_commands = false;
                self.model_active = false;
                self.program_id = None;
            }
            PendingEffect::Fault => {
                // A bad model or a torn snapshot: count, and ramp the prediction out.
                self.counters.model_faults += 1;
                self.fault_total = self.fault_total.wrapping_add(1);
                self.health.degraded |= DEGRADED_MODEL;
            }
        }
        let (bits, trips) = self.pending_supervision;
        self.health.degraded = (self.health.degraded & !SUPERVISOR_BITS) | bits;
        self.counters.supervisor_trips = self.counters.supervisor_trips.wrapping_add(trips);
        self.fault_total = self.fault_total.wrapping_add(trips);
        self.applied = slot;
        self.pending_due_tick = u64::MAX;
    }

    /// The synthesiser's update when the pending result was not prepared for this tick:
    /// silence (ramped). Not reached: a delivery is installed only when prepared for the tick
    /// that applies it, and the servo keeps no more of a result than its prepared update.
    #[cold]
    #[inline(never)]
    fn apply_unprepared(&mut self) {
        debug_assert!(false, "a model result applied without its prepared update");
        self.synth.apply(&SynthTargets::SILENT, &[]);
    }

    /// Whether the tick `ahead` ticks after the next one will end or start a feature block
    /// or hit the model countdown (the ticks a late result is not applied on; see
    /// `apply_due`), for `ahead` below the shortest model interval.
    fn tick_is_busy(&self, ahead: u32) -> bool {
        let countdown_hit = self.model_countdown.max(1) == ahead + 1;
        let block = match ahead {
            0 => self.features.next_push_is_busy(),
            // Blocks end every 16 pushes, the first of them `to_end` pushes from now, and the
            // push after each end starts the next block.
            _ => {
                let to_end = self.features.pushes_to_block_end() % BLOCK_SAMPLES as u32;
                (ahead + 1) % BLOCK_SAMPLES as u32 == to_end || ahead % BLOCK_SAMPLES as u32 == to_end
            }
        };
        countdown_hit || block
    }

    /// The model request the last request tick left, if not taken yet (at low priority).
    pub fn take_request(&mut self) -> Option<ModelRequest> {
        self.request.take()
    }

    /// Hands back a model result computed for a request of this servo, and prepares the
    /// synthesiser's update to it for the tick that will apply it (its due tick, or the next
    /// tick if that has passed), so that this tick has little to do. The same as
    /// [`Servo::judge`], [`Servo::delivery_view`], [`Servo::prepare_delivery`] and
    /// [`Servo::install_delivery`] in a row; the firmware runs the preparation between them
    /// outside the critical section it shares with the tick.
    pub fn deliver(&mut self, result: ModelResult) {
        let judgement = self.judge(&result);
        let view = self.delivery_view(&result, &judgement, 0);
        let prepared = Self::prepare_delivery(&view, &result, &judgement);
        let installed = self.install_delivery(&prepared, &result, &judgement);
        debug_assert!(installed, "nothing changed since the view");
    }

    /// The first step of a delivery, once per result: the supervisor's verdict on it (in
    /// force with the result) and the axis twin resets it reports.
    pub fn judge(&mut self, result: &ModelResult) -> Judgement {
        self.count_axis_resets();
        if result.new_axis_resets != 0 {
            self.update_counters(|c| c.axis_resets = c.axis_resets.wrapping_add(result.new_axis_resets));
        }
        let effect = match &result.outcome {
            Ok((_, _, program_id)) => PendingEffect::Output { program_id: *program_id },
            Err(ModelFault::NoProgram) => PendingEffect::NoProgram,
            Err(_) => PendingEffect::Fault,
        };
        // The supervisor's verdict, in force with the result: its degraded bits. Where the
        // gate holds the formulas off, an axis twin's correction (from the command) stays on.
        self.supervisor.judge(&result.observation);
        let command_driven = result.command_driven.is_some() && self.supervisor.allows_command_driven();
        let bits = if self.supervisor.allows() || command_driven {
            0
        } else if self.supervisor.state().tripped.is_some() {
            DEGRADED_SUPERVISED
        } else {
            DEGRADED_GATED
        };
        Judgement {
            effect,
            command_driven: command_driven && !self.supervisor.allows(),
            supervision: (bits, self.supervisor.take_trips()),
        }
    }

    /// What preparing the delivery of `result` reads of the servo (a copy of the live
    /// synthesiser bank, a few hundred bytes), for [`Servo::prepare_delivery`]. A late
    /// result is applied on the first tick from `late_margin_ticks` after the next one
    /// that is not busy (see `apply_due`): a margin leaves its preparation time to finish
    /// before that tick (the result comes so much later, as if it had been computed so).
    pub fn delivery_view(&self, result: &ModelResult, judgement: &Judgement, late_margin_ticks: u32) -> DeliveryView {
        let next = self.counters.ticks;
        let apply_tick = if result.due_tick >= next {
            result.due_tick
        } else {
            // At most two busy ticks come in a row (a block's end and the next one's start).
            let margin = late_margin_ticks.min(MAX_LATE_MARGIN_TICKS);
            next + u64::from((margin..margin + 2).find(|&j| !self.tick_is_busy(j)).unwrap_or(margin + 2))
        };
        let (targets, terms) = judgement.update_of(result);
        DeliveryView {
            apply_tick,
            ticks_ahead: (apply_tick - next).min(u64::from(u32::MAX)) as u32,
            synth: self.synth.view(targets, terms),
        }
    }

    /// Prepares the synthesiser's update to `result` from `view`; it touches no servo, so it
    /// may run while the tick does.
    pub fn prepare_delivery(view: &DeliveryView, result: &ModelResult, judgement: &Judgement) -> PreparedDelivery {
        let (targets, terms) = judgement.update_of(result);
        PreparedDelivery {
            apply_tick: view.apply_tick,
            update: Synth::prepare_from(&view.synth, targets, terms, view.ticks_ahead),
        }
    }

    /// The last step of a delivery: hands over the prepared update and makes `result`
    /// pending. Returns false, changing nothing, when the view is out of date (a result was
    /// applied since, or the tick that was to apply this one has passed): take a new view
    /// and prepare again.
    pub fn install_delivery(
        &mut self,
        prepared: &PreparedDelivery,
        result: &ModelResult,
        judgement: &Judgement,
    ) -> bool {
        let (_, terms) = judgement.update_of(result);
        if !self.synth.install(&prepared.update, terms) {
            return false;
        }
        let (applied, slot) = (self.applied & 1, (self.applied ^ 1) & 1);
        self.last_outputs[slot] = match &result.outcome {
            Ok((output, terms, _)) => {
                self.pending_push_commands = terms.iter().any(|t| matches!(t, TickTerm::Axis(_)));
                match &result.command_driven {
                    Some((command_output, _)) if judgement.command_driven => *command_output,
                    _ => *output,
                }
            }
            Err(_) => self.last_outputs[applied],
        };
        self.pending_effect = judgement.effect;
        self.pending_supervision = judgement.supervision;
        // The tick it was prepared for (the due tick, or a late result's; see `apply_due`).
        self.pending_due_tick = prepared.apply_tick;
        self.result_features[slot] = result.features;
        true
    }

    /// The analogue-path table in force (part of the feedforward parameters).
    pub fn analogue_path(&self) -> &AnaloguePath {
        &self.feedforward.params().analogue_path
    }

    /// Sets the feedforward parameters (rejected ones are counted and change nothing).
    pub fn set_params(&mut self, params: FeedforwardParams) -> Result<(), ParamError> {
        let result = self.feedforward.set_params(params);
        if result.is_err() {
            self.counters.rejected_params += 1;
            self.fault_total = self.fault_total.wrapping_add(1);
        } else {
            self.clear_supervisor_trip();
        }
        result
    }

    /// Sets the supervisor's thresholds (rejected ones are counted and change nothing); they
    /// take effect, and a trip is cleared, with the next model update.
    pub fn set_supervisor_params(&mut self, params: SupervisorParams) -> Result<(), SupervisorParamError> {
        let result = self.supervisor.set_params(params, self.counters.ticks);
        if result.is_err() {
            self.counters.rejected_params += 1;
            self.fault_total = self.fault_total.wrapping_add(1);
        }
        result
    }

    /// The supervisor's thresholds in force.
    pub fn supervisor_params(&self) -> SupervisorParams {
        *self.supervisor.params()
    }

    /// The supervisor's state.
    pub fn supervisor_state(&self) -> SupervisorState {
        *self.supervisor.state()
    }

    /// Clears a trip of the supervisor: compensation resumes (ramping) with the next model
    /// update, where a baseline is held.
    fn clear_supervisor_trip(&mut self) {
        self.supervisor.clear_trip(self.counters.ticks);
    }

    /// The feedforward parameters in force.
    pub fn params(&self) -> FeedforwardParams {
        *self.feedforward.params()
    }

    /// Switches compensation on or off; switching it on clears a supervisor trip.
    pub fn set_enabled(&mut self, enabled: bool) {
        self.feedforward.set_enabled(enabled);
        if enabled {
            self.clear_supervisor_trip();
        }
    }

    /// Whether compensation is asked for.
    pub fn enabled(&self) -> bool {
        self.feedforward.enabled()
    }

    /// The gain in force, 0 to 1.
    pub fn gain(&self) -> f32 {
        self.feedforward.gain()
    }

    /// The counters.
    pub fn counters(&self) -> &Counters {
        &self.counters
    }

    /// Takes the axis twin resets since the last call into the counters. The tick counts
    /// them only in the term's state (at no cost); this runs with every model delivery and
    /// before a status report.
    pub fn count_axis_resets(&mut self) {
        let total = self.synth.axis_resets();
        let new = total.wrapping_sub(self.axis_resets_seen);
        if new != 0 {
            self.axis_resets_seen = total;
            self.update_counters(|c| c.axis_resets = c.axis_resets.wrapping_add(new));
        }
    }

    /// Changes the counters (the board adds what it sees: overruns, frame errors, store
    /// errors; a reset clears them), keeping the servo's running sum of the fault counters.
    pub fn update_counters<R>(&mut self, f: impl FnOnce(&mut Counters) -> R) -> R {
        let result = f(&mut self.counters);
        self.fault_total = self.counters.fault_sum();
        result
    }

    /// `DEGRADED_*` bits in force.
    pub fn degraded(&self) -> u16 {
        self.health.degraded
    }

    /// The last model output applied.
    pub fn last_output(&self) -> &ModelOutput {
        &self.last_outputs[self.applied & 1]
    }

    /// The features of the last model update.
    pub fn last_features(&self) -> &[f32; 12] {
        &self.result_features[self.applied & 1]
    }

    /// Id of the program whose output is in force.
    pub fn program_id(&self) -> Option<u32> {
        self.program_id
    }

    /// Sum of the fault counters, as reported in every output slot ([`Counters::fault_sum`],
    /// kept as the counters change rather than summed on every tick).
    pub fn fault_count(&self) -> u32 {
        debug_assert_eq!(self.fault_total, self.counters.fault_sum());
        self.fault_total
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 40 Hz at 8 kHz as the command's phase step.
    const STEP_40HZ: i32 = (4_294_967_296.0f64 * 40.0 / 8000.0) as i64 as i32;

    #[test]
    fn a_diverging_axis_twin_is_counted_and_its_output_stays_bounded() {
        use crate::bus::{InputSlot, OutputSlot, IN_FLAG_PHASE_VALID};
        use crate::program::{ProgramBuilder, TickTerm, REG_AMP_UM, REG_PHASE_DEG};
        use crate::twin::Twin;
        use crate::wire::{Request, Response};
        // A derivative gain far beyond what the tick can carry: valid parameters whose loop
        // diverges on any motion.
        let unstable = crate::axis::AxisParams { kd_per_s: 9e5, ..crate::axis::default_machine() };
        let mut twin = Twin::boot(
            FeatureConfig { window_samples: 2000, ..FeatureConfig::DEFAULT },
            ServoConfig { model_interval_ticks: 400, model_latency_ticks: 200, ..ServoConfig::default() },
            &[],
        );
        let mut b = ProgramBuilder::new();
        b.id(8).constant(0.5).store(REG_AMP_UM).constant(0.0).store(REG_PHASE_DEG);
        b.term(TickTerm::Axis(unstable));
        assert_eq!(twin.handle(Request::UploadProgram { program: b.finish().unwrap(), activate: true }), Response::Ack);
        assert_eq!(twin.handle(Request::SetEnabled(true)), Response::Ack);
        let faults = twin.servo().fault_count();
        // A 40 Hz, 3 um command.
        let input = |k: u32| {
            let turns = (40.0 * f64::from(k) / 8000.0).fract();
            let sine = libm::sin(2.0 * core::f64::consts::PI * turns);
            InputSlot {
                tick: k,
                acc_code: (-5000.0 * sine) as i16,
                flags: IN_FLAG_PHASE_VALID,
                cmd_phase_turns: (turns * 4_294_967_296.0) as u64 as u32,
                cmd_pos_nm: (3000.0 * sine) as i32,
                ..Default::default()
            }
        };
        let mut outputs: heapless::Vec<OutputSlot, 8000> = heapless::Vec::new();
        for k in 0..8000 {
            outputs.push(twin.tick(Some(&input(k)))).unwrap();
        }
        let status = match twin.handle(Request::GetStatus) {
            Response::Status(status) => status,
            other => panic!("unexpected {other:?}"),
        };
        assert_eq!(status.program_id, Some(8));
        assert!(status.counters.axis_resets > 10, "{:?}", status.counters);
        // The resets are faults in the output slots' count (taken in with the model deliveries,
        // the last ones by the status report), beside the DAC saturations the excursions cause.
        assert_eq!(twin.servo().fault_count(), status.counters.fault_sum());
        assert!(twin.servo().fault_count() >= faults + status.counters.axis_resets);
        assert!(outputs[7999].fault_count > faults + 10);
        // The twin's output never leaves the divergence bound (1 mm of error and mode).
        assert!(outputs.iter().all(|o| o.de_pred_pm.unsigned_abs() <= 2_100_000_000));
    }

    /// A servo, rings, commands and models running a program with a harmonic term, as the
    /// delivery tests use them.
    #[allow(clippy::type_complexity)]
    fn delivery_rig(
        window_samples: u32,
    ) -> (
        std::boxed::Box<Servo>,
        std::boxed::Box<DefaultSpectralRings>,
        std::boxed::Box<DefaultCommandRing>,
        std::boxed::Box<Models>,
    ) {
        use crate::program::{ProgramBuilder, REG_AMP_UM, REG_PHASE_DEG};
        let features = FeatureConfig { window_samples, ..FeatureConfig::DEFAULT };
        let (servo, check) = Servo::new(features, ServoConfig::default(), FeedforwardParams::default());
        assert_eq!(check, Ok(()));
        let mut models = std::boxed::Box::new(Models::new());
        let mut b = ProgramBuilder::new();
        b.constant(2.0).feature(4).mul().store(REG_AMP_UM).constant(0.0).store(REG_PHASE_DEG);
        b.term(TickTerm::Harmonic { order: 3, amp_reg: 0, phase_reg: 1 });
        models.upload(b.finish().unwrap(), true).unwrap();
        (
            std::boxed::Box::new(servo),
            std::boxed::Box::new(DefaultSpectralRings::new()),
            std::boxed::Box::new(DefaultCommandRing::new()),
            models,
        )
    }

    fn delivery_input(k: u32) -> InputSlot {
        InputSlot {
            tick: k,
            acc_code: ((k * 7919) % 4001) as i16 - 2000,
            flags: crate::bus::IN_FLAG_PHASE_VALID,
            cmd_phase_turns: k.wrapping_mul(STEP_40HZ as u32),
            cmd_pos_nm: 0,
            ..Default::default()
        }
    }

    /// A delivery prepared from a view taken ticks before it is installed (as the firmware
    /// prepares it while the tick runs) gives the DAC codes of one delivered at once, bit for
    /// bit; a view whose result's tick passed is refused and changes nothing.
    #[test]
    fn deliveries_prepared_from_an_older_view_are_exact_and_stale_views_are_refused() {
        let (mut plain, rings_a, commands_a, mut models_a) = delivery_rig(800);
        let (mut split, rings_b, commands_b, mut models_b) = delivery_rig(800);
        let mut held: Option<(u32, ModelResult, Judgement, PreparedDelivery)> = None;
        let (mut refused, mut installed) = (0, 0);
        for k in 0..6000u32 {
            let input = delivery_input(k);
            assert_eq!(
                plain.tick(&rings_a, &commands_a, &input).0,
                split.tick(&rings_b, &commands_b, &input).0,
                "tick {k}"
            );
            if let Some(request) = plain.take_request() {
                let path = *plain.analogue_path();
                plain.deliver(models_a.compute(&rings_a, &commands_a, &request, &path));
            }
            if let Some(request) = split.take_request() {
                let path = *split.analogue_path();
                let result = models_b.compute(&rings_b, &commands_b, &request, &path);
                let judgement = split.judge(&result);
                let view = split.delivery_view(&result, &judgement, 0);
                let prepared = Servo::prepare_delivery(&view, &result, &judgement);
                // Held for 0 to 14 ticks: the result is due 16 ticks after its request.
                held = Some((k + k % 15, result, judgement, prepared));
            }
            if let Some((at, result, judgement, prepared)) = held.take() {
                if at != k {
                    held = Some((at, result, judgement, prepared));
                    continue;
                }
                // A copy held past the result's tick is refused.
                let mut late = std::boxed::Box::new(
                    Servo::new(
                        FeatureConfig { window_samples: 800, ..FeatureConfig::DEFAULT },
                        ServoConfig::default(),
                        FeedforwardParams::default(),
                    )
                    .0,
                );
                late.synth = split.synth.clone();
                late.synth.set_time_ticks(result.due_tick + 1);
                if !late.install_delivery(&prepared, &result, &judgement) {
                    refused += 1;
                }
                assert!(split.install_delivery(&prepared, &result, &judgement), "tick {k}");
                installed += 1;
            }
        }
        assert!(plain.counters().model_updates > 50, "{}", plain.counters().model_updates);
        assert_eq!(plain.counters().model_updates, split.counters().model_updates);
        assert_eq!(plain.counters().model_late, 0);
        assert_eq!(refused, installed);
    }

    /// Late results delivered with a margin (as the firmware does) are applied on the first
    /// tick from the margin that is not busy, and never before it.
    #[test]
    fn late_results_delivered_with_a_margin_are_applied_after_it_on_quiet_ticks() {
        for margin in [1, 3, 4, 9] {
            let (mut servo, rings, commands, mut models) = delivery_rig(800);
            let mut waiting: Option<(u32, ModelRequest)> = None;
            let mut delivered_at = None;
            let mut updates = 0;
            let mut applied = 0;
            for k in 0..6000u32 {
                let busy = servo.tick_is_busy(0);
                servo.tick(&rings, &commands, &delivery_input(k));
                if servo.counters().model_updates != updates {
                    updates = servo.counters().model_updates;
                    let at: u32 = delivered_at.take().expect("delivered");
                    assert!(!busy, "margin {margin}: applied on busy tick {k}");
                    assert!(k > at + margin, "margin {margin}: delivered after tick {at}, applied on {k}");
                    assert!(k <= at + margin + 3, "margin {margin}: delivered after tick {at}, applied on {k}");
                    applied += 1;
                }
                if let Some(request) = servo.take_request() {
                    waiting = Some((k + 17 + k % 7, request));
                }
                if let Some((_, request)) = waiting.filter(|(at, _)| *at == k) {
                    let path = *servo.analogue_path();
                    let result = models.compute(&rings, &commands, &request, &path);
                    let judgement = servo.judge(&result);
                    let view = servo.delivery_view(&result, &judgement, margin);
                    let prepared = Servo::prepare_delivery(&view, &result, &judgement);
                    assert!(servo.install_delivery(&prepared, &result, &judgement));
                    delivered_at = Some(k);
                    waiting = None;
                }
            }
            assert!(applied > 50, "{applied}");
            assert_eq!(servo.counters().model_late, servo.counters().model_updates);
        }
    }

    /// Results delivered late, some on the tick before a block end or a model request: each
    /// is applied on the next tick that is neither, with the update prepared for that tick
    /// (`apply_unprepared` asserts it is never needed), and counted as late.
    #[test]
    fn late_results_avoid_the_busy_ticks_and_are_prepared_for_their_tick() {
        use crate::bus::IN_FLAG_PHASE_VALID;
        use crate::program::{ProgramBuilder, REG_AMP_UM, REG_PHASE_DEG};
        let features = FeatureConfig { window_samples: 800, ..FeatureConfig::DEFAULT };
        let (servo, check) = Servo::new(features, ServoConfig::default(), FeedforwardParams::default());
        assert_eq!(check, Ok(()));
        let mut servo = std::boxed::Box::new(servo);
        let rings = std::boxed::Box::new(DefaultSpectralRings::new());
        let commands = std::boxed::Box::new(DefaultCommandRing::new());
        let mut models = std::boxed::Box::new(Models::new());
        let mut b = ProgramBuilder::new();
        b.constant(2.0).feature(4).mul().store(REG_AMP_UM).constant(0.0).store(REG_PHASE_DEG);
        b.term(TickTerm::Harmonic { order: 3, amp_reg: 0, phase_reg: 1 });
        models.upload(b.finish().unwrap(), true).unwrap();
        let mut waiting: Option<(u64, ModelRequest)> = None;
        let mut applied_on = std::vec::Vec::new();
        let mut updates = 0;
        for k in 0..6000u32 {
            let input = InputSlot {
                tick: k,
                acc_code: ((k * 7919) % 4001) as i16 - 2000,
                flags: IN_FLAG_PHASE_VALID,
                cmd_phase_turns: k.wrapping_mul(STEP_40HZ as u32),
                cmd_pos_nm: 0,
                ..Default::default()
            };
            let busy = servo.tick_is_busy(0);
            servo.tick(&rings, &commands, &input);
            if servo.counters().model_updates != updates {
                updates = servo.counters().model_updates;
                applied_on.push((k, busy));
            }
            if let Some(request) = servo.take_request() {
                // Late by 17..=23 ticks: past the due tick (16 later), on every phase.
                waiting = Some((u64::from(k) + 17 + u64::from(k % 7), request));
            }
            if let Some((at, request)) = waiting.filter(|(at, _)| *at == u64::from(k)) {
                let path = *servo.analogue_path();
                servo.deliver(models.compute(&rings, &commands, &request, &path));
                let _ = at;
                waiting = None;
            }
        }
        assert!(applied_on.len() > 50, "{}", applied_on.len());
        assert!(applied_on.iter().all(|(_, busy)| !busy), "{applied_on:?}");
        assert_eq!(servo.counters().model_late, servo.counters().model_updates);
    }
}
