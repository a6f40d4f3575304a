//! The analogue interface's offset, measured through the firmware.
//!
//! Compensation off, the co-processor writes `-offset_v` to its DAC (Eq. 5 with zero gain),
//! so setting `offset_v` puts any known DAC code on the line. The motion controller reads
//! its analogue input (here the emulated A3200's `ain_read_v` and the pulses it makes of it;
//! in a lab the controller's analogue-input readback) with its analogue feedforward still
//! off, so the axis does not move. Two steps:
//!
//! 1. A straight-line fit of the reading against the DAC voltage over a few voltages gives
//!    the interface's gain and offset (and `K_vc`, pulses per volt read).
//! 2. The codes around the fit's null are tried one by one; the one at which the controller
//!    makes the fewest pulses (then reads the least) is kept. Its voltage, negated, is the
//!    offset to store: with it, switching the controller's analogue input on at rest adds
//!    no pulse.

use serde::Serialize;
use sts_twin_core::feedforward::FeedforwardParams;

use super::rest::{RestAverage, RestRig};
use crate::RigError;
use sts_numerics::lsq::least_squares;

/// Settings of the offset measurement.
#[derive(Clone, Debug)]
pub struct OffsetConfig {
    /// DAC voltages of the straight-line fit, V (small: the reading must not clip).
    pub fit_voltages_v: Vec<f64>,
    /// Codes tried on each side of the fit's null.
    pub search_codes: i16,
    /// Ticks after each change before averaging (the DAC slews, the bus has a tick of latency).
    pub settle_ticks: u32,
    /// Ticks averaged at each code.
    pub average_ticks: u32,
}

impl Default for OffsetConfig {
    fn default() -> Self {
        Self {
            fit_voltages_v: vec![-0.5, -0.2, -0.05, 0.0, 0.05, 0.2, 0.5],
            search_codes: 3,
            settle_ticks: 16,
            average_ticks: 64,
        }
    }
}

/// The controller's reading at one DAC code.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct OffsetPoint {
    /// The DAC code written.
    pub dac_code: i16,
    /// Its voltage, V.
    pub dac_v: f64,
    /// The controller's mean reading, V.
    pub ain_read_v: f64,
    /// The mean motion pulses it makes of the reading.
    pub ain_pulses: f64,
}

/// What the offset measurement found.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct OffsetReport {
    /// The fit's points.
    pub fit_points: Vec<OffsetPoint>,
    /// Interface gain: volts read per DAC volt.
    pub interface_gain: f64,
    /// The interface's offset: the reading at 0 V from the fit, V.
    pub interface_offset_v: f64,
    /// RMS residual of the reading's straight-line fit, V.
    pub fit_residual_v: f64,
    /// Motion pulses per volt read (`K_vc`), fitted through the origin.
    pub k_vc_pulses_per_v: f64,
    /// The codes tried around the null.
    pub search_points: Vec<OffsetPoint>,
    /// The offset to store, V (the chosen code's voltage, negated).
    pub offset_v: f64,
    /// The chosen DAC code at rest.
    pub rest_dac_code: i16,
    /// Mean pulses the controller makes at rest with the calibrated offset.
    pub rest_pulses: f64,
    /// Mean pulses it makes at rest with no offset correction (DAC at 0 V).
    pub uncalibrated_pulses: f64,
}

impl OffsetReport {
    /// Whether the calibrated offset leaves less than one pulse at rest.
    pub fn nulled(&self) -> bool {
        self.rest_pulses.abs() < 1.0
    }
}

fn point(rig: &RestRig<'_>, average: &RestAverage) -> OffsetPoint {
    OffsetPoint {
        dac_code: average.dac_code,
        dac_v: f64::from(average.dac_code) * rig.volts_per_code(),
        ain_read_v: average.ain_read_v,
        ain_pulses: average.ain_pulses,
    }
}

fn measure_at(
    rig: &mut RestRig<'_>,
    params: &FeedforwardParams,
    dac_v: f64,
    config: &OffsetConfig,
) -> Result<OffsetPoint, RigError> {
    rig.hold_dac_v(params, dac_v)?;
    let average = rig.average(config.settle_ticks, config.average_ticks)?;
    if !average.dac_steady {
        return Err(RigError::DacNotSettled {
            dac_v,
            settle_ticks: config.settle_ticks,
            slew_v_per_tick: params.slew_v_per_tick,
        });
    }
    Ok(point(rig, &average))
}

