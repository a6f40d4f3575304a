//! # sts-twin-firmware
//!
//! The firmware for QEMU `mps2-an386` (Cortex-M4F) and `mps2-an500` (Cortex-M7, the
//! STM32H7's core): one image for both, which reads the board's SCC ID at boot to find the
//! shared PSRAM ([`qemu::Mps2Image`]). Interrupt priorities, most urgent first:
//!
//! 1. TIMER0, the 8 kHz servo tick: waits (bounded) for the host's input `k` on the
//!    virtual analogue bus, runs [`ServoApp::tick`], writes output `k`. Never logs.
//! 2. UART0 RX/TX: moves control-link bytes between the UART and two queues.
//! 3. IRQ 30 (not wired to a device): an embassy `InterruptExecutor` running the
//!    background half ([`BackgroundApp`]: model work, control protocol) and all logging.
//!
//! Thread mode idles with WFI. Logs are defmt over semihosting; a panic or HardFault ends
//! QEMU with a failing exit status. docs/firmware.md has the whole story.
//!
//! To plug in another application, change [`App`], [`AppBackground`], [`AppShared`] and
//! [`make_app`].
#![no_std]
#![no_main]
#![deny(missing_docs)]

mod hw;

use core::sync::atomic::Ordering;

use cortex_m_rt::{entry, exception, ExceptionFrame};
use cortex_m_semihosting::debug;
use defmt_semihosting as _;
use embassy_executor::InterruptExecutor;
#[cfg(feature = "bringup")]
use sts_twin_board::bringup::{BringUpBackground, BringUpServo, BringUpShared};
use sts_twin_board::bus::{BusAdc, BusDac, BusView};
use sts_twin_board::config::{AbStore, MemoryMedium};
use sts_twin_board::qemu::{self, Mps2Image, DIAG_WORDS};
use sts_twin_board::servo::{
    background_loop, run_tick, BackgroundApp, BackgroundCtx, ServoCounters, TickResult, TickState, EVENT_CONTROL_RX,
    EVENT_MODEL_WORK, EVENT_UNDERRUN,
};
use sts_twin_board::sync::{BootCell, Events, SharedCell};
#[cfg(not(feature = "bringup"))]
use sts_twin_board::twin::{TwinBackground, TwinServo, TwinShared};

use hw::{Irq, Timer0, Uart0Link};
use sts_twin_board::TickSource;

/// The servo half of the application.
#[cfg(not(feature = "bringup"))]
pub type App = TwinServo;
/// The background half of the application.
#[cfg(not(feature = "bringup"))]
pub type AppBackground = TwinBackground;
/// The state the two halves share.
#[cfg(not(feature = "bringup"))]
pub type AppShared = TwinShared;

/// Builds the application at boot.
#[cfg(not(feature = "bringup"))]
fn make_app() -> (App, AppBackground, AppShared) {
    (TwinServo, TwinBackground::new(), TwinShared::new())
}

/// The servo half of the application.
#[cfg(feature = "bringup")]
pub type App = BringUpServo;
/// The background half of the application.
#[cfg(feature = "bringup")]
pub type AppBackground = BringUpBackground;
/// The state the two halves share.
#[cfg(feature = "bringup")]
pub type AppShared = BringUpShared;

/// Builds the application at boot.
#[cfg(feature = "bringup")]
fn make_app() -> (App, AppBackground, AppShared) {
    (BringUpServo::new(), BringUpBackground::new(), BringUpShared::new())
}

/// Everything the servo interrupt owns.
struct ServoContext {
    app: App,
    bus: BusView,
    diag: Diag,
    adc: BusAdc,
    dac: BusDac,
    timer: Timer0,
    state: TickState,
    handler_last: u32,
    handler_max: u32,
}

type QemuConfigStore = AbStore<MemoryMedium>;

/// Owned by the TIMER0 interrupt.
static SERVO: BootCell<ServoContext> = BootCell::new();
/// Shared by the servo tick and the background (a critical-section cell).
static SHARED: BootCell<SharedCell<AppShared>> = BootCell::new();
/// The diagnostics block, for the UART receive handler (read-only use).
static RX_DIAG: BootCell<Diag> = BootCell::new();
/// Owned by the background task.
static BACKGROUND: BootCell<(AppBackground, QemuConfigStore)> = BootCell::new();

static COUNTERS: ServoCounters = ServoCounters::new();
/// The servo tick only pends the model executor; its interrupt wakes the background task.
static EVENTS: Events = Events::with_deferred_wake(pend_model_executor);

fn pend_model_executor() {
    cortex_m::peripheral::NVIC::pend(Irq::ModelExecutor);
}
static MODEL_EXEC: InterruptExecutor = InterruptExecutor::new();

defmt::timestamp!("tick {=u32}", COUNTERS.ticks.load(Ordering::Relaxed));

/// The board QEMU emulates, from its SCC ID register.
fn board() -> Option<Mps2Image> {
    // SAFETY: the SCC ID register is a read-only word present on every MPS2 image.
    Mps2Image::from_scc_id(unsafe { (qemu::SCC_ID_ADDR as *const u32).read_volatile() })
}

