//! The mps2-an386 hardware the firmware touches, as raw CMSDK registers (there is no PAC):
//! the vector table, TIMER0 (the servo tick), UART0 (the control link), the NVIC setup.

use core::ptr::{read_volatile, write_volatile};

use cortex_m::interrupt::InterruptNumber;
use cortex_m::peripheral::NVIC;
use sts_twin_board::qemu::QemuBoard;
use sts_twin_board::sync::ByteQueue;
use sts_twin_board::{ControlLink, TickSource};

/// External interrupt numbers of the board (AN385/AN386 map).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u16)]
pub enum Irq {
    /// UART0 receive.
    Uart0Rx = 0,
    /// UART0 transmit.
    Uart0Tx = 1,
    /// CMSDK TIMER0: the servo tick.
    Timer0 = 8,
    /// Not wired to any device: pended by software to run the model executor.
    ModelExecutor = 30,
}

// SAFETY: the numbers are valid external interrupts of the board's NVIC (32 lines).
unsafe impl InterruptNumber for Irq {
    fn number(self) -> u16 {
        self as u16
    }
}

/// NVIC priorities (upper bits count; lower number = more urgent).
pub mod prio {
    /// The servo tick preempts everything.
    pub const SERVO: u8 = 0x00;
    /// The control link's byte shuffling.
    pub const UART: u8 = 0x40;
    /// The model executor (background work and control protocol).
    pub const MODEL: u8 = 0x80;
}

/// One vector-table entry.
pub union Vector {
    handler: unsafe extern "C" fn(),
    reserved: usize,
}

extern "C" {
    fn UART0RX();
    fn UART0TX();
    fn TIMER0();
    fn MODEL_EXECUTOR();
    fn DefaultHandler();
}

const fn default() -> Vector {
    Vector { handler: DefaultHandler }
}

/// The external interrupt vectors (cortex-m-rt's `device` feature places them after the
/// core exceptions).
#[link_section = ".vector_table.interrupts"]
#[no_mangle]
pub static __INTERRUPTS: [Vector; 32] = {
    let mut v = [const { Vector { reserved: 0 } }; 32];
    let mut i = 0;
    while i < 32 {
        v[i] = default();
        i += 1;
    }
    v[Irq::Uart0Rx as usize] = Vector { handler: UART0RX };
    v[Irq::Uart0Tx as usize] = Vector { handler: UART0TX };
    v[Irq::Timer0 as usize] = Vector { handler: TIMER0 };
    v[Irq::ModelExecutor as usize] = Vector { handler: MODEL_EXECUTOR };
    v
};

#[inline(always)]
fn rd(addr: usize) -> u32 {
    // SAFETY: callers pass register addresses of this board's peripherals.
    unsafe { read_volatile(addr as *const u32) }
}

#[inline(always)]
fn wr(addr: usize, value: u32) {
    // SAFETY: as in `rd`.
    unsafe { write_volatile(addr as *mut u32, value) }
}

/// Timer counts per servo period (the same on both MPS2 images).
pub const SERVO_PERIOD_COUNTS: u32 = QemuBoard::An386.servo_period_counts();

const TIMER0_BASE: usize = 0x4000_0000;
const TIMER_CTRL: usize = 0x00;
const TIMER_VALUE: usize = 0x04;
const TIMER_RELOAD: usize = 0x08;
const TIMER_INT: usize = 0x0C;
const TIMER_CTRL_ENABLE: u32 = 1 << 0;
const TIMER_CTRL_IRQ_ENABLE: u32 = 1 << 3;

/// CMSDK TIMER0 as the 8 kHz servo tick (25 MHz clock, 3125 counts a period).
///
/// Under `-icount` the timer counts guest instructions, so `resync` restarting the period
/// when the host's input arrived makes everything after the wait independent of how long
/// the host took (see docs/firmware.md, "Determinism").
#[derive(Debug)]
pub struct Timer0;

impl Timer0 {
    /// Starts the periodic tick with its interrupt enabled at the NVIC.
    pub fn start(nvic: &mut NVIC) {
        wr(TIMER0_BASE + TIMER_CTRL, 0);
        wr(TIMER0_BASE + TIMER_RELOAD, SERVO_PERIOD_COUNTS);
        wr(TIMER0_BASE + TIMER_VALUE, SERVO_PERIOD_COUNTS);
        wr(TIMER0_BASE + TIMER_INT, 1);
        // SAFETY: priorities are set before unmasking; no priority-based critical sections.
        unsafe {
            nvic.set_priority(Irq::Timer0, prio::SERVO);
            NVIC::unmask(Irq::Timer0);
        }
        wr(TIMER0_BASE + TIMER_CTRL, TIMER_CTRL_ENABLE | TIMER_CTRL_IRQ_ENABLE);
    }

