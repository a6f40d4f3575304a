//! Machining trials: an emulated STS cut of the paper's bicuspid surface (Eq. 6) with the
//! co-processor in the loop, with or without the twin, and its form and phase errors.
//!
//! The cut faces from `r_start_mm` to the centre. Before it, the tool runs the same motion
//! in air at the starting radius for one feature window plus a second, so that the twin's
//! features are complete when the cut begins (a machinist's air cut; the twin is trained on
//! full windows). During the air cut's last half second the X slide accelerates smoothly
//! from rest to the facing feed, reaching the starting radius at full feed as the cut begins
//! (a velocity step there would be an acceleration impulse that deflects a tool post coupled
//! to X). The form error is the peak-to-peak deviation of the true TCP from the
//! design surface over all points cut within `r <= r_eval_mm`; the phase error is the lag
//! of the TCP's fundamental (2C) behind the design's over the same points.

use serde::Serialize;
use sts_emulator::{EffectSpec, Machine, PlantParams};
use sts_twin_core::bus::{OUT_FLAG_DEGRADED, OUT_FLAG_MODEL_ACTIVE};
use sts_twin_core::feedforward::FeedforwardParams;
use sts_twin_core::supervisor::Trip;
use sts_twin_core::wire::{ConfigSource, Request};

use crate::calibrate::{measure_params, CalibrationConfig, PathConfig, PathPoint};
use crate::{expect_ack, run_loop, Bicuspid, Coprocessor, RigError, Trajectory, TrajectoryPoint};
use sts_model::ModelFile;
use sts_twin_core::SERVO_RATE_HZ;

/// Settings of a trial.
#[derive(Clone, Debug)]
pub struct TrialConfig {
    /// Z operational frequency, Hz.
    pub freq_hz: f64,
    /// Starting radius of the cut, mm.
    pub r_start_mm: f64,
    /// Radius within which the form error is evaluated, mm.
    pub r_eval_mm: f64,
    /// X feed per revolution, um.
    pub feed_um_per_rev: f64,
    /// Seed of the machine's noise.
    pub seed: u64,
    /// Feature window in the co-processor, samples; `None`: [`cut_window_samples`]. The
    /// model's own window (5 s in training) is not used for cutting: the features of a steady
    /// motion hardly depend on the window, and a short one follows the cut's changing
    /// amplitude sooner.
    pub window_samples: Option<u32>,
}

impl Default for TrialConfig {
    fn default() -> Self {
        Self { freq_hz: 40.0, r_start_mm: 0.5, r_eval_mm: 0.5, feed_um_per_rev: 5.0, seed: 1, window_samples: None }
    }
}

/// The feature window for a cut at `freq_hz`: four periods of the Z motion, at least 0.1 s,
/// in whole 16-sample blocks. Shorter windows follow the cut's shrinking amplitude sooner
/// but their spectral features (the signal frequency) get coarse: measured at 40 Hz, 0.5 s
/// left 0.36 um PV and -1.6 deg, 0.1 s 0.08 um and -0.3 deg, 0.05 s went wrong (5.7 um).
pub fn cut_window_samples(freq_hz: f64, sample_rate_hz: f64) -> u32 {
    let block = sts_twin_core::features::BLOCK_SAMPLES as f64;
    let seconds = (4.0 / freq_hz.max(1e-3)).max(0.1);
    ((seconds * sample_rate_hz / block).ceil() * block).min(sts_twin_core::features::MAX_WINDOW_SAMPLES as f64) as u32
}

/// A cut binned over the disc (radius x spindle angle), for the report's maps.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CutMaps {
    /// Outer radius of the maps, mm.
    pub r_max_mm: f64,
    /// Mean true TCP height per bin, um, `[radial][angular]` (`None`: no point there).
    pub surface_um: Vec<Vec<Option<f64>>>,
    /// Mean deviation of the TCP from the design surface per bin, um.
    pub deviation_um: Vec<Vec<Option<f64>>>,
}

/// Most radial bins of [`CutMaps`] (fewer when the cut is short: each ring spans at least
/// two revolutions of the feed, so that every bin of it is cut).
pub const MAP_RADIAL_BINS: usize = 25;
/// Angular bins of [`CutMaps`] (4 degrees each).
pub const MAP_ANGULAR_BINS: usize = 90;

