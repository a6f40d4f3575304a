//! # sts-twin-firmware-riscv
//!
//! The twin firmware for QEMU RISC-V `virt` (RV32IMAC, machine mode, no FPU: the core's f32
//! work runs in software). The same application, bus and control protocol as the Cortex-M
//! app (`firmware/qemu-app`): what does not depend on the processor is
//! `sts_twin_board::qemu_app`; this crate adds the hardware ([`hw`]):
//!
//! 1. The goldfish RTC's alarm, the 8 kHz servo tick (PLIC priority 2): waits (bounded) for
//!    the host's input `k` on the virtual analogue bus, runs the tick, writes output `k`.
//!    Never logs.
//! 2. The 16550 UART (PLIC priority 1): moves control-link bytes between the UART and two
//!    queues. Interrupts do not nest: a pending tick is claimed before the UART.
//! 3. Thread mode: embassy's executor running the background half (model work, control
//!    protocol) and all logging, idling with WFI. The tick only marks the executor pending;
//!    the idle loop wakes the background task ([`Events::wake_deferred`]), so that the wake's
//!    cost stays out of the tick.
//!
//! Logs are defmt over semihosting; a panic or an exception ends QEMU with a failing status.
#![no_std]
#![no_main]
#![deny(missing_docs)]

mod hw;

use core::sync::atomic::{AtomicBool, Ordering};

use defmt_semihosting as _;
use embassy_executor::raw::Executor;
use riscv::interrupt::Interrupt;
use sts_twin_board::qemu::{self, QemuBoard};
use sts_twin_board::qemu_app::{
    open_region, paper_eval_counts, BackgroundDiag, Diag, QemuConfigStore, RxBytes, ServoContext,
};
use sts_twin_board::servo::{background_loop, BackgroundApp, BackgroundCtx, ServoCounters, EVENT_CONTROL_RX};
use sts_twin_board::sync::{BootCell, Events, SharedCell};
use sts_twin_board::twin::{TwinBackground, TwinServo, TwinShared};

use hw::{plic, RtcTick, Source, Uart0Link};

type Servo = ServoContext<TwinServo, RtcTick>;

/// Owned by the tick's handler.
static SERVO: BootCell<Servo> = BootCell::new();
/// Shared by the servo tick and the background (a critical-section cell).
static SHARED: BootCell<SharedCell<TwinShared>> = BootCell::new();
/// The diagnostics block, for the UART handler (read-only use).
static RX_DIAG: BootCell<Diag> = BootCell::new();
static RX_BYTES: RxBytes = RxBytes::new();
/// Owned by the background task.
static BACKGROUND: BootCell<(TwinBackground, QemuConfigStore)> = BootCell::new();
/// The thread-mode executor.
static EXECUTOR: BootCell<Executor> = BootCell::new();

static COUNTERS: ServoCounters = ServoCounters::new();
/// The servo tick only marks the executor pending; the idle loop wakes the background task.
static EVENTS: Events = Events::with_deferred_wake(pend_executor);
/// Set when the executor has work: a task was woken or the tick raised an event.
static PENDED: AtomicBool = AtomicBool::new(false);

fn pend_executor() {
    PENDED.store(true, Ordering::Release);
}

/// The executor's pender (embassy's hook): a woken task sets the flag the idle loop checks.
#[export_name = "__pender"]
fn pender(_context: *mut ()) {
    pend_executor();
}

defmt::timestamp!("tick {=u32}", COUNTERS.ticks.load(Ordering::Relaxed));

/// Ends QEMU with a failing status.
fn fail() -> ! {
    semihosting::process::exit(1)
}

