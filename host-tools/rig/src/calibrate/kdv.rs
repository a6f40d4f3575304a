//! `K_dv`: displacement of the tool per volt at the controller's analogue input.
//!
//! With the offset calibrated and the controller's analogue feedforward on, the co-processor
//! holds known voltages about its rest code (compensation off, so its output is exactly
//! `-offset_v`); after each change the axis settles and the capacitance probe at the TCP is
//! averaged. `K_dv` is the slope of a least-squares fit `z = K_dv V + z0 + drift t` (the
//! drift term absorbs a slow thermal growth during the measurement; the voltages are
//! ordered so that it is not confused with the slope).

use serde::Serialize;
use sts_twin_core::feedforward::FeedforwardParams;

use super::rest::RestRig;
use crate::RigError;
use sts_numerics::lsq::least_squares;
use sts_twin_core::SERVO_RATE_HZ;

/// Settings of the `K_dv` measurement.
#[derive(Clone, Debug)]
pub struct KdvConfig {
    /// Voltages held about the rest code, V, in the order held.
    pub voltages_v: Vec<f64>,
    /// Time after each change before averaging, s.
    pub settle_s: f64,
    /// Time averaged at each voltage, s.
    pub average_s: f64,
    /// The servo rate, Hz.
    pub sample_rate_hz: f64,
}

impl Default for KdvConfig {
    fn default() -> Self {
        Self {
            voltages_v: vec![0.0, 1.0, -1.0, 2.0, -2.0, 0.5, -0.5, 0.0],
            settle_s: 0.15,
            average_s: 0.05,
            sample_rate_hz: f64::from(SERVO_RATE_HZ),
        }
    }
}

/// The displacement at one voltage.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct KdvPoint {
    /// The DAC code held.
    pub dac_code: i16,
    /// Its voltage about the rest code, V.
    pub volts: f64,
    /// Mean probe reading at the TCP, um.
    pub z_tcp_um: f64,
    /// Mean encoder reading, um.
    pub z_enc_um: f64,
    /// Mean motion pulses the controller added.
    pub ain_pulses: f64,
    /// Machine time of the average, s.
    pub time_s: f64,
    /// Residual of the fit at this point, um.
    pub residual_um: f64,
}

/// What the `K_dv` measurement found.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct KdvReport {
    /// The points, in the order held.
    pub points: Vec<KdvPoint>,
    /// `K_dv`, um per V (probe at the TCP).
    pub k_dv_um_per_v: f64,
    /// The same slope from the encoder, um per V.
    pub k_dv_encoder_um_per_v: f64,
    /// The probe's reading at 0 V from the fit, um.
    pub z0_um: f64,
    /// Drift of the TCP during the measurement, um per s.
    pub drift_um_per_s: f64,
    /// RMS residual of the fit, um.
    pub residual_rms_um: f64,
    /// Largest residual, um.
    pub residual_max_um: f64,
}

fn fit(points: &[KdvPoint], value: impl Fn(&KdvPoint) -> f64) -> Result<sts_numerics::lsq::LinearFit, RigError> {
    let t0 = points.first().map_or(0.0, |p| p.time_s);
    let rows: Vec<[f64; 3]> = points.iter().map(|p| [p.volts, 1.0, p.time_s - t0]).collect();
    let y: Vec<f64> = points.iter().map(value).collect();
    least_squares(&rows, &y).ok_or(RigError::KdvSingular)
}