#[derive(Clone, Copy, Default)]
struct Bin {
    tcp_um: f64,
    dev_um: f64,
    points: u32,
}

/// What a trial measured.
#[derive(Clone, Debug, Serialize)]
pub struct TrialReport {
    /// Z operational frequency, Hz.
    pub freq_hz: f64,
    /// Whether the twin compensated.
    pub twin: bool,
    /// "hil" (firmware in QEMU) or "sim" (the same core on the host).
    pub coprocessor: String,
    /// Peak-to-peak deviation of the TCP from the design surface within `r_eval_mm`, um.
    pub form_error_pv_um: f64,
    /// Lag of the TCP's fundamental behind the design's, degrees.
    pub phase_error_deg: f64,
    /// RMS deviation from the design surface, um.
    pub form_error_rms_um: f64,
    /// Machine time of the cut (without the air cut), s.
    pub cut_time_s: f64,
    /// Machine time of the whole trial (air cut and cut), s.
    pub machine_time_s: f64,
    /// Wall time of the whole trial (configuration, air cut and cut), s.
    pub wall_time_s: f64,
    /// Points evaluated.
    pub points: usize,
    /// Firmware fault counters' sum at the end.
    pub fault_count: u32,
    /// Ticks of the cut with a model active and compensation trusted.
    pub cut_ticks_compensating: u64,
    /// Ticks of the cut with a model active but compensation held off (flagged degraded:
    /// the supervisor, or untrusted inputs; `supervisor` says which).
    pub cut_ticks_held_off: u64,
    /// The largest change of the DAC code from one tick to the next over the whole trial
    /// (air cut and cut): the slew limit bounds it.
    pub max_dac_step_codes: i32,
    /// The co-processor's supervisor at the end of the trial.
    pub supervisor: sts_twin_core::supervisor::SupervisorState,
    /// Its trips over the trial.
    pub supervisor_trips: u32,
    /// The cut over the disc (not in the JSON).
    #[serde(skip)]
    pub maps: CutMaps,
}

impl TrialReport {
    /// What the co-processor did in the cut, for a table: the shares of the cut's ticks with
    /// compensation on and held off, with the supervisor's state at the end.
    pub fn compensation_summary(&self) -> String {
        let share = |ticks: u64| 100.0 * ticks as f64 / self.points.max(1) as f64;
        let mut summary = format!("on {:.0}%", share(self.cut_ticks_compensating));
        if self.cut_ticks_held_off > 0 {
            let why = match self.supervisor.tripped {
                Some(Trip::WorseThanBare) => "the supervisor: worse than bare",
                Some(Trip::Shaking) => "the supervisor: shaking the structure",
                Some(Trip::Saturation) => "the supervisor: DAC saturated",
                None if self.supervisor.gated => "the gate: accelerometer noise",
                None => "inputs not trusted, or the supervisor before its baseline",
            };
            summary.push_str(&format!(", held off {:.0}% ({why})", share(self.cut_ticks_held_off)));
        }
        summary
    }
}

/// Calibrates `coprocessor` before a cut as a lab does (`sts-twin calibrate-offset`'s steps
/// 1-3, [`measure_params`]) on a machine like the trial's (same plant and effects, its own
/// noise seed): the interface offset, `K_dv` and `K_vc`, and with `path` the analogue path.
/// Returns the parameters to cut with and the path's points (empty without `path`).
pub fn calibrated(
    coprocessor: &mut dyn Coprocessor,
    plant: &PlantParams,
    effects: &[EffectSpec],
    seed: u64,
    path: bool,
) -> Result<(FeedforwardParams, Vec<PathPoint>), RigError> {
    let mut machine = Machine::new(plant, effects, seed ^ 0xCA1B)?;
    let config = CalibrationConfig { path: path.then(PathConfig::default), ..CalibrationConfig::default() };
    let measured = measure_params(coprocessor, &mut machine, plant, &config, &mut |_| {})?;
    Ok((measured.params, measured.path))
}

/// Time over which X accelerates to the facing feed before the cut, s.
const X_APPROACH_S: f64 = 0.5;

