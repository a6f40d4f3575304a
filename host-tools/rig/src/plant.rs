//! The machine as the rig sees it: one servo tick of a Z axis whose motion controller has an
//! analogue input wired to the co-processor's DAC.
//!
//! Per tick the rig sets the trajectory's command (Z, X, spindle angle), the voltage at the
//! controller's analogue input and whether the controller adds that input to its command; it
//! reads back the encoder, the capacitance probe at the tool, the accelerometer's ADC code (for
//! the co-processor), the controller's reading of its analogue input and the motion pulses it
//! makes of it, and the machine time. Nothing else: the calibration ([`crate::calibrate`]) and
//! the loop ([`crate::run_loop`]) need no more, so they run on any machine that can be stepped
//! this way: the emulator ([`sts_emulator::Machine`], implemented here), a model written from
//! other equations, or a lab's machine behind its controller's I/O.

use sts_emulator::{Machine, StepInput};

/// What the rig sets on the machine for one servo tick.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PlantInput {
    /// Z position command from the trajectory, um.
    pub z_cmd_um: f64,
    /// X slide position, mm.
    pub x_mm: f64,
    /// Spindle angle, degrees.
    pub spindle_deg: f64,
    /// Voltage at the controller's analogue input (the co-processor's DAC), V.
    pub analog_in_v: f64,
    /// Whether the controller adds its analogue input to the position command (its analogue
    /// feedforward switched on). The input is read either way.
    pub analog_enabled: bool,
}

/// What the rig reads from the machine at one servo tick, at the tick's instant.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PlantReading {
    /// Machine time of this sample, s.
    pub time_s: f64,
    /// Encoder reading, um.
    pub z_enc_um: f64,
    /// Capacitance probe reading of the tool (TCP), um.
    pub z_tcp_um: f64,
    /// True tool position, um, where the plant knows it (a simulation); a plant that does not
    /// (a lab's machine) gives the probe's reading. Only reports and trials' scores use it.
    pub z_tcp_true_um: f64,
    /// Accelerometer ADC code: what the co-processor reads.
    pub acc_code: i16,
    /// The controller's reading of its analogue input (offset included), V.
    pub ain_read_v: f64,
    /// Motion pulses the controller makes of that reading, added to its command only when
    /// [`PlantInput::analog_enabled`].
    pub ain_pulses: i64,
}

/// A machine the rig can step one servo tick at a time.
///
/// Tick `k`: the rig calls [`Plant::step`] with the command of tick `k` and the voltage the
/// co-processor wrote at tick `k - 1`, and hands the reading's accelerometer code to the
/// co-processor, whose output reaches the machine at tick `k + 1`.
pub trait Plant {
    /// Steps one servo tick with `input`; returns the sensors at the tick's instant.
    fn step(&mut self, input: &PlantInput) -> PlantReading;
}

/// The emulated machine, stepped as it is (the readings are its own, unchanged).
impl Plant for Machine {
    fn step(&mut self, input: &PlantInput) -> PlantReading {
        let out = Machine::step(
            self,
            &StepInput {
                z_cmd_um: input.z_cmd_um,
                x_mm: input.x_mm,
                spindle_deg: input.spindle_deg,
                analog_in_v: input.analog_in_v,
                analog_enabled: input.analog_enabled,
            },
        );
        PlantReading {
            time_s: out.time_s,
            z_enc_um: out.z_enc_um,
            z_tcp_um: out.z_tcp_um,
            z_tcp_true_um: out.z_tcp_true_um,
            acc_code: out.acc_code,
            ain_read_v: out.ain_read_v,
            ain_pulses: out.ain_pulses,
        }
    }
}

/// A plant that counts the ticks stepped through it.
pub(crate) struct Counted<'a> {
    pub plant: &'a mut dyn Plant,
    pub ticks: u64,
}

impl Plant for Counted<'_> {
    fn step(&mut self, input: &PlantInput) -> PlantReading {
        self.ticks += 1;
        self.plant.step(input)
    }
}