/// The diagnostics block in the PSRAM. Copyable: it is only a pointer.
#[derive(Clone, Copy)]
struct Diag(*mut u32);

// SAFETY: the block is plain memory read by the host; each word has one writing context.
unsafe impl Send for Diag {}

impl Diag {
    fn of(board: Mps2Image) -> Self {
        Self((board.psram_base() + qemu::DIAG_OFFSET) as *mut u32)
    }

    fn write(self, word: usize, value: u32) {
        debug_assert!(word < DIAG_WORDS);
        // SAFETY: the diagnostics block lies in the PSRAM, written by the firmware only.
        unsafe { self.0.add(word).write_volatile(value) }
    }
}

fn config_store(board: Mps2Image) -> QemuConfigStore {
    // SAFETY: the config region lies in the PSRAM after the bus and diagnostics block and
    // is used by this one store.
    AbStore::new(unsafe {
        MemoryMedium::new((board.psram_base() + qemu::CONFIG_OFFSET) as *mut u8, qemu::CONFIG_SLOT_BYTES)
    })
}

/// Ends QEMU with a failing status.
fn fail() -> ! {
    loop {
        debug::exit(debug::EXIT_FAILURE);
    }
}

/// Timer counts of one evaluation of the built-in paper program on typical features (those
/// of a 40 Hz, 3 um motion), the mean of 16, for the benchmark of one model evaluation.
fn paper_eval_counts() -> u32 {
    const RUNS: u32 = 16;
    let program = sts_twin_core::program::paper_program();
    let features = [40.0f32, 0.112, 0.0155, 0.181, 0.124, 1.50, 0.0007, 1.46, 1.62, 1.11, 40.0, 0.0152];
    let (_, counts) = Timer0::count(|| {
        for _ in 0..RUNS {
            let _ = core::hint::black_box(program.evaluate(core::hint::black_box(&features)));
        }
    });
    counts / RUNS
}

#[entry]
fn main() -> ! {
    let mut core = cortex_m::Peripherals::take().unwrap();
    let Some(board) = board() else {
        defmt::error!("not an MPS2 AN386 or AN500 (SCC ID): this image runs on QEMU mps2-an386 or mps2-an500");
        fail();
    };
    defmt::info!(
        "sts-twin firmware {=str} on {=str} ({=str})",
        env!("CARGO_PKG_VERSION"),
        board.qemu_machine(),
        board.core()
    );
    // SAFETY: the PSRAM is not used by the linker (memory.x) and is the bus.
    let bus = unsafe { BusView::new(board.psram_base() as *mut u32) };
    if !bus.header_valid() {
        defmt::error!(
            "no analogue bus at PSRAM {=usize:#x} (magic/version): start QEMU through the sts-twin HIL harness",
            board.psram_base()
        );
        fail();
    }
    let diag = Diag::of(board);
    diag.write(qemu::DIAG_MAGIC, qemu::DIAG_MAGIC_VALUE);
    diag.write(qemu::DIAG_PERIOD_COUNTS, qemu::SERVO_PERIOD_COUNTS);
    diag.write(qemu::DIAG_PAPER_EVAL_COUNTS, paper_eval_counts());

    let (app, background, shared) = make_app();
    // SAFETY: no interrupt is enabled yet.
    let (shared, (background, config)) = unsafe {
        let shared: &'static SharedCell<AppShared> = SHARED.init(SharedCell::new(shared));
        SERVO.init(ServoContext {
            app,
            bus,
            diag,
            adc: BusAdc::new(bus, qemu::BUS_SPIN_BOUND),
            dac: BusDac::new(bus),
            timer: Timer0,
            state: TickState::default(),
            handler_last: 0,
            handler_max: 0,
        });
        RX_DIAG.init(diag);
        (shared, BACKGROUND.init((background, config_store(board))))
    };
    // What the boot hook loads (stored settings) is in force from tick 0.
    let mut link = Uart0Link;
    background.on_boot(&mut BackgroundCtx { shared, link: &mut link, config, counters: &COUNTERS });

    Uart0Link::start(&mut core.NVIC);
    // SAFETY: priority set before the executor unmasks its interrupt.
    unsafe { core.NVIC.set_priority(Irq::ModelExecutor, hw::prio::MODEL) };
    let spawner = MODEL_EXEC.start(Irq::ModelExecutor);
    spawner.spawn(background_task(background, config, shared, diag).unwrap());

    bus.set_ready(0);
    defmt::info!("serving the bus: 8 kHz tick, spin bound {=u32} polls", qemu::BUS_SPIN_BOUND);
    Timer0::start(&mut core.NVIC);
    loop {
        // WFI, not WFE: QEMU treats WFE as a yield and would spin a host core.
        cortex_m::asm::wfi();
    }
}

