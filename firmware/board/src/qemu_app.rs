//! What every QEMU firmware app does the same way, whatever its processor: the views of the
//! shared region ([`Region`]), the diagnostics the firmware publishes ([`Diag`]), the servo
//! interrupt's whole body ([`ServoContext::serve`]) and the background's bookkeeping after
//! each batch of events ([`BackgroundDiag`]). An app adds only its hardware: the tick timer,
//! the control link's UART, the interrupt wiring and the executor's idle loop.

use core::sync::atomic::{AtomicU32, Ordering};

use crate::bus::{BusAdc, BusDac, BusView};
use crate::config::{AbStore, MemoryMedium};
use crate::qemu::{self, QemuBoard};
use crate::servo::{
    run_tick, ServoApp, ServoCounters, TickResult, TickState, EVENT_CONTROL_RX, EVENT_MODEL_WORK, EVENT_UNDERRUN,
};
use crate::sync::{Events, SharedCell};
use crate::TickSource;

/// The config store of a QEMU board: A/B records in the shared region.
pub type QemuConfigStore = AbStore<MemoryMedium>;

/// The shared region of a board, at [`QemuBoard::shared_base`].
#[derive(Clone, Copy, Debug)]
pub struct Region {
    base: usize,
}

impl Region {
    /// The region of `board`.
    ///
    /// # Safety
    /// The firmware runs on `board`, and nothing else in the program (the linker's memory
    /// included) uses its shared region.
    pub const unsafe fn of(board: QemuBoard) -> Self {
        Self { base: board.shared_base() }
    }

    /// Guest address of the region.
    pub const fn base(self) -> usize {
        self.base
    }

    /// The analogue bus at the region's start.
    pub fn bus(self) -> BusView {
        // SAFETY: the bus lies at the region's start, used only through this view.
        unsafe { BusView::new(self.base as *mut u32) }
    }

    /// The diagnostics block.
    pub fn diag(self) -> Diag {
        Diag((self.base + qemu::DIAG_OFFSET) as *mut u32)
    }

    /// The config store. Call once: the store owns its slots.
    pub fn config_store(self) -> QemuConfigStore {
        // SAFETY: the config slots lie in the region after the bus and the diagnostics
        // block, and the caller makes this the one store over them.
        AbStore::new(unsafe {
            MemoryMedium::new((self.base + qemu::CONFIG_OFFSET) as *mut u8, qemu::CONFIG_SLOT_BYTES)
        })
    }
}

/// The boot's first steps on every QEMU board: the banner naming the image (`version`) and the
/// board, then the shared region, whose bus header the HIL harness must have written (else
/// `fail`), with the boot diagnostics published in it: the tick period and, measured only
/// once the bus is there, `paper_eval_counts`.
///
/// # Safety
/// As [`Region::of`]: the firmware runs on `board`, and nothing else in the program uses its
/// shared region.
pub unsafe fn open_region(
    board: QemuBoard,
    version: &str,
    period_counts: u32,
    paper_eval_counts: impl FnOnce() -> u32,
    fail: fn() -> !,
) -> Region {
    #[cfg(feature = "defmt")]
    defmt::info!("sts-twin firmware {=str} on {=str} ({=str})", version, board.qemu_machine(), board.core());
    #[cfg(not(feature = "defmt"))]
    let _ = version;
    // SAFETY: the caller's promise.
    let region = unsafe { Region::of(board) };
    if !region.bus().header_valid() {
        #[cfg(feature = "defmt")]
        defmt::error!(
            "no analogue bus at {=usize:#x} (magic/version): start QEMU through the sts-twin HIL harness",
            region.base()
        );
        fail();
    }
    region.diag().boot(period_counts, paper_eval_counts());
    region
}

/// The diagnostics block in the shared region. Copyable: it is only a pointer.
#[derive(Clone, Copy, Debug)]
pub struct Diag(*mut u32);

// SAFETY: the block is plain memory read by the host; each word has one writing context.
unsafe impl Send for Diag {}
unsafe impl Sync for Diag {}

impl Diag {
    /// Writes diagnostics word `word` (a `DIAG_*` index).
    #[inline(always)]
    pub fn write(self, word: usize, value: u32) {
        debug_assert!(word < qemu::DIAG_WORDS);
        // SAFETY: the block lies in the shared region, written by the firmware only.
        unsafe { self.0.add(word).write_volatile(value) }
    }

    /// Marks the block valid and records what the firmware measured at boot.
    pub fn boot(self, period_counts: u32, paper_eval_counts: u32) {
        self.write(qemu::DIAG_MAGIC, qemu::DIAG_MAGIC_VALUE);
        self.write(qemu::DIAG_PERIOD_COUNTS, period_counts);
        self.write(qemu::DIAG_PAPER_EVAL_COUNTS, paper_eval_counts);
    }
}

/// Timer counts of one evaluation of the built-in paper program on typical features (those
/// of a 40 Hz, 3 um motion), the mean of 16, for the benchmark of one model evaluation.
/// `count` runs the closure it is given and returns the timer counts it took.
pub fn paper_eval_counts(count: impl FnOnce(&mut dyn FnMut()) -> u32) -> u32 {
    const RUNS: u32 = 16;
    let program = sts_twin_core::program::paper_program();
    let features = [40.0f32, 0.112, 0.0155, 0.181, 0.124, 1.50, 0.0007, 1.46, 1.62, 1.11, 40.0, 0.0152];
    let counts = count(&mut || {
        for _ in 0..RUNS {
            let _ = core::hint::black_box(program.evaluate(core::hint::black_box(&features)));
        }
    });
    counts / RUNS
}