/// Measures the offset on `rig` (the co-processor's compensation off and no program; the
/// controller's analogue input off). `params` are the co-processor's parameters apart from
/// the offset. The co-processor is left writing the chosen code.
pub fn measure_offset(
    rig: &mut RestRig<'_>,
    params: &FeedforwardParams,
    config: &OffsetConfig,
) -> Result<OffsetReport, RigError> {
    if config.fit_voltages_v.len() < 2 {
        return Err(RigError::OffsetVoltageCount { count: config.fit_voltages_v.len() });
    }
    let limit_v = f64::from(params.dac_full_scale_v) / 2.0;
    if let Some(bad) = config.fit_voltages_v.iter().find(|v| !(v.is_finite() && v.abs() <= limit_v)) {
        return Err(RigError::OffsetVoltageRange { volts: *bad, limit_v });
    }
    rig.analog_enabled = false;
    let volts_per_code = rig.volts_per_code();
    let mut fit_points = Vec::with_capacity(config.fit_voltages_v.len());
    for &dac_v in &config.fit_voltages_v {
        fit_points.push(measure_at(rig, params, dac_v, config)?);
    }
    let rows: Vec<[f64; 2]> = fit_points.iter().map(|p| [p.dac_v, 1.0]).collect();
    let reads: Vec<f64> = fit_points.iter().map(|p| p.ain_read_v).collect();
    let fit = least_squares(&rows, &reads).ok_or(RigError::OffsetSingular)?;
    let (gain, intercept_v) = (fit.coefficients[0], fit.coefficients[1]);
    if !(gain.is_finite() && gain.abs() > 0.1) {
        return Err(RigError::ReadingDoesNotFollow { gain });
    }
    let pulse_rows: Vec<[f64; 1]> = fit_points.iter().map(|p| [p.ain_read_v]).collect();
    let pulses: Vec<f64> = fit_points.iter().map(|p| p.ain_pulses).collect();
    let k_vc_pulses_per_v = least_squares(&pulse_rows, &pulses).map(|f| f.coefficients[0]).unwrap_or(f64::NAN);

    let uncalibrated = fit_points.iter().find(|p| p.dac_code == 0).copied();
    let uncalibrated = match uncalibrated {
        Some(p) => p,
        None => measure_at(rig, params, 0.0, config)?,
    };

    // The code whose voltage nulls the reading, then its neighbours.
    let null_v = -intercept_v / gain;
    let null_code = (null_v / volts_per_code).round();
    if null_code.abs() > f64::from(i16::MAX) {
        return Err(RigError::OffsetBeyondRange { intercept_v });
    }
    let mut search_points = Vec::new();
    for delta in -i32::from(config.search_codes)..=i32::from(config.search_codes) {
        let code = null_code as i32 + delta;
        if code.unsigned_abs() > i16::MAX as u32 {
            continue;
        }
        let p = measure_at(rig, params, f64::from(code) * volts_per_code, config)?;
        if i32::from(p.dac_code) != code {
            return Err(RigError::DacCodeMismatch { asked: code, wrote: p.dac_code });
        }
        search_points.push(p);
    }
    let score = |p: &OffsetPoint| (p.ain_pulses.abs(), p.ain_read_v.abs());
    let best = search_points
        .iter()
        .map(score)
        .min_by(|a, b| a.partial_cmp(b).unwrap_or(std::cmp::Ordering::Equal))
        .ok_or(RigError::NoDacCode)?;
    // Equally good codes: the middle one, farthest from the pulses on either side.
    let ties: Vec<&OffsetPoint> = search_points.iter().filter(|p| score(p) == best).collect();
    let chosen = *ties[ties.len() / 2];
    let offset_v = -chosen.dac_v;
    // Leave the co-processor writing the chosen code.
    rig.hold_dac_v(params, chosen.dac_v)?;
    rig.average(config.settle_ticks, 1)?;
    Ok(OffsetReport {
        fit_points,
        interface_gain: gain,
        interface_offset_v: intercept_v,
        fit_residual_v: fit.residual_rms,
        k_vc_pulses_per_v,
        search_points,
        offset_v,
        rest_dac_code: chosen.dac_code,
        rest_pulses: chosen.ain_pulses,
        uncalibrated_pulses: uncalibrated.ain_pulses,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::machine_params;
    use crate::SimCoprocessor;
    use sts_emulator::{Machine, PlantParams};

    fn run(plant: &PlantParams) -> OffsetReport {
        let mut machine = Machine::new(plant, &[], 5).unwrap();
        let mut cop = SimCoprocessor::boot(&[]);
        let params = machine_params(plant, 0.0);
        let mut rig = RestRig::new(&mut cop, &mut machine, f64::from(params.dac_full_scale_v), 0);
        measure_offset(&mut rig, &params, &OffsetConfig::default()).unwrap()
    }

    #[test]
    fn the_default_interface_offset_is_nulled_to_less_than_a_pulse() {
        let plant = PlantParams::default();
        let report = run(&plant);
        assert!((report.interface_offset_v - 0.012).abs() < 3e-4, "{report:?}");
        assert!((report.interface_gain - 1.0).abs() < 2e-3, "{report:?}");
        assert!((report.k_vc_pulses_per_v - 2000.0).abs() < 20.0, "{report:?}");
        assert!((report.offset_v - 0.012).abs() < 2e-4, "{report:?}");
        assert_eq!(report.rest_pulses, 0.0, "{report:?}");
        assert!(report.nulled());
        // Without calibration the controller would add 0.012 V * 2000 pulses/V.
        assert_eq!(report.uncalibrated_pulses, 24.0, "{report:?}");
    }

    #[test]
    fn other_interfaces_are_nulled_too() {
        for (offset_v, kvc) in [(-0.2371, 2000.0), (0.0893, 500.0), (0.0, 8000.0)] {
            let mut plant = PlantParams::default();
            plant.interface.offset_v = offset_v;
            plant.interface.kvc_pulses_per_v = kvc;
            let report = run(&plant);
            assert!(report.nulled(), "offset {offset_v} kvc {kvc}: {report:?}");
            assert!((report.offset_v - offset_v).abs() < 3e-4, "offset {offset_v}: {report:?}");
            assert!((report.k_vc_pulses_per_v / kvc - 1.0).abs() < 0.02, "kvc {kvc}: {report:?}");
        }
    }
}
