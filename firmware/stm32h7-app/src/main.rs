//! # sts-twin-board-stm32h7
//!
//! The sts-twin firmware on a real co-processor board: an STM32H743ZI (NUCLEO-H743ZI)
//! next to the motion controller. The same twin application as the QEMU firmware (the
//! servo and background halves of `sts_twin_board::twin`, on the seam of `sts-twin-board`),
//! on real converters:
//!
//! | what | peripheral | pins (NUCLEO-H743ZI) |
//! |---|---|---|
//! | servo tick, 8 kHz, highest priority | TIM2 update interrupt | - |
//! | accelerometer (conditioned to 0..3.3 V) | ADC1 channel 15 | PA3 (CN9 A0) |
//! | Z command position monitor (0..3.3 V) | ADC1 channel 10 | PC0 (CN9 A1) |
//! | spindle encoder (command phase) | TIM3 encoder mode | PB4 / PB5 |
//! | feedforward voltage to the controller | DAC1 channel 1 (12 bit) | PA4 |
//! | control link | USART3, 115200 8N1 | PD8 / PD9 (ST-LINK VCP) |
//! | config store | flash bank 2, sectors 6 and 7 | - |
//!
//! The background half runs in an embassy `InterruptExecutor` on UART4's (unused)
//! interrupt, below the servo tick and the USART. Build: `cargo xtask firmware` at the
//! repository root, or `cargo build --profile firmware` in this directory; flash and run
//! with probe-rs: `cargo run --release` from this directory (see `.cargo/config.toml`).
#![no_std]
#![no_main]
#![deny(missing_docs)]

use core::sync::atomic::{AtomicU32, Ordering};

use defmt_rtt as _;
use embassy_executor::InterruptExecutor;
use embassy_stm32::adc::{Adc, SampleTime};
use embassy_stm32::dac::{DacChannel, Value};
use embassy_stm32::flash::{Blocking, Flash};
use embassy_stm32::interrupt::{self, InterruptExt, Priority};
use embassy_stm32::mode::Blocking as BlockingMode;
use embassy_stm32::peripherals::{ADC1, PA3, PC0, TIM2, TIM3};
use embassy_stm32::time::Hertz;
use embassy_stm32::timer::low_level::{RoundTo, Timer};
use embassy_stm32::timer::qei::{self, Qei};
use embassy_stm32::usart::{self, BufferedUart};
use embassy_stm32::{bind_interrupts, peripherals, Peri};
use panic_probe as _;
use sts_twin_board::config::{AbStore, RecordMedium, HEADER_BYTES};
use sts_twin_board::servo::{
    background_loop, run_tick, BackgroundApp, BackgroundCtx, ServoCounters, TickState, EVENT_CONTROL_RX,
};
use sts_twin_board::sync::{BootCell, Events, SharedCell};
use sts_twin_board::twin::{TwinBackground, TwinServo, TwinShared};
use sts_twin_board::{AdcSource, ConfigError, ControlLink, DacSink, InputSlot, OutputSlot, SampleError, TickSource};
use sts_twin_core::bus::IN_FLAG_PHASE_VALID;

/// The servo half of the application: the twin, as in the QEMU firmware.
pub type App = TwinServo;
/// The background half of the application: model work and the control protocol.
pub type AppBackground = TwinBackground;
/// The state the two halves share.
pub type AppShared = TwinShared;

fn make_app() -> (App, AppBackground, AppShared) {
    (TwinServo, TwinBackground::new(), TwinShared::new())
}

/// Servo rate.
const SERVO_RATE_HZ: u32 = sts_twin_core::SERVO_RATE_HZ;
/// Spindle encoder counts per revolution (quadrature, x4).
const ENCODER_COUNTS_PER_REV: u32 = 16_384;
/// Z command monitor scale: nanometres per ADC code around mid-scale (16-bit reads).
const CMD_POS_NM_PER_CODE: i32 = 50;
/// The control link is drained every this many ticks (1 kHz): the buffered UART fills its
/// ring from its own interrupt, the background only has to look.
const CONTROL_POLL_TICKS: u32 = 8;