/// Everything the servo interrupt owns.
#[derive(Debug)]
pub struct ServoContext<A, T> {
    app: A,
    bus: BusView,
    diag: Diag,
    adc: BusAdc,
    dac: BusDac,
    timer: T,
    state: TickState,
    handler_last: u32,
    handler_max: u32,
}

impl<A: ServoApp, T: TickSource> ServoContext<A, T> {
    /// The servo of `app` on the bus of `region`, ticked by `timer`.
    pub fn new(app: A, region: Region, timer: T) -> Self {
        let bus = region.bus();
        Self {
            app,
            bus,
            diag: region.diag(),
            adc: BusAdc::new(bus, qemu::BUS_SPIN_BOUND),
            dac: BusDac::new(bus),
            timer,
            state: TickState::default(),
            handler_last: 0,
            handler_max: 0,
        }
    }

    /// The servo interrupt's body: one tick ([`run_tick`]), then the counters and the
    /// handler timing published for the host.
    #[inline(always)]
    pub fn serve(&mut self, shared: &SharedCell<A::Shared>, counters: &ServoCounters, events: &Events) {
        let s = self;
        let result = run_tick(&mut s.adc, &mut s.dac, &mut s.timer, &mut s.app, shared, &mut s.state, counters, events);
        let t = &s.state.timing;
        s.diag.write(qemu::DIAG_HANDLER_LAST, s.handler_last);
        s.diag.write(qemu::DIAG_HANDLER_MAX, s.handler_max);
        s.bus.write_counters(counters.underruns.load(Ordering::Relaxed), counters.overruns.load(Ordering::Relaxed));
        s.diag.write(qemu::DIAG_ENTRY_LAST, t.entry_last);
        s.diag.write(qemu::DIAG_ENTRY_MAX, t.entry_max);
        s.diag.write(qemu::DIAG_BUSY_LAST, t.busy_last);
        s.diag.write(qemu::DIAG_BUSY_MAX, t.busy_max);
        s.diag.write(qemu::DIAG_BUSY_SUM_LO, t.busy_sum as u32);
        s.diag.write(qemu::DIAG_BUSY_SUM_HI, (t.busy_sum >> 32) as u32);
        s.diag.write(qemu::DIAG_INPUT_FAULTS, counters.input_faults.load(Ordering::Relaxed));
        if result == TickResult::Served {
            // The whole handler after the input arrived, publication included; published with
            // the next tick.
            s.handler_last = s.timer.elapsed_counts();
            s.handler_max = s.handler_max.max(s.handler_last);
        }
    }
}

/// Control bytes received, published in the diagnostics block by the receive interrupt.
#[derive(Debug)]
pub struct RxBytes(AtomicU32);

impl RxBytes {
    /// None yet.
    pub const fn new() -> Self {
        Self(AtomicU32::new(0))
    }

    /// Counts `n` more bytes and publishes the total. One writing context (the receive
    /// interrupt).
    #[inline(always)]
    pub fn add(&self, n: u32, diag: Diag) {
        let total = self.0.load(Ordering::Relaxed).wrapping_add(n);
        self.0.store(total, Ordering::Relaxed);
        diag.write(qemu::DIAG_CONTROL_RX_BYTES, total);
    }
}

impl Default for RxBytes {
    fn default() -> Self {
        Self::new()
    }
}

/// The background's bookkeeping after each batch of events: where the model work ended
/// relative to the ticks (a hash the platform tests compare across runs), the counters for
/// the host, and the logs.
#[derive(Debug)]
pub struct BackgroundDiag {
    diag: Diag,
    last_underruns: u32,
    timing_hash: u32,
}

impl BackgroundDiag {
    /// Bookkeeping into `diag`.
    pub const fn new(diag: Diag) -> Self {
        Self { diag, last_underruns: 0, timing_hash: 0x811C_9DC5 }
    }

    /// After the events `bits`: `into_period` is the timer counts into the current tick
    /// period now, `rx_dropped` the control bytes dropped so far.
    pub fn after_events(&mut self, bits: u32, counters: &ServoCounters, into_period: u32, rx_dropped: u32) {
        let diag = self.diag;
        if bits & EVENT_MODEL_WORK != 0 {
            // Deterministic under -icount whatever the host's pace.
            let ticks = counters.ticks.load(Ordering::Relaxed);
            for v in [ticks, into_period] {
                self.timing_hash = (self.timing_hash ^ v).wrapping_mul(0x0100_0193);
            }
            diag.write(qemu::DIAG_MODEL_TIMING_HASH, self.timing_hash);
        }
        diag.write(qemu::DIAG_MODEL_REQUESTS, counters.model_requests.load(Ordering::Relaxed));
        diag.write(qemu::DIAG_MODEL_RUNS, counters.model_runs.load(Ordering::Relaxed));
        diag.write(qemu::DIAG_CONTROL_RX_DROPPED, rx_dropped);
        if bits & EVENT_UNDERRUN != 0 {
            let underruns = counters.underruns.load(Ordering::Relaxed);
            #[cfg(feature = "defmt")]
            defmt::warn!(
                "underrun: the host's input for tick {=u32} is late ({=u32} underruns, {=u32} new)",
                counters.ticks.load(Ordering::Relaxed),
                underruns,
                underruns.wrapping_sub(self.last_underruns)
            );
            self.last_underruns = underruns;
        }
        if bits & EVENT_CONTROL_RX != 0 {
            #[cfg(feature = "defmt")]
            defmt::debug!("control bytes handled");
        }
    }
}
