//! Measuring the analogue path's response `H(f)`: DAC -> motion controller -> servo -> TCP.
//!
//! The co-processor runs a constant twin program (amplitude `amp_um`, phase 0), so that it
//! asks for the displacement `u = -amp_um * sin(command phase)`; the command itself stays at
//! zero while its phase turns at `f`. The capacitance probe at the TCP then reads `H(f) u`.
//! Both are fitted with sine and cosine at the command phase over whole periods after a
//! settling time; `H` is their ratio. Because the co-processor's output of tick `k` acts at
//! tick `k + 1`, `u` of tick `k` is paired with the probe at tick `k + 1`: the bus's latency is
//! part of the path, as it is in operation.
//!
//! Works on any [`Coprocessor`] and any [`Plant`]: it reads only what a lab has (the probe,
//! the co-processor's prediction).

use std::f64::consts::TAU;

use sts_twin_core::analogue_path::{AnaloguePath, PATH_POINTS};
use sts_twin_core::bus::{InputSlot, OutputSlot, IN_FLAG_PHASE_VALID};
use sts_twin_core::features::FeatureConfig;
use sts_twin_core::feedforward::FeedforwardParams;
use sts_twin_core::program::{ProgramBuilder, REG_AMP_UM, REG_PHASE_DEG};
use sts_twin_core::wire::Request;

use sts_model::replay::turns_u32;
use sts_numerics::lsq::least_squares;

use crate::plant::{Counted, Plant, PlantInput, PlantReading};
use crate::{expect_ack, restore_supervisor, supervisor_off, Coprocessor, RigError};
use sts_twin_core::SERVO_RATE_HZ;

/// Program id of the calibration's constant program.
pub const PATH_PROGRAM_ID: u32 = 0xCA1B_0001;

/// Settings of the path measurement.
#[derive(Clone, Debug)]
pub struct PathConfig {
    /// Frequencies to measure, Hz, increasing; at most [`PATH_POINTS`].
    pub freqs_hz: Vec<f64>,
    /// Amplitude of the requested displacement, um. Large enough that the slide slides:
    /// at rest, friction bends a small sine's response (measured on a 3 N / 4.5 N Coulomb /
    /// static machine at 40 Hz: -30.6 deg with 1 um, -8.7 deg with 8 um, -5.9 deg without
    /// friction), while a cut's corrections ride on a moving slide.
    pub amp_um: f64,
    /// Time at each frequency before measuring, s.
    pub settle_s: f64,
    /// Time measured at each frequency (rounded down to whole periods), s.
    pub measure_s: f64,
    /// The servo rate, Hz.
    pub sample_rate_hz: f64,
}

impl Default for PathConfig {
    fn default() -> Self {
        Self {
            freqs_hz: vec![5.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 100.0],
            amp_um: 8.0,
            settle_s: 0.75,
            measure_s: 1.0,
            sample_rate_hz: f64::from(SERVO_RATE_HZ),
        }
    }
}

/// `H` at one frequency.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct PathPoint {
    /// Frequency, Hz.
    pub freq_hz: f64,
    /// `|H|`: TCP amplitude per requested amplitude.
    pub gain: f64,
    /// `arg H`, degrees (a lag is negative).
    pub phase_deg: f64,
}

/// The table for the firmware from points measured with a sine of `amp_um`.
pub fn path_table(points: &[PathPoint], amp_um: f64) -> Result<AnaloguePath, RigError> {
    let responses: Vec<(f32, f32, f32)> =
        points.iter().map(|p| (p.freq_hz as f32, p.gain as f32, p.phase_deg as f32)).collect();
    AnaloguePath::from_responses(amp_um as f32, &responses).map_err(|error| RigError::PathTable { error })
}

/// Least-squares `a sin + b cos + c` of `values` against `angles`; returns `(a, b)`.
fn phasor(angles: &[f64], values: &[f64]) -> Result<(f64, f64), RigError> {
    let rows: Vec<[f64; 3]> = angles.iter().map(|a| [a.sin(), a.cos(), 1.0]).collect();
    let fit = least_squares(&rows, values).ok_or(RigError::SineFit { points: angles.len() })?;
    Ok((fit.coefficients[0], fit.coefficients[1]))
}

/// The machine held at rest (command zero) while the co-processor's output drives its
/// analogue input, one tick at a time.
struct AtRest {
    tick: u64,
    analog_in_v: f64,
    volts_per_code: f64,
}

impl AtRest {
    /// Steps the machine with the last output, then ticks the co-processor with the command
    /// phase `cmd_phase_turns` (turns) and keeps its output for the next step.
    fn tick(
        &mut self,
        coprocessor: &mut dyn Coprocessor,
        machine: &mut dyn Plant,
        cmd_phase_turns: f64,
    ) -> Result<(PlantReading, OutputSlot), RigError> {
        let out = machine.step(&PlantInput {
            z_cmd_um: 0.0,
            x_mm: 0.0,
            spindle_deg: 0.0,
            analog_in_v: self.analog_in_v,
            analog_enabled: true,
        });
        let input = InputSlot {
            tick: self.tick as u32,
            acc_code: out.acc_code,
            flags: IN_FLAG_PHASE_VALID,
            cmd_phase_turns: turns_u32(cmd_phase_turns),
            ..Default::default()
        };
        let output = coprocessor.tick(&input)?;
        self.analog_in_v = f64::from(output.dac_code) * self.volts_per_code;
        self.tick += 1;
        Ok((out, output))
    }
}