#[riscv_rt::entry]
fn main() -> ! {
    let board = QemuBoard::RiscvVirt;
    hw::park_clint_timer();
    // SAFETY: this is the board; memory.x links nothing into the RAM's upper half.
    let region = unsafe {
        open_region(
            board,
            env!("CARGO_PKG_VERSION"),
            hw::SERVO_PERIOD_COUNTS,
            || paper_eval_counts(|f| RtcTick::count(f).1),
            fail,
        )
    };
    let bus = region.bus();
    let diag = region.diag();

    // SAFETY: no interrupt is enabled yet.
    let (shared, (background, config), executor) = unsafe {
        let shared: &'static SharedCell<TwinShared> = SHARED.init(SharedCell::new(TwinShared::new()));
        RX_DIAG.init(diag);
        let background = BACKGROUND.init((TwinBackground::new(), region.config_store()));
        (shared, background, &*EXECUTOR.init(Executor::new(core::ptr::null_mut())))
    };
    // What the boot hook loads (stored settings) is in force from tick 0.
    let mut link = Uart0Link;
    background.on_boot(&mut BackgroundCtx { shared, link: &mut link, config, counters: &COUNTERS });
    executor.spawner().spawn(background_task(background, config, shared, diag).unwrap());

    Uart0Link::start();
    bus.set_ready(0);
    defmt::info!("serving the bus: 8 kHz tick, spin bound {=u32} polls", qemu::BUS_SPIN_BOUND);
    let mut tick = RtcTick::new();
    tick.start();
    // SAFETY: interrupts are still off; from here on the tick's handler owns the context.
    unsafe {
        SERVO.init(ServoContext::new(TwinServo, region, tick));
        riscv::interrupt::enable_interrupt(Interrupt::MachineExternal);
        riscv::interrupt::enable();
    }
    loop {
        EVENTS.wake_deferred();
        // SAFETY: the executor is polled from this loop only.
        unsafe { executor.poll() };
        critical_section::with(|_| {
            // WFI with interrupts masked still wakes on a pending one, which is taken when
            // the critical section ends: no wake-up is lost between the check and the WFI.
            if !PENDED.swap(false, Ordering::Acquire) {
                riscv::asm::wfi();
            }
        });
    }
}

#[embassy_executor::task]
async fn background_task(
    app: &'static mut TwinBackground,
    config: &'static mut QemuConfigStore,
    shared: &'static SharedCell<TwinShared>,
    diag: Diag,
) {
    let mut link = Uart0Link;
    let mut ctx = BackgroundCtx { shared, link: &mut link, config, counters: &COUNTERS };
    let mut bookkeeping = BackgroundDiag::new(diag);
    background_loop(app, &mut ctx, &EVENTS, |bits, counters| {
        bookkeeping.after_events(bits, counters, RtcTick::into_period(), hw::UART_RX.dropped() as u32);
    })
    .await
}

/// Every device interrupt: the PLIC hands out the pending sources, the tick first.
#[riscv_rt::core_interrupt(Interrupt::MachineExternal)]
fn machine_external() {
    loop {
        let source = plic::claim();
        if source == Source::Rtc as u32 {
            // SAFETY: initialised before interrupts were enabled; this handler is the only user.
            let s = unsafe { SERVO.get() };
            // SAFETY: initialised before; shared access only.
            let shared = unsafe { SHARED.get() };
            s.serve(shared, &COUNTERS, &EVENTS);
        } else if source == Source::Uart0 as u32 {
            let n = Uart0Link::on_interrupt();
            if n > 0 {
                // SAFETY: initialised before interrupts were enabled; read-only.
                RX_BYTES.add(n, *unsafe { RX_DIAG.get() });
                EVENTS.raise(EVENT_CONTROL_RX);
            }
        } else if source == 0 {
            return;
        } else {
            defmt::error!("unexpected PLIC source {=u32}", source);
            fail();
        }
        plic::complete(source);
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    riscv::interrupt::disable();
    defmt::error!("panic: {}", defmt::Display2Format(info));
    fail()
}

/// Any exception (a fault, an illegal instruction): logged, then QEMU ends failing.
#[export_name = "ExceptionHandler"]
fn exception_handler(frame: &riscv_rt::TrapFrame) -> ! {
    let mcause = riscv::register::mcause::read().bits();
    let mepc = riscv::register::mepc::read();
    defmt::error!("exception: mcause={=usize:#x} mepc={=usize:#010x} ra={=usize:#010x}", mcause, mepc, frame.ra);
    fail()
}

/// A core interrupt the firmware does not use.
#[export_name = "DefaultHandler"]
fn default_handler() {
    defmt::error!("unexpected interrupt: mcause={=usize:#x}", riscv::register::mcause::read().bits());
    fail()
}