bind_interrupts!(struct Irqs {
    USART3 => usart::BufferedInterruptHandler<peripherals::USART3>;
});

/// Accelerometer, command position (ADC1) and command phase (spindle encoder on TIM3).
struct H7Inputs {
    adc: Adc<'static, ADC1>,
    acc_pin: Peri<'static, PA3>,
    pos_pin: Peri<'static, PC0>,
    encoder: Qei<'static, TIM3>,
}

impl AdcSource for H7Inputs {
    fn sample(&mut self, tick: u32) -> Result<InputSlot, SampleError> {
        // Two short conversions (~0.2 us each at 16.5 cycles): sampled on the tick itself,
        // so there is no wait and never an underrun.
        let acc = self.adc.blocking_read(&mut self.acc_pin, SampleTime::CYCLES16_5);
        let pos = self.adc.blocking_read(&mut self.pos_pin, SampleTime::CYCLES16_5);
        let count = u32::from(self.encoder.count()) % ENCODER_COUNTS_PER_REV;
        let spindle_turns = count.wrapping_mul(u32::MAX / ENCODER_COUNTS_PER_REV + 1);
        Ok(InputSlot {
            tick,
            acc_code: (i32::from(acc) - 32_768) as i16,
            flags: IN_FLAG_PHASE_VALID,
            // The STS command is locked to the spindle: its phase is the spindle encoder's.
            cmd_phase_turns: spindle_turns,
            cmd_pos_nm: (i32::from(pos) - 32_768) * CMD_POS_NM_PER_CODE,
            // No X axis input on this board: axis-coupling terms see only the spindle.
            x_acc_um_per_s2: 0,
            spindle_turns,
        })
    }
}

/// DAC1 channel 1: the signed 16-bit code to 12 bits around mid-scale.
struct H7Dac {
    dac: DacChannel<'static, BlockingMode>,
}

impl DacSink for H7Dac {
    fn write(&mut self, output: &OutputSlot) {
        let code12 = ((i32::from(output.dac_code) + 32_768) >> 4) as u16;
        self.dac.set(Value::Bit12Right(code12));
    }
}

/// TIM2 update interrupt at 8 kHz.
struct H7Tick {
    timer: Timer<'static, TIM2>,
}

impl TickSource for H7Tick {
    fn period_counts(&self) -> u32 {
        self.timer.regs_core().arr().read().arr() as u32 + 1
    }

    fn ack(&mut self) {
        self.timer.clear_update_interrupt();
    }

    fn resync(&mut self) {
        // Sampled on the tick edge: the period never needs restarting.
    }

    fn elapsed_counts(&self) -> u32 {
        self.timer.regs_core().cnt().read().cnt() as u32
    }

    fn overran(&mut self) -> bool {
        self.timer.regs_core().sr().read().uif()
    }
}

/// USART3 through embassy's interrupt-driven buffered UART.
struct H7Link {
    uart: BufferedUart<'static>,
}

impl ControlLink for H7Link {
    fn read(&mut self, buf: &mut [u8]) -> usize {
        use embedded_io::{Read, ReadReady};
        match self.uart.read_ready() {
            Ok(true) => self.uart.read(buf).unwrap_or(0),
            _ => 0,
        }
    }

    fn write(&mut self, bytes: &[u8]) -> usize {
        // Blocks only while the 1 KiB transmit ring is full (background context).
        embedded_io::Write::write(&mut self.uart, bytes).unwrap_or(0)
    }
}

/// Flash bank 2 sectors 6 and 7 (128 KiB each) as the two record slots.
struct H7FlashMedium {
    flash: Flash<'static, Blocking>,
}

/// Offset of slot 0 from the flash base (bank 2, sector 6).
const CONFIG_FLASH_OFFSET: u32 = 0x1C_0000;
const CONFIG_SECTOR_BYTES: u32 = 128 * 1024;

impl H7FlashMedium {
    fn at(slot: usize, offset: usize) -> u32 {
        CONFIG_FLASH_OFFSET + slot as u32 * CONFIG_SECTOR_BYTES + offset as u32
    }
}