/// Measures `H` at each of `config.freqs_hz` with `coprocessor` driving `machine`'s analogue
/// input. The co-processor is configured here (`params` with an empty path table, a short
/// feature window, the constant program, compensation on) and left disabled with its output
/// ramped down to the offset, its program cleared. `first_tick` is the machine's tick count so far.
pub fn measure_path(
    coprocessor: &mut dyn Coprocessor,
    machine: &mut dyn Plant,
    params: FeedforwardParams,
    config: &PathConfig,
    first_tick: u64,
) -> Result<Vec<PathPoint>, RigError> {
    measure_path_counted(coprocessor, machine, params, config, first_tick).map(|(points, _)| points)
}

/// [`measure_path`], with the number of ticks it stepped `machine`.
pub(crate) fn measure_path_counted(
    coprocessor: &mut dyn Coprocessor,
    machine: &mut dyn Plant,
    params: FeedforwardParams,
    config: &PathConfig,
    first_tick: u64,
) -> Result<(Vec<PathPoint>, u64), RigError> {
    let mut machine = Counted { plant: machine, ticks: 0 };
    let machine = &mut machine;
    if config.freqs_hz.is_empty() || config.freqs_hz.len() > PATH_POINTS {
        return Err(RigError::PathFrequencyCount { count: config.freqs_hz.len() });
    }
    let params = FeedforwardParams { analogue_path: AnaloguePath::NONE, ..params };
    expect_ack("the feedforward parameters", coprocessor.request(Request::SetParams(params))?)?;
    // The sine is driven on purpose, with the slide at rest.
    let supervisor = supervisor_off(coprocessor)?;
    // The constant program ignores the features; a short window makes it start soon.
    let features =
        FeatureConfig { window_samples: 800, sample_rate_hz: config.sample_rate_hz as f32, ..FeatureConfig::DEFAULT };
    expect_ack("the feature settings", coprocessor.request(Request::SetFeatureConfig(features))?)?;
    let mut builder = ProgramBuilder::new();
    builder.id(PATH_PROGRAM_ID).constant(config.amp_um as f32).store(REG_AMP_UM);
    builder.constant(0.0).store(REG_PHASE_DEG);
    let program = builder.finish().map_err(|error| RigError::PathProgram { error })?;
    expect_ack("the calibration program", coprocessor.request(Request::UploadProgram { program, activate: true })?)?;
    expect_ack("enabling the output", coprocessor.request(Request::SetEnabled(true))?)?;

    let rate = config.sample_rate_hz;
    let mut rig =
        AtRest { tick: first_tick, analog_in_v: 0.0, volts_per_code: f64::from(params.dac_full_scale_v) / 32767.0 };
    let mut points = Vec::with_capacity(config.freqs_hz.len());
    // The enable ramp and the first model update come before the first frequency's settling.
    let warmup_s = f64::from(params.enable_ramp_ticks) / rate + 0.25;
    for (index, &freq_hz) in config.freqs_hz.iter().enumerate() {
        if !(freq_hz.is_finite() && freq_hz > 0.0 && freq_hz < rate / 2.0) {
            return Err(RigError::PathFrequency { freq_hz });
        }
        let settle_s = config.settle_s + if index == 0 { warmup_s } else { 0.0 };
        let settle_ticks = (settle_s * rate).round() as u64;
        let periods = (config.measure_s * freq_hz).floor().max(1.0);
        let measure_ticks = (periods / freq_hz * rate).round() as u64;
        let mut angles = Vec::with_capacity(measure_ticks as usize);
        let mut requested_um = Vec::with_capacity(measure_ticks as usize);
        let mut tcp_um = Vec::with_capacity(measure_ticks as usize);
        let mut pending: Option<(f64, f64)> = None;
        for k in 0..settle_ticks + measure_ticks + 1 {
            // The phase the output of this tick is for: the next tick's.
            let next_turns = freq_hz * (k + 1) as f64 / rate;
            let (out, output) = rig.tick(coprocessor, machine, next_turns)?;
            if let Some((angle, u_um)) = pending.take() {
                angles.push(angle);
                requested_um.push(u_um);
                tcp_um.push(out.z_tcp_um);
            }
            if k >= settle_ticks && k < settle_ticks + measure_ticks {
                pending = Some((TAU * next_turns.fract(), -f64::from(output.de_pred_pm) * 1e-6));
            }
        }
        let (us, uc) = phasor(&angles, &requested_um)?;
        let (ts, tc) = phasor(&angles, &tcp_um)?;
        let u_amp = us.hypot(uc);
        if u_amp < 0.1 * config.amp_um {
            return Err(RigError::OutputTooSmall { freq_hz, asked_um: u_amp, expected_um: config.amp_um });
        }
        // Phasors as complex numbers (sin part real, cos part imaginary): H = tcp / u.
        let gain = ts.hypot(tc) / u_amp;
        let phase_deg = (tc.atan2(ts) - uc.atan2(us)).to_degrees();
        let phase_deg = (phase_deg + 180.0).rem_euclid(360.0) - 180.0;
        points.push(PathPoint { freq_hz, gain, phase_deg });
    }
    // Ramp the output down before returning, with the sine still turning, so that what
    // comes next (a cut, a stored calibration) starts from an output at the offset and a
    // slide at rest, as after any switch-off, not from the sine cut off mid-stroke.
    expect_ack("disabling the output", coprocessor.request(Request::SetEnabled(false))?)?;
    let last_freq_hz = config.freqs_hz[config.freqs_hz.len() - 1];
    let ramp_down_ticks = u64::from(params.enable_ramp_ticks) + (0.25 * rate).round() as u64;
    for k in 0..ramp_down_ticks {
        rig.tick(coprocessor, machine, last_freq_hz * (k + 1) as f64 / rate)?;
    }
    expect_ack("clearing the calibration program", coprocessor.request(Request::ClearProgram)?)?;
    restore_supervisor(coprocessor, supervisor)?;
    Ok((points, machine.ticks))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::machine_params;
    use crate::SimCoprocessor;
    use sts_emulator::{Machine, PlantParams};

    #[test]
    fn the_phasor_fit_recovers_amplitude_and_phase() {
        let angles: Vec<f64> = (0..400).map(|k| TAU * k as f64 / 200.0).collect();
        let values: Vec<f64> = angles.iter().map(|a| 2.0 * (a + 0.3).sin() + 5.0).collect();
        let (s, c) = phasor(&angles, &values).unwrap();
        assert!((s.hypot(c) - 2.0).abs() < 1e-9);
        assert!((c.atan2(s) - 0.3).abs() < 1e-9);
    }

    #[test]
    fn the_emulated_paths_phase_lags_more_with_frequency_and_matches_a_direct_drive() {
        let plant = PlantParams::default();
        let mut machine = Machine::new(&plant, &[], 3).unwrap();
        let mut cop = SimCoprocessor::boot(&[]);
        let config = PathConfig { freqs_hz: vec![10.0, 40.0], ..PathConfig::default() };
        let params = machine_params(&plant, plant.interface.offset_v);
        let points = measure_path(&mut cop, &mut machine, params, &config, 0).unwrap();
        // The default machine's structural mode amplifies 40 Hz (|H| ~ 1.9) and lags it by a
        // few degrees (the servo loop plus one bus tick); 10 Hz hardly at all.
        assert!((points[0].gain - 1.03).abs() < 0.05, "{points:?}");
        assert!(points[0].phase_deg.abs() < 2.5, "{points:?}");
        assert!((points[1].gain - 1.94).abs() < 0.1, "{points:?}");
        assert!(points[1].phase_deg < -3.0 && points[1].phase_deg > -12.0, "{points:?}");
        let table = path_table(&points, config.amp_um).unwrap();
        assert_eq!(table.count, 2);
        // Left at rest: the output ramped out, not cut off mid-stroke for the next user.
        match cop.request(Request::GetStatus).unwrap() {
            sts_twin_core::wire::Response::Status(status) => {
                assert!(!status.enabled && status.gain == 0.0, "{status:?}");
                assert_eq!(status.program_id, None);
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn friction_hardly_bends_the_path_measured_with_the_default_amplitude() {
        let plant = PlantParams::default();
        let friction =
            "coulomb-friction:coulomb_n=3,static_n=4.5,stribeck_mps=2e-4".parse::<sts_emulator::EffectSpec>().unwrap();
        let phase_at_40_hz = |effects: &[sts_emulator::EffectSpec], amp_um: f64| {
            let mut machine = Machine::new(&plant, effects, 3).unwrap();
            let mut cop = SimCoprocessor::boot(&[]);
            let config = PathConfig { freqs_hz: vec![40.0], amp_um, ..PathConfig::default() };
            let params = machine_params(&plant, plant.interface.offset_v);
            measure_path(&mut cop, &mut machine, params, &config, 0).unwrap()[0].phase_deg
        };
        let linear_deg = phase_at_40_hz(&[], PathConfig::default().amp_um);
        let small_deg = phase_at_40_hz(std::slice::from_ref(&friction), 1.0);
        let default_deg = phase_at_40_hz(std::slice::from_ref(&friction), PathConfig::default().amp_um);
        // A 1 um sine at rest mostly sticks and lags far more; the default one slides.
        assert!(small_deg < linear_deg - 15.0, "1 um: {small_deg} deg, without friction {linear_deg} deg");
        assert!(
            (default_deg - linear_deg).abs() < 4.0,
            "default: {default_deg} deg, without friction {linear_deg} deg"
        );
    }
}
