//! The QEMU `virt` hardware the firmware touches, as raw registers: the PLIC (interrupt
//! routing and priorities), the goldfish RTC (the servo tick) and the 16550 UART (the
//! control link).

use core::ptr::{read_volatile, write_volatile};
use core::sync::atomic::{AtomicU32, Ordering};

use sts_twin_board::qemu::QemuBoard;
use sts_twin_board::sync::ByteQueue;
use sts_twin_board::{ControlLink, TickSource};

/// Timer counts (nanoseconds) per servo period.
pub const SERVO_PERIOD_COUNTS: u32 = QemuBoard::RiscvVirt.servo_period_counts();

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

#[inline(always)]
fn rd8(addr: usize) -> u8 {
    // SAFETY: as in `rd`, for the UART's byte registers.
    unsafe { read_volatile(addr as *const u8) }
}

#[inline(always)]
fn wr8(addr: usize, value: u8) {
    // SAFETY: as in `rd`.
    unsafe { write_volatile(addr as *mut u8, value) }
}

/// The PLIC's interrupt sources of the devices the firmware uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u32)]
pub enum Source {
    /// The 16550 UART: the control link.
    Uart0 = 10,
    /// The goldfish RTC's alarm: the servo tick.
    Rtc = 11,
}

/// The PLIC, for hart 0 in machine mode (context 0). Without nested interrupts, its
/// priorities decide which pending source is served first: the tick before the UART.
pub mod plic {
    use super::{rd, wr, Source};

    const BASE: usize = 0x0C00_0000;
    const ENABLE_CONTEXT0: usize = BASE + 0x2000;
    const THRESHOLD_CONTEXT0: usize = BASE + 0x20_0000;
    const CLAIM_CONTEXT0: usize = BASE + 0x20_0004;

    /// Priority of the servo tick (the highest pending source is claimed first).
    pub const PRIO_TICK: u32 = 2;
    /// Priority of the control link.
    pub const PRIO_UART: u32 = 1;

    /// Enables `source` at `priority` (above the threshold of 0).
    pub fn enable(source: Source, priority: u32) {
        let n = source as u32;
        wr(BASE + 4 * n as usize, priority);
        let word = ENABLE_CONTEXT0 + 4 * (n as usize / 32);
        wr(word, rd(word) | 1 << (n % 32));
        wr(THRESHOLD_CONTEXT0, 0);
    }

    /// The highest-priority pending source, now claimed (0: none).
    #[inline(always)]
    pub fn claim() -> u32 {
        rd(CLAIM_CONTEXT0)
    }

    /// Ends the handling of a claimed source.
    #[inline(always)]
    pub fn complete(source: u32) {
        wr(CLAIM_CONTEXT0, source);
    }
}

const CLINT_MTIMECMP0_LOW: usize = 0x0200_4000;
const CLINT_MTIMECMP0_HIGH: usize = 0x0200_4004;

/// Parks the CLINT's timer compare at the end of time. It resets to 0, which keeps the
/// machine timer interrupt pending (unused, masked) for ever; QEMU then leaves translated
/// code at every block to look at it, and guest time jumps over idle periods late.
pub fn park_clint_timer() {
    wr(CLINT_MTIMECMP0_HIGH, u32::MAX);
    wr(CLINT_MTIMECMP0_LOW, u32::MAX);
}

const RTC_BASE: usize = 0x0010_1000;
const RTC_TIME_LOW: usize = RTC_BASE;
const RTC_TIME_HIGH: usize = RTC_BASE + 0x04;
const RTC_ALARM_LOW: usize = RTC_BASE + 0x08;
const RTC_ALARM_HIGH: usize = RTC_BASE + 0x0C;
const RTC_IRQ_ENABLED: usize = RTC_BASE + 0x10;
const RTC_CLEAR_INTERRUPT: usize = RTC_BASE + 0x1C;

/// Low word of the RTC time at which the current tick period started, for the background's
/// timing hash.
static PERIOD_START_LOW: AtomicU32 = AtomicU32::new(0);