/// Distance of X from the starting radius `before_s` seconds before the cut: at rest, then a
/// constant acceleration over `ramp_s` to the feed velocity `feed_mm_per_s` at the cut.
fn approach_mm(before_s: f64, feed_mm_per_s: f64, ramp_s: f64) -> f64 {
    let tau = before_s.clamp(0.0, ramp_s);
    feed_mm_per_s * (tau - tau * tau / (2.0 * ramp_s))
}

/// The STS trajectory with an air cut before it.
struct WithAirCut {
    cut: Bicuspid,
    air_s: f64,
}

impl Trajectory for WithAirCut {
    fn at(&self, t_s: f64) -> TrajectoryPoint {
        if t_s < self.air_s {
            // The same motion at the starting radius, phase-continuous into the cut.
            let mut p = self.cut.at(0.0);
            let revs = self.cut.spindle_rev_per_s() * (t_s - self.air_s);
            let c_deg = 360.0 * revs.rem_euclid(1.0);
            p.spindle_deg = c_deg;
            p.z_cmd_um = Bicuspid::design_z_um(self.cut.r_start_mm, c_deg);
            p.phase_turns = sts_model::replay::turns_u32(2.0 * revs);
            p.x_mm = self.cut.r_start_mm
                + approach_mm(self.air_s - t_s, self.cut.feed_mm_per_s(), (self.air_s / 2.0).min(X_APPROACH_S));
            p
        } else {
            self.cut.at(t_s - self.air_s)
        }
    }
    fn sample_rate_hz(&self) -> f64 {
        self.cut.sample_rate_hz
    }
    fn duration_s(&self) -> f64 {
        self.air_s + self.cut.duration_s()
    }
}

/// The feedforward parameters (offset, K_dv, analogue path, ...) the co-processor loaded from
/// its config store at boot, as `calibrate-offset` stored them; an error that says what to run
/// when it booted without a stored calibration.
pub fn stored_params(coprocessor: &mut dyn Coprocessor) -> Result<FeedforwardParams, RigError> {
    let status = crate::status(coprocessor)?;
    match status.config_source {
        ConfigSource::Stored => Ok(status.params),
        other => Err(RigError::NotCalibrated { config_source: other }),
    }
}

