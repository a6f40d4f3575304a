//! The calibration on a lab's own machine, with a board on a serial port
//! (`sts-twin calibrate-offset --port`): the interface offset and `K_dv`, measured through
//! what only the machine can give, the motion controller's reading of its analogue input
//! and the probe at the tool, taken through [`LabInstruments`] (the operator types them, or
//! the lab's own commands print them).
//!
//! The board cannot be ticked from the host (it runs on its own timer), so the offset is
//! found from a straight-line fit of the controller's readings against the DAC voltages and
//! not by trying codes one by one, as the emulated procedure does. With compensation off the
//! board writes `-offset_v` to its DAC (Eq. 5 at zero gain), so setting `offset_v` puts any
//! voltage on the line. The analogue path is not measured (that needs a sine through the
//! controller, from a board the host cannot tick); the stored table is kept.

use std::time::{Duration, Instant};

use serde::Serialize;
use sts_numerics::lsq::least_squares;
use sts_twin_core::feedforward::FeedforwardParams;
use sts_twin_core::wire::Request;
use sts_twin_core::SERVO_RATE_HZ;

use crate::{expect_ack, status, Coprocessor, RigError};

/// What a lab reads off its own instruments. The voltages passed are what the board is
/// asked to output, for the operator's prompt; a reading must come from the instrument.
pub trait LabInstruments {
    /// The motion controller's reading of its analogue input, V, with the board's output at
    /// `dac_v` and the controller's analogue feedforward off (the axis stays at rest).
    fn controller_reading_v(&mut self, dac_v: f64) -> Result<f64, RigError>;
    /// Called once before the `K_dv` step: the controller's analogue feedforward goes on.
    fn feedforward_on(&mut self) -> Result<(), RigError>;
    /// The probe at the tool, um, with the board's output at `dac_v` and the controller's
    /// analogue feedforward on.
    fn tool_position_um(&mut self, dac_v: f64) -> Result<f64, RigError>;
}

/// Settings of the lab calibration.
#[derive(Clone, Debug, PartialEq)]
pub struct LabConfig {
    /// DAC voltages of the offset fit, V.
    pub offset_voltages_v: Vec<f64>,
    /// Voltages about the null of the `K_dv` fit, V.
    pub kdv_voltages_v: Vec<f64>,
    /// Wait after each new output before reading (the DAC slews; the controller filters), in
    /// the board's own time: its servo ticks, so that a board that runs slow (an emulated one
    /// under load) settles as far as a real one.
    pub settle: Duration,
    /// Longest wall-clock wait for the board's ticks to cover `settle`.
    pub settle_timeout: Duration,
    /// Longest wait for compensation to ramp out at the start.
    pub ramp_out_timeout: Duration,
}

impl Default for LabConfig {
    fn default() -> Self {
        Self {
            offset_voltages_v: vec![-0.5, -0.2, 0.0, 0.2, 0.5],
            kdv_voltages_v: vec![-1.0, -0.5, 0.5, 1.0],
            settle: Duration::from_millis(200),
            settle_timeout: Duration::from_secs(30),
            ramp_out_timeout: Duration::from_secs(10),
        }
    }
}

/// One reading of the calibration.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LabPoint {
    /// The board's output, V.
    pub dac_v: f64,
    /// What the instrument read: the controller's input, V, or the tool's position, um.
    pub reading: f64,
}

/// What the lab calibration found and stored.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LabCalibration {
    /// The offset fit's readings.
    pub offset_points: Vec<LabPoint>,
    /// The controller's reading per DAC volt.
    pub interface_gain: f64,
    /// The offset stored, V: with it, the board's zero is the controller's zero.
    pub offset_v: f64,
    /// The offset fit's RMS residual, V.
    pub offset_residual_v: f64,
    /// The `K_dv` fit's readings.
    pub kdv_points: Vec<LabPoint>,
    /// Motion at the tool per DAC volt, um/V.
    pub k_dv_um_per_v: f64,
    /// The `K_dv` fit's RMS residual, um.
    pub kdv_residual_um: f64,
    /// The parameters stored and read back.
    pub params: FeedforwardParams,
}

impl std::fmt::Display for LabCalibration {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "offset: {:+.5} V (the controller reads {:.4} V per DAC volt; fit residual {:.2} mV over {} voltages)",
            self.offset_v,
            self.interface_gain,
            1e3 * self.offset_residual_v,
            self.offset_points.len()
        )?;
        writeln!(
            f,
            "K_dv: {:.4} um/V (fit residual {:.3} um over {} voltages)",
            self.k_dv_um_per_v,
            self.kdv_residual_um,
            self.kdv_points.len()
        )?;
        write!(f, "stored in the board and read back; the analogue-path table was kept as it was")
    }
}