fn hw(e: embassy_stm32::flash::Error) -> ConfigError {
    ConfigError::Hardware(e as u32)
}

impl RecordMedium for H7FlashMedium {
    fn slot_bytes(&self) -> usize {
        CONFIG_SECTOR_BYTES as usize
    }

    fn read(&mut self, slot: usize, offset: usize, buf: &mut [u8]) -> Result<(), ConfigError> {
        self.flash.blocking_read(Self::at(slot, offset), buf).map_err(hw)
    }

    fn erase(&mut self, slot: usize) -> Result<(), ConfigError> {
        let from = Self::at(slot, 0);
        self.flash.blocking_erase(from, from + CONFIG_SECTOR_BYTES).map_err(hw)
    }

    fn program(&mut self, slot: usize, offset: usize, data: &[u8]) -> Result<(), ConfigError> {
        // The H7 programs 32-byte flash words; pad the last one with the erased value.
        let mut at = Self::at(slot, offset);
        for chunk in data.chunks(HEADER_BYTES) {
            let mut word = [0xFFu8; HEADER_BYTES];
            word[..chunk.len()].copy_from_slice(chunk);
            self.flash.blocking_write(at, &word).map_err(hw)?;
            at += HEADER_BYTES as u32;
        }
        Ok(())
    }
}

type H7ConfigStore = AbStore<H7FlashMedium>;

struct ServoContext {
    app: App,
    inputs: H7Inputs,
    dac: H7Dac,
    tick: H7Tick,
    state: TickState,
}

static SERVO: BootCell<ServoContext> = BootCell::new();
static SHARED: BootCell<SharedCell<AppShared>> = BootCell::new();
static BACKGROUND: BootCell<(AppBackground, H7ConfigStore, H7Link)> = BootCell::new();
static COUNTERS: ServoCounters = ServoCounters::new();
static EVENTS: Events = Events::new();
static EXECUTOR_MODEL: InterruptExecutor = InterruptExecutor::new();
static TICKS_SINCE_POLL: AtomicU32 = AtomicU32::new(0);

defmt::timestamp!("tick {=u32}", COUNTERS.ticks.load(Ordering::Relaxed));

fn clocks() -> embassy_stm32::Config {
    use embassy_stm32::rcc::*;
    let mut config = embassy_stm32::Config::default();
    // HSI 64 MHz -> PLL1 400 MHz system clock; PLL2 P 100 MHz for the ADC.
    config.rcc.hsi = Some(HSIPrescaler::DIV1);
    config.rcc.csi = true;
    config.rcc.pll1 = Some(Pll {
        source: PllSource::HSI,
        prediv: PllPreDiv::DIV4,
        mul: PllMul::MUL50,
        fracn: None,
        divp: Some(PllDiv::DIV2),
        divq: Some(PllDiv::DIV8),
        divr: None,
    });
    config.rcc.pll2 = Some(Pll {
        source: PllSource::HSI,
        prediv: PllPreDiv::DIV4,
        mul: PllMul::MUL50,
        fracn: None,
        divp: Some(PllDiv::DIV8),
        divq: None,
        divr: None,
    });
    config.rcc.sys = Sysclk::PLL1_P;
    config.rcc.ahb_pre = AHBPrescaler::DIV2;
    config.rcc.apb1_pre = APBPrescaler::DIV2;
    config.rcc.apb2_pre = APBPrescaler::DIV2;
    config.rcc.apb3_pre = APBPrescaler::DIV2;
    config.rcc.apb4_pre = APBPrescaler::DIV2;
    config.rcc.voltage_scale = VoltageScale::Scale1;
    config.rcc.mux.adcsel = mux::Adcsel::PLL2_P;
    config
}