/// Measures `K_dv` on `rig` about the calibrated `offset_v` (compensation off, no program).
/// Switches the controller's analogue input on; the co-processor is left at its rest code.
pub fn measure_kdv(
    rig: &mut RestRig<'_>,
    params: &FeedforwardParams,
    offset_v: f64,
    config: &KdvConfig,
) -> Result<KdvReport, RigError> {
    if config.voltages_v.len() < 3 {
        return Err(RigError::KdvVoltageCount { count: config.voltages_v.len() });
    }
    let limit_v = f64::from(params.dac_full_scale_v) / 2.0 - offset_v.abs();
    if let Some(bad) = config.voltages_v.iter().find(|v| !(v.is_finite() && v.abs() <= limit_v)) {
        return Err(RigError::KdvVoltageRange { volts: *bad, limit_v });
    }
    if !(config.settle_s >= 0.0 && config.average_s > 0.0 && config.sample_rate_hz > 0.0) {
        return Err(RigError::KdvTimes);
    }
    let settle_ticks = (config.settle_s * config.sample_rate_hz).round() as u32;
    let average_ticks = ((config.average_s * config.sample_rate_hz).round() as u32).max(1);
    let rest_v = -offset_v;
    let rest_code = (rest_v / rig.volts_per_code()).round();
    rig.hold_dac_v(params, rest_v)?;
    rig.average(16, 1)?;
    rig.analog_enabled = true;
    let mut points = Vec::with_capacity(config.voltages_v.len());
    for &volts in &config.voltages_v {
        rig.hold_dac_v(params, rest_v + volts)?;
        let average = rig.average(settle_ticks, average_ticks)?;
        points.push(KdvPoint {
            dac_code: average.dac_code,
            volts: (f64::from(average.dac_code) - rest_code) * rig.volts_per_code(),
            z_tcp_um: average.z_tcp_um,
            z_enc_um: average.z_enc_um,
            ain_pulses: average.ain_pulses,
            time_s: average.time_s,
            residual_um: 0.0,
        });
    }
    rig.hold_dac_v(params, rest_v)?;
    let probe = fit(&points, |p| p.z_tcp_um)?;
    let encoder = fit(&points, |p| p.z_enc_um)?;
    let k_dv_um_per_v = probe.coefficients[0];
    let t0 = points[0].time_s;
    for p in &mut points {
        p.residual_um =
            p.z_tcp_um - (k_dv_um_per_v * p.volts + probe.coefficients[1] + probe.coefficients[2] * (p.time_s - t0));
    }
    let span_um = points.iter().map(|p| p.z_tcp_um).fold(f64::MIN, f64::max)
        - points.iter().map(|p| p.z_tcp_um).fold(f64::MAX, f64::min);
    if k_dv_um_per_v.is_nan() || k_dv_um_per_v.abs() < 1e-4 || span_um < 4.0 * probe.residual_rms {
        return Err(RigError::AxisDidNotMove { k_dv_um_per_v, span_um, residual_um: probe.residual_rms });
    }
    Ok(KdvReport {
        points,
        k_dv_um_per_v,
        k_dv_encoder_um_per_v: encoder.coefficients[0],
        z0_um: probe.coefficients[1],
        drift_um_per_s: probe.coefficients[2],
        residual_rms_um: probe.residual_rms,
        residual_max_um: probe.residual_max,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::machine_params;
    use crate::SimCoprocessor;
    use sts_emulator::{EffectSpec, Machine, PlantParams};

    fn run(plant: &PlantParams, effects: &[EffectSpec]) -> KdvReport {
        let mut machine = Machine::new(plant, effects, 9).unwrap();
        let mut cop = SimCoprocessor::boot(&[]);
        let params = machine_params(plant, 0.0);
        let mut rig = RestRig::new(&mut cop, &mut machine, f64::from(params.dac_full_scale_v), 0);
        measure_kdv(&mut rig, &params, plant.interface.offset_v, &KdvConfig::default()).unwrap()
    }

    #[test]
    fn k_dv_of_the_default_machine_is_kvc_times_the_pulse() {
        let plant = PlantParams::default();
        let report = run(&plant, &[]);
        // 2000 pulses/V of 1 nm: 2 um/V; the probe's noise (5 nm RMS) averages down.
        assert!((report.k_dv_um_per_v - 2.0).abs() < 0.01, "{report:?}");
        assert!((report.k_dv_encoder_um_per_v - 2.0).abs() < 0.01, "{report:?}");
        assert!(report.residual_rms_um < 0.01, "{report:?}");
        assert_eq!(report.points.len(), 8);
    }

    #[test]
    fn a_probe_scale_error_shows_in_k_dv_and_drift_is_separated() {
        let plant = PlantParams::default();
        let gain: EffectSpec = "sensor-gain:acc_gain=1,probe_gain=1.05".parse().unwrap();
        let report = run(&plant, &[gain]);
        assert!((report.k_dv_um_per_v - 2.1).abs() < 0.01, "{report:?}");
        assert!((report.k_dv_encoder_um_per_v - 2.0).abs() < 0.01, "{report:?}");
        // About 1 um/s of thermal growth: the drift term takes it, the slope stays.
        let drift: EffectSpec = "thermal-drift:rise_k=10,tau_s=100,um_per_k=10".parse().unwrap();
        let report = run(&plant, &[drift]);
        assert!((report.k_dv_um_per_v - 2.0).abs() < 0.01, "{report:?}");
        assert!(report.drift_um_per_s.abs() > 0.3, "{report:?}");
        assert!(report.residual_rms_um < 0.02, "{report:?}");
    }
}
