//! Where the application plugs in: the per-tick work in the servo interrupt
//! ([`ServoApp`]), the model update and the control protocol at a lower priority
//! ([`BackgroundApp`]), and the one per-tick procedure every board runs ([`run_tick`]).
//!
//! Determinism contract: [`ServoApp::tick`] sees input `k` at tick `k`, always. Work the
//! tick hands to the background (by returning [`TickOutcome::request_model_work`]) runs
//! later at a lower priority; its result should be taken up by the tick at a fixed tick
//! offset (e.g. "the result of the work requested at tick `k` is applied at tick `k + D`,
//! or counted late"), never "whenever it is ready", so that the outputs do not depend on
//! how fast the background ran. [`crate::bringup`] shows the pattern.

use core::sync::atomic::{AtomicU32, Ordering};

use sts_twin_core::bus::{InputSlot, OutputSlot};

use crate::sync::{Events, SharedCell};
use crate::{AdcSource, ConfigStore, ControlLink, DacSink, SampleError, TickSource};

/// Event bit: a tick asked for model work.
pub const EVENT_MODEL_WORK: u32 = 1 << 0;
/// Event bit: control-link bytes arrived.
pub const EVENT_CONTROL_RX: u32 = 1 << 1;
/// Event bit: a tick gave up waiting for its input (an underrun was counted).
pub const EVENT_UNDERRUN: u32 = 1 << 2;

/// What a servo tick produces.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TickOutcome {
    /// The tick's output (its `tick` field is set by the platform).
    pub output: OutputSlot,
    /// Ask the background context to run [`BackgroundApp::model_work`].
    pub request_model_work: bool,
}

/// The per-tick processing, run in the servo interrupt at the highest priority.
/// Must be bounded and fast (the budget is a few hundred instructions); never logs.
pub trait ServoApp {
    /// State shared with the background half.
    type Shared;
    /// Processes input `input.tick` and returns the output of the same tick.
    fn tick(&mut self, input: &InputSlot, shared: &SharedCell<Self::Shared>) -> TickOutcome;

    /// A tick period passed without the input (an underrun; the same tick is retried next
    /// period and the DAC holds its value). For counting and for degrading after several in
    /// a row. The default does nothing.
    fn on_underrun(&mut self, shared: &SharedCell<Self::Shared>) {
        let _ = shared;
    }
}

/// What the background half may use.
pub struct BackgroundCtx<'a, S> {
    /// State shared with the servo tick (short critical sections).
    pub shared: &'a SharedCell<S>,
    /// The control channel, for replies.
    pub link: &'a mut dyn ControlLink,
    /// Persistent storage.
    pub config: &'a mut dyn ConfigStore,
    /// The platform's live counters.
    pub counters: &'a ServoCounters,
}

/// The background half, run at a lower priority than the servo tick (one context, so its
/// methods never preempt each other). May log and may take time.
pub trait BackgroundApp {
    /// State shared with the servo half.
    type Shared;
    /// Once at boot, before the first tick (e.g. load the stored configuration).
    fn on_boot(&mut self, ctx: &mut BackgroundCtx<'_, Self::Shared>) {
        let _ = ctx;
    }
    /// Runs after a tick asked for it (several requests may coalesce into one run).
    fn model_work(&mut self, ctx: &mut BackgroundCtx<'_, Self::Shared>);
    /// Bytes received on the control link.
    fn on_control_bytes(&mut self, rx: &[u8], ctx: &mut BackgroundCtx<'_, Self::Shared>);
}

/// Live counters of the platform, readable from any context.
#[derive(Debug, Default)]
pub struct ServoCounters {
    /// Ticks served (outputs written).
    pub ticks: AtomicU32,
    /// Ticks whose input did not arrive in time.
    pub underruns: AtomicU32,
    /// Ticks whose handler ran into the next period.
    pub overruns: AtomicU32,
    /// Input faults reported by the ADC source.
    pub input_faults: AtomicU32,
    /// Model work requests from the tick.
    pub model_requests: AtomicU32,
    /// Model work runs completed by the background.
    pub model_runs: AtomicU32,
}

impl ServoCounters {
    /// All zero.
    pub const fn new() -> Self {
        Self {
            ticks: AtomicU32::new(0),
            underruns: AtomicU32::new(0),
            overruns: AtomicU32::new(0),
            input_faults: AtomicU32::new(0),
            model_requests: AtomicU32::new(0),
            model_runs: AtomicU32::new(0),
        }
    }

    fn bump(c: &AtomicU32) {
        // Single writer per counter (the servo interrupt): load + store, no RMW needed.
        c.store(c.load(Ordering::Relaxed).wrapping_add(1), Ordering::Relaxed);
    }
}

/// Handler timing of the servo tick, in timer counts (owned by the servo interrupt).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TickTiming {
    /// Counts from the tick edge to the start of the input wait, last tick.
    pub entry_last: u32,
    /// Largest `entry_last` so far.
    pub entry_max: u32,
    /// Counts from the input's arrival to the end of the handler, last served tick.
    pub busy_last: u32,
    /// Largest `busy_last` so far.
    pub busy_max: u32,
    /// Sum of `busy_last` over served ticks.
    pub busy_sum: u64,
}

/// State of the servo loop, owned by the servo interrupt.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TickState {
    /// The next tick to serve (= outputs written so far).
    pub next_tick: u32,
    /// Handler timing.
    pub timing: TickTiming,
}

