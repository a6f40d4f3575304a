//! The co-processor as the loop sees it, and the loop that steps it with the machine.

use sts_emulator::PlantParams;
use sts_model::replay::turns_u32;
use sts_twin_core::feedforward::FeedforwardParams;

use crate::plant::{Plant, PlantInput, PlantReading};
use crate::trajectory::{Trajectory, TrajectoryPoint};
use crate::RigError;
use sts_twin_core::bus::{InputSlot, OutputSlot, IN_FLAG_PHASE_VALID};
use sts_twin_core::supervisor::SupervisorParams;
use sts_twin_core::wire::{Request, Response, Status};

/// The feedforward parameters matching the emulated controller's analogue interface: its
/// true values, which only the calibration's starting point and its tests use; a cut uses what
/// the calibration measures ([`crate::trial::calibrated`]), as a lab has only that.
pub fn machine_params(plant: &PlantParams, offset_v: f64) -> FeedforwardParams {
    let ain = &plant.interface;
    FeedforwardParams {
        k_dv_um_per_v: (ain.kvc_pulses_per_v * ain.pulse_nm * 1e-3) as f32,
        k_vc_pulses_per_v: ain.kvc_pulses_per_v as f32,
        offset_v: offset_v as f32,
        slew_v_per_tick: 1.0,
        dac_full_scale_v: 10.0,
        enable_ramp_ticks: 4000,
        analogue_path: sts_twin_core::analogue_path::AnaloguePath::NONE,
    }
}

/// A co-processor running the twin: the firmware under QEMU or its host simulation.
pub trait Coprocessor {
    /// One servo tick.
    fn tick(&mut self, input: &InputSlot) -> Result<OutputSlot, RigError>;
    /// One control request and its answer.
    fn request(&mut self, request: Request) -> Result<Response, RigError>;
    /// A short name for reports ("hil" or "sim").
    fn kind(&self) -> &'static str;
}

/// Fails unless `response` is `Ack`, naming what was asked.
pub fn expect_ack(what: &str, response: Response) -> Result<(), RigError> {
    match response {
        Response::Ack => Ok(()),
        other => Err(RigError::Refused { what: what.to_string(), response: Box::new(other) }),
    }
}

/// The co-processor's status.
pub fn status(coprocessor: &mut dyn Coprocessor) -> Result<Status, RigError> {
    match coprocessor.request(Request::GetStatus)? {
        Response::Status(status) => Ok(status),
        other => Err(RigError::Unexpected { request: "the status request", response: Box::new(other) }),
    }
}

/// Switches the co-processor's supervisor off, for a calibration that drives the output on
/// purpose (with no motion commanded, the supervisor would hold it at zero), and returns
/// the thresholds to give back with [`restore_supervisor`] afterwards.
pub fn supervisor_off(coprocessor: &mut dyn Coprocessor) -> Result<SupervisorParams, RigError> {
    let before = status(coprocessor)?.supervisor_params;
    let off = SupervisorParams { active: false, ..before };
    expect_ack("switching the supervisor off", coprocessor.request(Request::SetSupervisor(off))?)?;
    Ok(before)
}

/// Sets the supervisor's thresholds back after [`supervisor_off`].
pub fn restore_supervisor(coprocessor: &mut dyn Coprocessor, params: SupervisorParams) -> Result<(), RigError> {
    expect_ack("restoring the supervisor", coprocessor.request(Request::SetSupervisor(params))?)
}

/// One tick of the loop as recorded.
#[derive(Clone, Copy, Debug)]
pub struct LoopSample {
    /// The trajectory point.
    pub point: TrajectoryPoint,
    /// What the machine measured.
    pub machine: PlantReading,
    /// What the co-processor answered.
    pub output: OutputSlot,
}

/// Runs the closed loop of `machine` and `coprocessor` over the machine ticks `ticks` and
/// hands every tick to `record`. The DAC code is converted to volts with `dac_full_scale_v`
/// (code 32767).
pub fn run_loop(
    machine: &mut dyn Plant,
    coprocessor: &mut dyn Coprocessor,
    trajectory: &dyn Trajectory,
    ticks: std::ops::Range<u64>,
    dac_full_scale_v: f64,
    analog_enabled: bool,
    mut record: impl FnMut(&LoopSample),
) -> Result<(), RigError> {
    let sample_rate_hz = trajectory.sample_rate_hz();
    let mut analog_in_v = 0.0;
    let at_tick = |k: u64| trajectory.at(k as f64 / sample_rate_hz);
    // Each tick needs the trajectory at k - 1 (X acceleration), k and k + 1: evaluated once
    // each and carried along.
    let mut before = at_tick(ticks.start.saturating_sub(1));
    let mut point = at_tick(ticks.start);
    for k in ticks {
        let machine_out = machine.step(&PlantInput {
            z_cmd_um: point.z_cmd_um,
            x_mm: point.x_mm,
            spindle_deg: point.spindle_deg,
            analog_in_v,
            analog_enabled,
        });
        // The output of this tick acts at the next one: hand over the command phase, the X
        // acceleration (as the machine computes it, from three X positions) and the spindle
        // angle there.
        let next = at_tick(k + 1);
        let x_acc_mps2 = (next.x_mm - 2.0 * point.x_mm + before.x_mm) * 1e-3 * sample_rate_hz * sample_rate_hz;
        let input = InputSlot {
            tick: k as u32,
            acc_code: machine_out.acc_code,
            flags: IN_FLAG_PHASE_VALID,
            cmd_phase_turns: next.phase_turns,
            cmd_pos_nm: (next.z_cmd_um * 1e3).round().clamp(i32::MIN as f64, i32::MAX as f64) as i32,
            x_acc_um_per_s2: (x_acc_mps2 * 1e6).round().clamp(i32::MIN as f64, i32::MAX as f64) as i32,
            spindle_turns: turns_u32(next.spindle_deg / 360.0),
        };
        let output = coprocessor.tick(&input)?;
        analog_in_v = f64::from(output.dac_code) * dac_full_scale_v / 32767.0;
        record(&LoopSample { point, machine: machine_out, output });
        (before, point) = (point, next);
    }
    Ok(())
}
