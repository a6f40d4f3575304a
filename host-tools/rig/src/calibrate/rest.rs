//! The axis at rest with the co-processor's DAC wired to the motion controller's analogue
//! input: the bench on which the offset and `K_dv` are measured.
//!
//! Tick `k`: the machine steps with a zero command and the voltage the co-processor wrote at
//! tick `k - 1`; the co-processor gets the (at rest, nearly silent) accelerometer code.

use sts_twin_core::bus::{InputSlot, OutputSlot};
use sts_twin_core::feedforward::FeedforwardParams;
use sts_twin_core::wire::{Request, Status};

use crate::plant::{Plant, PlantInput, PlantReading};
use crate::{expect_ack, Coprocessor, RigError};

/// DAC codes at full scale (code 32767 is `dac_full_scale_v`).
pub const DAC_FULL_SCALE_CODE: f64 = 32767.0;

/// Means over an averaging window at rest.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct RestAverage {
    /// The DAC code the co-processor wrote (the last of the window).
    pub dac_code: i16,
    /// Whether the DAC code was the same on every tick of the window.
    pub dac_steady: bool,
    /// The controller's reading of its analogue input, V.
    pub ain_read_v: f64,
    /// Motion pulses the controller made of it (what it adds when its input is on).
    pub ain_pulses: f64,
    /// Capacitance probe at the TCP, um.
    pub z_tcp_um: f64,
    /// Encoder, um.
    pub z_enc_um: f64,
    /// True TCP position where the plant knows it (a simulation; a lab's plant gives the
    /// probe), um.
    pub z_tcp_true_um: f64,
    /// Machine time at the window's middle, s.
    pub time_s: f64,
    /// Largest `|ain_pulses|` of one tick in the window.
    pub ain_pulses_max: i64,
}

/// The co-processor and the machine (any [`Plant`]), stepped together at rest.
pub struct RestRig<'a> {
    coprocessor: &'a mut dyn Coprocessor,
    machine: &'a mut dyn Plant,
    volts_per_code: f64,
    analog_in_v: f64,
    tick: u64,
    /// Whether the controller adds its analogue input's pulses to the position command.
    pub analog_enabled: bool,
}

impl<'a> RestRig<'a> {
    /// A rig from tick `first_tick`, the controller's analogue input off, the DAC at 0 V.
    pub fn new(
        coprocessor: &'a mut dyn Coprocessor,
        machine: &'a mut dyn Plant,
        dac_full_scale_v: f64,
        first_tick: u64,
    ) -> Self {
        Self {
            coprocessor,
            machine,
            volts_per_code: dac_full_scale_v / DAC_FULL_SCALE_CODE,
            analog_in_v: 0.0,
            tick: first_tick,
            analog_enabled: false,
        }
    }

    /// Volts per DAC code.
    pub fn volts_per_code(&self) -> f64 {
        self.volts_per_code
    }

    /// Ticks stepped so far (from the first tick given).
    pub fn tick(&self) -> u64 {
        self.tick
    }

    /// One tick.
    pub fn step(&mut self) -> Result<(PlantReading, OutputSlot), RigError> {
        let machine = self.machine.step(&PlantInput {
            z_cmd_um: 0.0,
            x_mm: 0.0,
            spindle_deg: 0.0,
            analog_in_v: self.analog_in_v,
            analog_enabled: self.analog_enabled,
        });
        let input = InputSlot { tick: self.tick as u32, acc_code: machine.acc_code, ..Default::default() };
        let output = self.coprocessor.tick(&input)?;
        self.analog_in_v = f64::from(output.dac_code) * self.volts_per_code;
        self.tick += 1;
        Ok((machine, output))
    }

    /// Steps `settle_ticks`, then averages over `average_ticks` (at least one).
    pub fn average(&mut self, settle_ticks: u32, average_ticks: u32) -> Result<RestAverage, RigError> {
        for _ in 0..settle_ticks {
            self.step()?;
        }
        let n = average_ticks.max(1);
        let mut sum = RestAverage { dac_steady: true, ..RestAverage::default() };
        let mut first_code = None;
        for _ in 0..n {
            let (machine, output) = self.step()?;
            let code = *first_code.get_or_insert(output.dac_code);
            sum.dac_steady &= code == output.dac_code;
            sum.dac_code = output.dac_code;
            sum.ain_read_v += machine.ain_read_v;
            sum.ain_pulses += machine.ain_pulses as f64;
            sum.ain_pulses_max = sum.ain_pulses_max.max(machine.ain_pulses.abs());
            sum.z_tcp_um += machine.z_tcp_um;
            sum.z_enc_um += machine.z_enc_um;
            sum.z_tcp_true_um += machine.z_tcp_true_um;
            sum.time_s += machine.time_s;
        }
        let n = f64::from(n);
        Ok(RestAverage {
            ain_read_v: sum.ain_read_v / n,
            ain_pulses: sum.ain_pulses / n,
            z_tcp_um: sum.z_tcp_um / n,
            z_enc_um: sum.z_enc_um / n,
            z_tcp_true_um: sum.z_tcp_true_um / n,
            time_s: sum.time_s / n,
            ..sum
        })
    }

    /// Sends `request`, which must be acknowledged.
    pub fn request(&mut self, what: &str, request: Request) -> Result<(), RigError> {
        expect_ack(what, self.coprocessor.request(request)?)
    }

    /// Sets the co-processor's parameters so that, compensation off, it writes `dac_v` volts
    /// (its output is then `-offset_v`).
    pub fn hold_dac_v(&mut self, params: &FeedforwardParams, dac_v: f64) -> Result<(), RigError> {
        let params = FeedforwardParams { offset_v: -dac_v as f32, ..*params };
        self.request(&format!("an offset of {:.4} V", params.offset_v), Request::SetParams(params))
    }

    /// The co-processor's status.
    pub fn status(&mut self) -> Result<Status, RigError> {
        status(self.coprocessor)
    }

    /// The co-processor and the machine, for procedures that drive them themselves; `tick`
    /// is where they are. Call [`RestRig::advanced`] afterwards with the ticks they ran.
    pub fn parts(&mut self) -> (&mut dyn Coprocessor, &mut dyn Plant, u64) {
        (&mut *self.coprocessor, &mut *self.machine, self.tick)
    }

    /// Accounts for `ticks` run through [`RestRig::parts`]; the DAC voltage at the
    /// controller is taken as `analog_in_v` for the next tick.
    pub fn advanced(&mut self, ticks: u64, analog_in_v: f64) {
        self.tick += ticks;
        self.analog_in_v = analog_in_v;
    }
}

pub use crate::coprocessor::status;