#[embassy_executor::task]
async fn background_task(
    app: &'static mut AppBackground,
    config: &'static mut QemuConfigStore,
    shared: &'static SharedCell<AppShared>,
    diag: Diag,
) {
    let mut link = Uart0Link;
    let mut ctx = BackgroundCtx { shared, link: &mut link, config, counters: &COUNTERS };
    let mut last_underruns = 0;
    let mut timing_hash: u32 = 0x811C_9DC5;
    background_loop(app, &mut ctx, &EVENTS, |bits, counters| {
        if bits & EVENT_MODEL_WORK != 0 {
            // Where the model work ended relative to the ticks: deterministic under -icount
            // whatever the host's pace; the platform tests compare it across runs.
            let ticks = counters.ticks.load(Ordering::Relaxed);
            let into_period = qemu::SERVO_PERIOD_COUNTS.saturating_sub(Timer0::value());
            for v in [ticks, into_period] {
                timing_hash = (timing_hash ^ v).wrapping_mul(0x0100_0193);
            }
            diag.write(qemu::DIAG_MODEL_TIMING_HASH, timing_hash);
        }
        diag.write(qemu::DIAG_MODEL_REQUESTS, counters.model_requests.load(Ordering::Relaxed));
        diag.write(qemu::DIAG_MODEL_RUNS, counters.model_runs.load(Ordering::Relaxed));
        diag.write(qemu::DIAG_CONTROL_RX_DROPPED, hw::UART_RX.dropped() as u32);
        if bits & EVENT_UNDERRUN != 0 {
            let underruns = counters.underruns.load(Ordering::Relaxed);
            defmt::warn!(
                "underrun: the host's input for tick {=u32} is late ({=u32} underruns, {=u32} new)",
                counters.ticks.load(Ordering::Relaxed),
                underruns,
                underruns.wrapping_sub(last_underruns)
            );
            last_underruns = underruns;
        }
        if bits & EVENT_CONTROL_RX != 0 {
            defmt::debug!("control bytes handled");
        }
    })
    .await
}

/// The servo tick.
#[no_mangle]
unsafe extern "C" fn TIMER0() {
    // SAFETY: initialised before TIMER0 was unmasked; this handler is the only user.
    let s = unsafe { SERVO.get() };
    // SAFETY: initialised before; shared access only.
    let shared = unsafe { SHARED.get() };
    let result = run_tick(&mut s.adc, &mut s.dac, &mut s.timer, &mut s.app, shared, &mut s.state, &COUNTERS, &EVENTS);
    let t = &s.state.timing;
    s.diag.write(qemu::DIAG_HANDLER_LAST, s.handler_last);
    s.diag.write(qemu::DIAG_HANDLER_MAX, s.handler_max);
    s.bus.write_counters(COUNTERS.underruns.load(Ordering::Relaxed), COUNTERS.overruns.load(Ordering::Relaxed));
    s.diag.write(qemu::DIAG_ENTRY_LAST, t.entry_last);
    s.diag.write(qemu::DIAG_ENTRY_MAX, t.entry_max);
    s.diag.write(qemu::DIAG_BUSY_LAST, t.busy_last);
    s.diag.write(qemu::DIAG_BUSY_MAX, t.busy_max);
    s.diag.write(qemu::DIAG_BUSY_SUM_LO, t.busy_sum as u32);
    s.diag.write(qemu::DIAG_BUSY_SUM_HI, (t.busy_sum >> 32) as u32);
    s.diag.write(qemu::DIAG_INPUT_FAULTS, COUNTERS.input_faults.load(Ordering::Relaxed));
    if result == TickResult::Served {
        // The whole handler after the input arrived, publication included; published with
        // the next tick.
        s.handler_last = s.timer.elapsed_counts();
        s.handler_max = s.handler_max.max(s.handler_last);
    }
}

/// Control link receive.
#[no_mangle]
unsafe extern "C" fn UART0RX() {
    static mut RX_BYTES: u32 = 0;
    let n = Uart0Link::on_rx_interrupt();
    // SAFETY: only this handler touches RX_BYTES.
    let total = unsafe {
        RX_BYTES = RX_BYTES.wrapping_add(n);
        RX_BYTES
    };
    // SAFETY: initialised before the UART interrupts were unmasked; read-only.
    unsafe { RX_DIAG.get() }.write(qemu::DIAG_CONTROL_RX_BYTES, total);
    EVENTS.raise(EVENT_CONTROL_RX);
}

/// Control link transmit.
#[no_mangle]
unsafe extern "C" fn UART0TX() {
    Uart0Link::on_tx_interrupt();
}

/// The model executor.
#[no_mangle]
unsafe extern "C" fn MODEL_EXECUTOR() {
    // Events raised by the servo tick wake the background task here, not in the tick.
    EVENTS.wake_deferred();
    // SAFETY: this is the executor's interrupt, as given to `start`.
    unsafe { MODEL_EXEC.on_interrupt() }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    cortex_m::interrupt::disable();
    defmt::error!("panic: {}", defmt::Display2Format(info));
    fail()
}

#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    defmt::error!("HardFault: pc={=u32:#010x} lr={=u32:#010x}", frame.pc(), frame.lr());
    fail()
}

#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    defmt::error!("unexpected interrupt {=i16}", irqn);
    fail()
}