    /// Timer counts `f` takes, with the timer free-running and its interrupt off: for
    /// benchmarks at boot, before [`Timer0::start`].
    pub fn count<R>(f: impl FnOnce() -> R) -> (R, u32) {
        wr(TIMER0_BASE + TIMER_CTRL, 0);
        wr(TIMER0_BASE + TIMER_RELOAD, u32::MAX);
        wr(TIMER0_BASE + TIMER_VALUE, u32::MAX);
        wr(TIMER0_BASE + TIMER_CTRL, TIMER_CTRL_ENABLE);
        let start = Self::value();
        let result = f();
        let end = Self::value();
        wr(TIMER0_BASE + TIMER_CTRL, 0);
        (result, start.wrapping_sub(end))
    }

    /// The current down-counter value.
    #[inline(always)]
    pub fn value() -> u32 {
        rd(TIMER0_BASE + TIMER_VALUE)
    }
}

impl TickSource for Timer0 {
    fn period_counts(&self) -> u32 {
        SERVO_PERIOD_COUNTS
    }

    #[inline(always)]
    fn ack(&mut self) {
        wr(TIMER0_BASE + TIMER_INT, 1);
    }

    #[inline(always)]
    fn resync(&mut self) {
        // Restart the count first, so no expiry can slip in between the clears.
        wr(TIMER0_BASE + TIMER_VALUE, SERVO_PERIOD_COUNTS);
        wr(TIMER0_BASE + TIMER_INT, 1);
        NVIC::unpend(Irq::Timer0);
    }

    #[inline(always)]
    fn elapsed_counts(&self) -> u32 {
        SERVO_PERIOD_COUNTS.saturating_sub(Self::value())
    }

    #[inline(always)]
    fn overran(&mut self) -> bool {
        rd(TIMER0_BASE + TIMER_INT) & 1 != 0
    }
}

const UART0_BASE: usize = 0x4000_4000;
const UART_DATA: usize = 0x00;
const UART_STATE: usize = 0x04;
const UART_CTRL: usize = 0x08;
const UART_INT: usize = 0x0C;
const UART_BAUDDIV: usize = 0x10;
const UART_STATE_TXFULL: u32 = 1 << 0;
const UART_STATE_RXFULL: u32 = 1 << 1;
const UART_CTRL_TX_EN: u32 = 1 << 0;
const UART_CTRL_RX_EN: u32 = 1 << 1;
const UART_CTRL_TX_INT: u32 = 1 << 2;
const UART_CTRL_RX_INT: u32 = 1 << 3;
const UART_INT_TX: u32 = 1 << 0;
const UART_INT_RX: u32 = 1 << 1;

/// Receive queue: the RX interrupt fills it, the background drains it.
pub static UART_RX: ByteQueue<512> = ByteQueue::new();
/// Transmit queue: the background fills it, the TX interrupt drains it.
pub static UART_TX: ByteQueue<2048> = ByteQueue::new();

/// CMSDK UART0 as the control link: interrupt-driven both ways through [`UART_RX`] and
/// [`UART_TX`].
#[derive(Debug)]
pub struct Uart0Link;

impl Uart0Link {
    /// Enables the UART and its interrupts.
    pub fn start(nvic: &mut NVIC) {
        wr(UART0_BASE + UART_BAUDDIV, 16);
        wr(UART0_BASE + UART_CTRL, UART_CTRL_TX_EN | UART_CTRL_RX_EN | UART_CTRL_TX_INT | UART_CTRL_RX_INT);
        // SAFETY: as in `Timer0::start`.
        unsafe {
            nvic.set_priority(Irq::Uart0Rx, prio::UART);
            nvic.set_priority(Irq::Uart0Tx, prio::UART);
            NVIC::unmask(Irq::Uart0Rx);
            NVIC::unmask(Irq::Uart0Tx);
        }
    }

    /// RX interrupt body: moves every received byte into [`UART_RX`]; returns how many.
    #[inline(always)]
    pub fn on_rx_interrupt() -> u32 {
        wr(UART0_BASE + UART_INT, UART_INT_RX);
        let mut n = 0;
        while rd(UART0_BASE + UART_STATE) & UART_STATE_RXFULL != 0 {
            UART_RX.push(rd(UART0_BASE + UART_DATA) as u8);
            n += 1;
        }
        n
    }

    /// TX interrupt body: feeds queued bytes while the transmitter takes them. The only
    /// consumer of [`UART_TX`]. The TX flag is cleared first and never after the loop, so a
    /// completion raised meanwhile is not lost.
    #[inline(always)]
    pub fn on_tx_interrupt() {
        wr(UART0_BASE + UART_INT, UART_INT_TX);
        while rd(UART0_BASE + UART_STATE) & UART_STATE_TXFULL == 0 {
            match UART_TX.pop() {
                Some(b) => wr(UART0_BASE + UART_DATA, u32::from(b)),
                None => break,
            }
        }
    }
}

impl ControlLink for Uart0Link {
    fn read(&mut self, buf: &mut [u8]) -> usize {
        UART_RX.pop_slice(buf)
    }

    fn write(&mut self, bytes: &[u8]) -> usize {
        let n = UART_TX.push_slice(bytes);
        if n > 0 {
            NVIC::pend(Irq::Uart0Tx);
        }
        n
    }
}