/// The goldfish RTC's alarm as the 8 kHz servo tick: nanoseconds of guest time
/// (`-rtc clock=vm`), which under `-icount` count executed instructions exactly.
///
/// The alarm is one-shot and armed once per handler, at its end or when the input arrived
/// ([`TickSource::resync`]): the next tick comes one period after the input's arrival, to the
/// nanosecond, however long the host took, and no alarm is pending while the tick waits for
/// the host. (The CLINT's `mtime`, the other timer, counts 100 ns steps: a period restarted
/// from it would start on that grid, wherever in a step the input arrived.)
#[derive(Debug)]
pub struct RtcTick {
    period_start: u64,
    alarm_at: u64,
    armed: bool,
}

impl RtcTick {
    /// The tick, not started.
    pub const fn new() -> Self {
        Self { period_start: 0, alarm_at: 0, armed: false }
    }

    /// The RTC time, ns (the high word is latched by the read of the low one).
    #[inline(always)]
    fn now() -> u64 {
        let low = rd(RTC_TIME_LOW);
        (u64::from(rd(RTC_TIME_HIGH)) << 32) | u64::from(low)
    }

    #[inline(always)]
    fn arm(&mut self, at: u64) {
        self.alarm_at = at;
        self.armed = true;
        // The low word's write sets the alarm.
        wr(RTC_ALARM_HIGH, (at >> 32) as u32);
        wr(RTC_ALARM_LOW, at as u32);
    }

    #[inline(always)]
    fn start_period(&mut self, at: u64) {
        self.period_start = at;
        PERIOD_START_LOW.store(at as u32, Ordering::Relaxed);
    }

    /// Starts the periodic tick with its interrupt enabled at the PLIC.
    pub fn start(&mut self) {
        wr(RTC_IRQ_ENABLED, 1);
        plic::enable(Source::Rtc, plic::PRIO_TICK);
        let now = Self::now();
        self.start_period(now);
        self.arm(now + u64::from(SERVO_PERIOD_COUNTS));
    }

    /// Nanoseconds `f` takes: for benchmarks at boot.
    pub fn count<R>(f: impl FnOnce() -> R) -> (R, u32) {
        let start = rd(RTC_TIME_LOW);
        let result = f();
        (result, rd(RTC_TIME_LOW).wrapping_sub(start))
    }

    /// Nanoseconds into the current tick period.
    pub fn into_period() -> u32 {
        critical_section::with(|_| rd(RTC_TIME_LOW).wrapping_sub(PERIOD_START_LOW.load(Ordering::Relaxed)))
    }
}

impl Default for RtcTick {
    fn default() -> Self {
        Self::new()
    }
}

impl TickSource for RtcTick {
    fn period_counts(&self) -> u32 {
        SERVO_PERIOD_COUNTS
    }

    #[inline(always)]
    fn ack(&mut self) {
        wr(RTC_CLEAR_INTERRUPT, 1);
        // The alarm that fired is the edge of this tick.
        self.start_period(self.alarm_at);
        self.armed = false;
    }

    #[inline(always)]
    fn resync(&mut self) {
        let now = Self::now();
        self.start_period(now);
        self.arm(now + u64::from(SERVO_PERIOD_COUNTS));
    }

    #[inline(always)]
    fn elapsed_counts(&self) -> u32 {
        rd(RTC_TIME_LOW).wrapping_sub(self.period_start as u32)
    }

    #[inline(always)]
    fn overran(&mut self) -> bool {
        if !self.armed {
            // No resync this time (an input fault): the next tick one period after this one.
            self.arm(self.period_start + u64::from(SERVO_PERIOD_COUNTS));
        }
        self.armed = false;
        Self::now() >= self.alarm_at
    }
}

