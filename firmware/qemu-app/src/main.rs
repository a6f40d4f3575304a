//! # sts-twin-firmware
//!
//! The firmware for QEMU `mps2-an386` (Cortex-M4F) and `mps2-an500` (Cortex-M7, the
//! STM32H7's core): one image for both, which reads the board's SCC ID at boot to find the
//! shared PSRAM ([`qemu::QemuBoard`]). Interrupt priorities, most urgent first:
//!
//! 1. TIMER0, the 8 kHz servo tick: waits (bounded) for the host's input `k` on the
//!    virtual analogue bus, runs [`ServoApp::tick`], writes output `k`. Never logs.
//! 2. UART0 RX/TX: moves control-link bytes between the UART and two queues.
//! 3. IRQ 30 (not wired to a device): an embassy `InterruptExecutor` running the
//!    background half ([`BackgroundApp`]: model work, control protocol) and all logging.
//!
//! Thread mode idles with WFI. Logs are defmt over semihosting; a panic or HardFault ends
//! QEMU with a failing exit status. What does not depend on the processor (the servo
//! interrupt's body, the diagnostics) is `sts_twin_board::qemu_app`, shared with the RISC-V
//! app. docs/firmware.md has the whole story.
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
use sts_twin_board::qemu::{self, QemuBoard};
use sts_twin_board::qemu_app::{
    open_region, paper_eval_counts, BackgroundDiag, Diag, QemuConfigStore, RxBytes, ServoContext,
};
use sts_twin_board::servo::{background_loop, BackgroundApp, BackgroundCtx, ServoCounters, EVENT_CONTROL_RX};
use sts_twin_board::sync::{BootCell, Events, SharedCell};
#[cfg(not(feature = "bringup"))]
use sts_twin_board::twin::{TwinBackground, TwinServo, TwinShared};

use hw::{Irq, Timer0, Uart0Link};

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

type Servo = ServoContext<App, Timer0>;

/// Owned by the TIMER0 interrupt.
static SERVO: BootCell<Servo> = BootCell::new();
/// Shared by the servo tick and the background (a critical-section cell).
static SHARED: BootCell<SharedCell<AppShared>> = BootCell::new();
/// The diagnostics block, for the UART receive handler (read-only use).
static RX_DIAG: BootCell<Diag> = BootCell::new();
static RX_BYTES: RxBytes = RxBytes::new();
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
fn board() -> Option<QemuBoard> {
    // SAFETY: the SCC ID register is a read-only word present on every MPS2 image.
    QemuBoard::from_scc_id(unsafe { (qemu::SCC_ID_ADDR as *const u32).read_volatile() })
}

/// Ends QEMU with a failing status.
fn fail() -> ! {
    loop {
        debug::exit(debug::EXIT_FAILURE);
    }
}

#[entry]
fn main() -> ! {
    let mut core = cortex_m::Peripherals::take().unwrap();
    let Some(board) = board() else {
        defmt::error!("not an MPS2 AN386 or AN500 (SCC ID): this image runs on QEMU mps2-an386 or mps2-an500");
        fail();
    };
    // SAFETY: this is the board; the PSRAM is not used by the linker (memory.x).
    let region = unsafe {
        open_region(
            board,
            env!("CARGO_PKG_VERSION"),
            board.servo_period_counts(),
            || paper_eval_counts(|f| Timer0::count(f).1),
            fail,
        )
    };
    let bus = region.bus();
    let diag = region.diag();

    let (app, background, shared) = make_app();
    // SAFETY: no interrupt is enabled yet.
    let (shared, (background, config)) = unsafe {
        let shared: &'static SharedCell<AppShared> = SHARED.init(SharedCell::new(shared));
        SERVO.init(ServoContext::new(app, region, Timer0));
        RX_DIAG.init(diag);
        (shared, BACKGROUND.init((background, region.config_store())))
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
    let mut bookkeeping = BackgroundDiag::new(diag);
    background_loop(app, &mut ctx, &EVENTS, |bits, counters| {
        let into_period = hw::SERVO_PERIOD_COUNTS.saturating_sub(Timer0::value());
        bookkeeping.after_events(bits, counters, into_period, hw::UART_RX.dropped() as u32);
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
    s.serve(shared, &COUNTERS, &EVENTS);
}

/// Control link receive.
#[no_mangle]
unsafe extern "C" fn UART0RX() {
    let n = Uart0Link::on_rx_interrupt();
    // SAFETY: initialised before the UART interrupts were unmasked; read-only.
    RX_BYTES.add(n, *unsafe { RX_DIAG.get() });
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