/// Measures the offset and `K_dv` through `instruments`, stores them (with `SaveConfig`) and
/// reads them back. Compensation is switched off first and stays off.
pub fn calibrate_lab(
    board: &mut dyn Coprocessor,
    instruments: &mut dyn LabInstruments,
    config: &LabConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<LabCalibration, RigError> {
    if config.offset_voltages_v.len() < 2 || config.kdv_voltages_v.len() < 2 {
        return Err(RigError::LabSettings { reason: "the offset and K_dv fits need at least two voltages each" });
    }
    expect_ack("switching compensation off", board.request(Request::SetEnabled(false))?)?;
    let deadline = Instant::now() + config.ramp_out_timeout;
    let base = loop {
        let s = status(board)?;
        if s.gain == 0.0 {
            break s.params;
        }
        if Instant::now() >= deadline {
            return Err(RigError::LabSettings { reason: "compensation did not ramp out in time" });
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let limit_v = 0.5 * f64::from(base.dac_full_scale_v);
    let output = |board: &mut dyn Coprocessor, dac_v: f64| -> Result<(), RigError> {
        if dac_v.abs() > limit_v {
            return Err(RigError::OffsetVoltageRange { volts: dac_v, limit_v });
        }
        let params = FeedforwardParams { offset_v: -dac_v as f32, ..base };
        let start = status(board)?.counters.ticks;
        expect_ack("holding a DAC voltage", board.request(Request::SetParams(params))?)?;
        let settle_ticks = (config.settle.as_secs_f64() * f64::from(SERVO_RATE_HZ)).ceil() as u64;
        let deadline = Instant::now() + config.settle_timeout;
        std::thread::sleep(config.settle.min(Duration::from_millis(20)));
        while status(board)?.counters.ticks.wrapping_sub(start) < settle_ticks {
            if Instant::now() >= deadline {
                return Err(RigError::LabSettings {
                    reason: "the board's servo ticks did not cover the settling time: is its tick running?",
                });
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        Ok(())
    };

    progress("step 1: the interface offset (the controller's readings against the board's output, feedforward off)");
    let mut offset_points = Vec::new();
    for &dac_v in &config.offset_voltages_v {
        output(board, dac_v)?;
        offset_points.push(LabPoint { dac_v, reading: instruments.controller_reading_v(dac_v)? });
    }
    let rows: Vec<[f64; 2]> = offset_points.iter().map(|p| [1.0, p.dac_v]).collect();
    let y: Vec<f64> = offset_points.iter().map(|p| p.reading).collect();
    let fit = least_squares(&rows, &y).ok_or(RigError::OffsetSingular)?;
    let (intercept_v, gain) = (fit.coefficients[0], fit.coefficients[1]);
    // A NaN gain fails too.
    if gain.abs().is_nan() || gain.abs() <= 0.1 {
        return Err(RigError::ReadingDoesNotFollow { gain });
    }
    let null_v = -intercept_v / gain;
    if null_v.abs() > limit_v {
        return Err(RigError::OffsetBeyondRange { intercept_v });
    }

    progress("step 2: K_dv (the controller's analogue feedforward on, the probe at the tool)");
    instruments.feedforward_on()?;
    let mut kdv_points = Vec::new();
    for &dv in &config.kdv_voltages_v {
        let dac_v = null_v + dv;
        output(board, dac_v)?;
        kdv_points.push(LabPoint { dac_v, reading: instruments.tool_position_um(dac_v)? });
    }
    output(board, null_v)?;
    let rows: Vec<[f64; 2]> = kdv_points.iter().map(|p| [1.0, p.dac_v - null_v]).collect();
    let y: Vec<f64> = kdv_points.iter().map(|p| p.reading).collect();
    let kdv_fit = least_squares(&rows, &y).ok_or(RigError::KdvSingular)?;
    let k_dv_um_per_v = kdv_fit.coefficients[1];
    let span_um = y.iter().copied().fold(f64::MIN, f64::max) - y.iter().copied().fold(f64::MAX, f64::min);
    if !(span_um > 10.0 * kdv_fit.residual_rms && k_dv_um_per_v.abs() > 1e-6) {
        return Err(RigError::AxisDidNotMove { k_dv_um_per_v, span_um, residual_um: kdv_fit.residual_rms });
    }

    let params = FeedforwardParams { offset_v: -null_v as f32, k_dv_um_per_v: k_dv_um_per_v as f32, ..base };
    params.validate().map_err(|error| RigError::MeasuredParams { error, params: Box::new(params) })?;
    expect_ack("the measured parameters", board.request(Request::SetParams(params))?)?;
    expect_ack("saving the calibration", board.request(Request::SaveConfig)?)?;
    let read_back = status(board)?.params;
    if read_back != params {
        return Err(RigError::LabSettings { reason: "the board reads back other parameters than were stored" });
    }
    progress("stored: the board boots with this calibration (`sts-twin board status` shows config: Stored)");
    Ok(LabCalibration {
        offset_points,
        interface_gain: gain,
        offset_v: -null_v,
        offset_residual_v: fit.residual_rms,
        kdv_points,
        k_dv_um_per_v,
        kdv_residual_um: kdv_fit.residual_rms,
        params,
    })
}