/// Runs one trial on `coprocessor`, which is configured here: the feedforward parameters
/// (`params`), and with `model` its feature settings and program, compensation enabled.
pub fn run_trial(
    coprocessor: &mut dyn Coprocessor,
    plant: &PlantParams,
    effects: &[EffectSpec],
    model: Option<&ModelFile>,
    params: FeedforwardParams,
    config: &TrialConfig,
) -> Result<TrialReport, RigError> {
    let started = std::time::Instant::now();
    let mut machine = Machine::new(plant, effects, config.seed)?;
    expect_ack("the feedforward parameters", coprocessor.request(Request::SetParams(params))?)?;
    let window_s = match model {
        Some(model) => {
            let mut features = model.feature_config;
            features.window_samples = config
                .window_samples
                .unwrap_or_else(|| cut_window_samples(config.freq_hz, f64::from(features.sample_rate_hz)));
            expect_ack("the feature settings", coprocessor.request(Request::SetFeatureConfig(features))?)?;
            let program = model.firmware_program()?;
            expect_ack("the twin program", coprocessor.request(Request::UploadProgram { program, activate: true })?)?;
            expect_ack("enabling compensation", coprocessor.request(Request::SetEnabled(true))?)?;
            f64::from(features.window_samples) / f64::from(features.sample_rate_hz)
        }
        None => 0.0,
    };
    let cut = Bicuspid {
        freq_hz: config.freq_hz,
        r_start_mm: config.r_start_mm,
        feed_um_per_rev: config.feed_um_per_rev,
        sample_rate_hz: f64::from(SERVO_RATE_HZ),
    };
    // The air cut: the feature window, the enable ramp and a settling second; at low
    // speed, where the window is long, the supervisor's baseline (two bare windows a window
    // apart, after the first) before the ramp, so that the cut starts compensated.
    let air_s = if model.is_some() { (window_s + 1.5).max(3.0 * window_s + 1.0) } else { 1.0 };
    let trajectory = WithAirCut { cut, air_s };
    let ticks = (trajectory.duration_s() * f64::from(SERVO_RATE_HZ)).round() as u64;
    let mut deviations = Vec::new();
    let (mut s_tcp, mut c_tcp, mut s_des, mut c_des) = (0.0, 0.0, 0.0, 0.0);
    let mut last_fault = 0;
    let (mut held_off, mut compensating) = (0u64, 0u64);
    let (mut last_dac, mut max_dac_step_codes) = (None::<i16>, 0i32);
    let radial_bins =
        ((config.r_eval_mm * 1e3 / (2.0 * config.feed_um_per_rev)).floor() as usize).clamp(1, MAP_RADIAL_BINS);
    let angular_bins = MAP_ANGULAR_BINS;
    let mut bins = vec![Bin::default(); radial_bins * angular_bins];
    run_loop(&mut machine, coprocessor, &trajectory, 0..ticks, f64::from(params.dac_full_scale_v), true, |s| {
        last_fault = s.output.fault_count;
        if let Some(last) = last_dac.replace(s.output.dac_code) {
            max_dac_step_codes = max_dac_step_codes.max((i32::from(s.output.dac_code) - i32::from(last)).abs());
        }
        let t = s.machine.time_s;
        if t < air_s || s.point.x_mm > config.r_eval_mm {
            return;
        }
        let flags = s.output.flags;
        if flags & OUT_FLAG_MODEL_ACTIVE != 0 {
            let degraded = flags & OUT_FLAG_DEGRADED != 0;
            held_off += u64::from(degraded);
            compensating += u64::from(!degraded);
        }
        let design = s.point.z_cmd_um;
        let dev = s.machine.z_tcp_true_um - design;
        deviations.push(dev);
        let ri = ((s.point.x_mm / config.r_eval_mm * radial_bins as f64) as usize).min(radial_bins - 1);
        let ai = ((s.point.spindle_deg.rem_euclid(360.0) / 360.0 * angular_bins as f64) as usize).min(angular_bins - 1);
        let bin = &mut bins[ri * angular_bins + ai];
        bin.tcp_um += s.machine.z_tcp_true_um;
        bin.dev_um += dev;
        bin.points += 1;
        // Fundamental at 2C of the TCP and of the design (the ramp term is common to both
        // and nearly orthogonal over whole revolutions).
        let angle = 2.0 * s.point.spindle_deg.to_radians();
        let (sin, cos) = angle.sin_cos();
        s_tcp += s.machine.z_tcp_true_um * sin;
        c_tcp += s.machine.z_tcp_true_um * cos;
        s_des += design * sin;
        c_des += design * cos;
    })?;
    if deviations.is_empty() {
        return Err(RigError::NoCutPoints { r_eval_mm: config.r_eval_mm });
    }
    let status = crate::status(coprocessor)?;
    let mean = |f: fn(&Bin) -> f64| -> Vec<Vec<Option<f64>>> {
        bins.chunks(angular_bins)
            .map(|row| row.iter().map(|b| (b.points > 0).then(|| f(b) / f64::from(b.points))).collect())
            .collect()
    };
    let maps = CutMaps { r_max_mm: config.r_eval_mm, surface_um: mean(|b| b.tcp_um), deviation_um: mean(|b| b.dev_um) };
    let max = deviations.iter().cloned().fold(f64::MIN, f64::max);
    let min = deviations.iter().cloned().fold(f64::MAX, f64::min);
    let rms = (deviations.iter().map(|d| d * d).sum::<f64>() / deviations.len() as f64).sqrt();
    let phase_tcp = c_tcp.atan2(s_tcp);
    let phase_des = c_des.atan2(s_des);
    let mut lag_deg = (phase_des - phase_tcp).to_degrees();
    lag_deg = (lag_deg + 180.0).rem_euclid(360.0) - 180.0;
    Ok(TrialReport {
        freq_hz: config.freq_hz,
        twin: model.is_some(),
        coprocessor: coprocessor.kind().to_string(),
        form_error_pv_um: max - min,
        phase_error_deg: lag_deg,
        form_error_rms_um: rms,
        cut_time_s: cut.duration_s(),
        machine_time_s: ticks as f64 / f64::from(SERVO_RATE_HZ),
        wall_time_s: started.elapsed().as_secs_f64(),
        points: deviations.len(),
        fault_count: last_fault,
        cut_ticks_compensating: compensating,
        cut_ticks_held_off: held_off,
        max_dac_step_codes,
        supervisor: status.supervisor,
        supervisor_trips: status.counters.supervisor_trips,
        maps,
    })
}