/// What one run of the servo handler did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TickResult {
    /// Tick served: input read, output written.
    Served,
    /// No input in time: underrun counted, the same tick is retried next period.
    Underrun,
    /// The source is paused: nothing done.
    Paused,
    /// The source reported a fault: counted, the tick is retried.
    Fault,
}

/// The servo interrupt's work, for every board: acknowledge the tick, wait (bounded) for
/// input `k`, restart the period, run the application, write output `k`, count.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub fn run_tick<S: ServoApp>(
    adc: &mut impl AdcSource,
    dac: &mut impl DacSink,
    timer: &mut impl TickSource,
    app: &mut S,
    shared: &SharedCell<S::Shared>,
    state: &mut TickState,
    counters: &ServoCounters,
    events: &Events,
) -> TickResult {
    timer.ack();
    let entry = timer.elapsed_counts();
    state.timing.entry_last = entry;
    state.timing.entry_max = state.timing.entry_max.max(entry);
    let k = state.next_tick;
    let result = match adc.sample(k) {
        Ok(input) => {
            timer.resync();
            let outcome = app.tick(&input, shared);
            let mut output = outcome.output;
            output.tick = k;
            dac.write(&output);
            state.next_tick = k.wrapping_add(1);
            ServoCounters::bump(&counters.ticks);
            if outcome.request_model_work {
                ServoCounters::bump(&counters.model_requests);
                events.raise_from_tick(EVENT_MODEL_WORK);
            }
            let busy = timer.elapsed_counts();
            let t = &mut state.timing;
            t.busy_last = busy;
            t.busy_max = t.busy_max.max(busy);
            t.busy_sum += u64::from(busy);
            TickResult::Served
        }
        Err(SampleError::Late) => {
            timer.resync();
            ServoCounters::bump(&counters.underruns);
            app.on_underrun(shared);
            events.raise(EVENT_UNDERRUN);
            TickResult::Underrun
        }
        Err(SampleError::Paused) => {
            timer.resync();
            TickResult::Paused
        }
        Err(SampleError::Fault(_)) => {
            ServoCounters::bump(&counters.input_faults);
            TickResult::Fault
        }
    };
    if timer.overran() {
        ServoCounters::bump(&counters.overruns);
    }
    result
}

/// The background context's loop: model work and control bytes as their events arrive,
/// then `after_events(bits, counters)` (for logging). Never returns. Call
/// [`BackgroundApp::on_boot`] before the servo tick starts, not from here, so that what it
/// loads is in force from tick 0.
pub async fn background_loop<B: BackgroundApp>(
    app: &mut B,
    ctx: &mut BackgroundCtx<'_, B::Shared>,
    events: &Events,
    mut after_events: impl FnMut(u32, &ServoCounters),
) -> ! {
    let mut rx = [0u8; 64];
    loop {
        let bits = events.wait().await;
        if bits & EVENT_CONTROL_RX != 0 {
            loop {
                let n = ctx.link.read(&mut rx);
                if n == 0 {
                    break;
                }
                app.on_control_bytes(&rx[..n], ctx);
            }
        }
        if bits & EVENT_MODEL_WORK != 0 {
            app.model_work(ctx);
            ServoCounters::bump(&ctx.counters.model_runs);
        }
        after_events(bits, ctx.counters);
    }
}