const UART0_BASE: usize = 0x1000_0000;
const UART_RBR_THR_DLL: usize = UART0_BASE;
const UART_IER_DLM: usize = UART0_BASE + 1;
const UART_IIR_FCR: usize = UART0_BASE + 2;
const UART_LCR: usize = UART0_BASE + 3;
const UART_MCR: usize = UART0_BASE + 4;
const UART_LSR: usize = UART0_BASE + 5;
const IER_RX_AVAILABLE: u8 = 1 << 0;
const IER_TX_EMPTY: u8 = 1 << 1;
const IIR_NONE_PENDING: u8 = 1 << 0;
const IIR_ID_MASK: u8 = 0x0E;
const IIR_TX_EMPTY: u8 = 0x02;
const IIR_RX_AVAILABLE: u8 = 0x04;
const IIR_RX_TIMEOUT: u8 = 0x0C;
const LCR_DLAB: u8 = 1 << 7;
const LCR_8N1: u8 = 0x03;
/// FIFOs on and cleared, receive interrupt at the first byte.
const FCR_FIFO_CLEAR_TRIGGER_1: u8 = 0x07;
const MCR_OUT2: u8 = 1 << 3;
const LSR_DATA_READY: u8 = 1 << 0;
const LSR_TX_EMPTY: u8 = 1 << 5;
const TX_FIFO_BYTES: usize = 16;

/// Receive queue: the UART interrupt fills it, the background drains it.
pub static UART_RX: ByteQueue<512> = ByteQueue::new();
/// Transmit queue: the background fills it, the UART interrupt (and [`ControlLink::write`])
/// drains it.
pub static UART_TX: ByteQueue<2048> = ByteQueue::new();

/// The 16550 UART0 as the control link: interrupt-driven both ways through [`UART_RX`] and
/// [`UART_TX`].
#[derive(Debug)]
pub struct Uart0Link;

impl Uart0Link {
    /// Sets 8N1 at the fastest divisor, the FIFOs, and enables the UART's interrupts.
    pub fn start() {
        wr8(UART_IER_DLM, 0);
        wr8(UART_LCR, LCR_DLAB);
        wr8(UART_RBR_THR_DLL, 1);
        wr8(UART_IER_DLM, 0);
        wr8(UART_LCR, LCR_8N1);
        wr8(UART_IIR_FCR, FCR_FIFO_CLEAR_TRIGGER_1);
        wr8(UART_MCR, MCR_OUT2);
        wr8(UART_IER_DLM, IER_RX_AVAILABLE | IER_TX_EMPTY);
        plic::enable(Source::Uart0, plic::PRIO_UART);
    }

    /// Interrupt body: moves received bytes into [`UART_RX`] and queued bytes into the
    /// transmitter until the UART has nothing pending; returns the bytes received.
    #[inline(always)]
    pub fn on_interrupt() -> u32 {
        let mut received = 0;
        loop {
            let iir = rd8(UART_IIR_FCR);
            if iir & IIR_NONE_PENDING != 0 {
                return received;
            }
            match iir & IIR_ID_MASK {
                IIR_RX_AVAILABLE | IIR_RX_TIMEOUT => {
                    while rd8(UART_LSR) & LSR_DATA_READY != 0 {
                        UART_RX.push(rd8(UART_RBR_THR_DLL));
                        received += 1;
                    }
                }
                // Reading IIR cleared it; refill the FIFO.
                IIR_TX_EMPTY => Self::feed(),
                // A line status interrupt: reading LSR clears it.
                _ => {
                    let _ = rd8(UART_LSR);
                }
            }
        }
    }

    /// Fills the empty transmit FIFO from [`UART_TX`]. The FIFO's emptying raises the next
    /// interrupt.
    #[inline(always)]
    fn feed() {
        if rd8(UART_LSR) & LSR_TX_EMPTY == 0 {
            return;
        }
        for _ in 0..TX_FIFO_BYTES {
            match UART_TX.pop() {
                Some(b) => wr8(UART_RBR_THR_DLL, b),
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
            // An idle transmitter raises no interrupt: start it here.
            critical_section::with(|_| Uart0Link::feed());
        }
        n
    }
}