#[cortex_m_rt::entry]
fn main() -> ! {
    let p = embassy_stm32::init(clocks());
    defmt::info!("sts-twin firmware {=str} on STM32H743ZI", env!("CARGO_PKG_VERSION"));

    static mut TX_BUF: [u8; 1024] = [0; 1024];
    static mut RX_BUF: [u8; 512] = [0; 512];
    let mut uart_config = usart::Config::default();
    uart_config.baudrate = 115_200;
    // SAFETY: the buffers are handed out once, here.
    let (tx_buf, rx_buf) = unsafe { (&mut *core::ptr::addr_of_mut!(TX_BUF), &mut *core::ptr::addr_of_mut!(RX_BUF)) };
    let uart = BufferedUart::new(p.USART3, p.PD9, p.PD8, tx_buf, rx_buf, Irqs, uart_config).expect("USART3 config");

    let encoder = Qei::new(
        p.TIM3,
        p.PB4,
        p.PB5,
        qei::Config { auto_reload: (ENCODER_COUNTS_PER_REV - 1) as u16, ..Default::default() },
    );
    let inputs = H7Inputs { adc: Adc::new(p.ADC1), acc_pin: p.PA3, pos_pin: p.PC0, encoder };
    let mut dac = DacChannel::new_blocking(p.DAC1, p.PA4);
    dac.set(Value::Bit12Right(2048));
    dac.enable();
    let timer = Timer::new(p.TIM2);
    timer.set_frequency(Hertz(SERVO_RATE_HZ), RoundTo::Slower);
    timer.enable_update_interrupt(true);

    let (app, background, shared) = make_app();
    // SAFETY: no interrupt that uses these cells is enabled yet.
    let (shared, (background, config, link)) = unsafe {
        let shared: &'static SharedCell<AppShared> = SHARED.init(SharedCell::new(shared));
        SERVO.init(ServoContext {
            app,
            inputs,
            dac: H7Dac { dac },
            tick: H7Tick { timer },
            state: TickState::default(),
        });
        let store = AbStore::new(H7FlashMedium { flash: Flash::new_blocking(p.FLASH) });
        let cell = BACKGROUND.init((background, store, H7Link { uart }));
        (shared, (&mut cell.0, &mut cell.1, &mut cell.2))
    };
    background.on_boot(&mut BackgroundCtx { shared, link, config, counters: &COUNTERS });

    interrupt::UART4.set_priority(Priority::P6);
    let spawner = EXECUTOR_MODEL.start(interrupt::UART4);
    spawner.spawn(background_task(background, config, link, shared).unwrap());

    interrupt::TIM2.set_priority(Priority::P0);
    interrupt::USART3.set_priority(Priority::P2);
    // SAFETY: the servo context is initialised.
    unsafe { interrupt::TIM2.enable() };
    unsafe { SERVO.get() }.tick.timer.start();
    loop {
        cortex_m::asm::wfi();
    }
}

#[embassy_executor::task]
async fn background_task(
    app: &'static mut AppBackground,
    config: &'static mut H7ConfigStore,
    link: &'static mut H7Link,
    shared: &'static SharedCell<AppShared>,
) {
    let mut ctx = BackgroundCtx { shared, link, config, counters: &COUNTERS };
    background_loop(app, &mut ctx, &EVENTS, |_, _| {}).await
}

/// The servo tick.
#[no_mangle]
unsafe extern "C" fn TIM2() {
    // SAFETY: initialised before TIM2 was enabled; this handler is its only user.
    let s = unsafe { SERVO.get() };
    // SAFETY: initialised before; shared access only.
    let shared = unsafe { SHARED.get() };
    run_tick(&mut s.inputs, &mut s.dac, &mut s.tick, &mut s.app, shared, &mut s.state, &COUNTERS, &EVENTS);
    let n = TICKS_SINCE_POLL.load(Ordering::Relaxed) + 1;
    if n >= CONTROL_POLL_TICKS {
        EVENTS.raise(EVENT_CONTROL_RX);
        TICKS_SINCE_POLL.store(0, Ordering::Relaxed);
    } else {
        TICKS_SINCE_POLL.store(n, Ordering::Relaxed);
    }
}

/// The model executor.
#[no_mangle]
unsafe extern "C" fn UART4() {
    // SAFETY: this is the executor's interrupt, as given to `start`.
    unsafe { EXECUTOR_MODEL.on_interrupt() }
}
