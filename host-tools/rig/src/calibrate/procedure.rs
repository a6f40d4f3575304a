//! The whole calibration before a cut, as `sts-twin calibrate-offset` runs it:
//!
//! 0. read how the co-processor booted (its config store valid, empty, or corrupt);
//! 1. the interface offset ([`super::offset`]), axis at rest, controller input off;
//! 2. `K_dv` ([`super::kdv`]), controller input on;
//! 3. the analogue path's phase ([`super::path`]);
//! 4. store: `SetParams`, `SaveConfig`, read back;
//! 5. reboot the co-processor on the same store and read back what it loaded;
//! 6. the enable check ([`super::enable`]) on the reloaded configuration.
//!
//! Verified when every read-back matches, the firmware loaded the stored record, the offset
//! left no pulse at rest and switching on moved the axis by less than one pulse.

use std::fmt;

use serde::Serialize;
use sts_emulator::{EffectSpec, Machine, PlantParams};
use sts_twin_core::analogue_path::{PATH_MAX_FREQ_HZ, PATH_POINTS};
use sts_twin_core::feedforward::FeedforwardParams;
use sts_twin_core::supervisor::SupervisorParams;
use sts_twin_core::wire::{ConfigSource, Rejection, Request, Response};

use super::board::Board;
use super::enable::{enable_check, EnableCheck, EnableConfig};
use super::kdv::{measure_kdv, KdvConfig, KdvReport};
use super::offset::{measure_offset, OffsetConfig, OffsetReport};
use super::path::{measure_path_counted, path_table, PathConfig, PathPoint};
use super::rest::{status, RestRig};
use crate::machine_params;
use crate::plant::Plant;
use crate::{expect_ack, Coprocessor, RigError};

/// Settings of the whole calibration.
#[derive(Clone, Debug, Default)]
pub struct CalibrationConfig {
    /// The offset measurement.
    pub offset: OffsetConfig,
    /// The `K_dv` measurement.
    pub kdv: KdvConfig,
    /// The analogue path's measurement; `None` stores an empty table (no phase correction).
    pub path: Option<PathConfig>,
    /// The enable check.
    pub enable: EnableConfig,
}

impl CalibrationConfig {
    /// Checks the settings that would otherwise fail only after the first measurements.
    pub fn validate(&self) -> Result<(), RigError> {
        if let Some(path) = &self.path {
            let freqs = &path.freqs_hz;
            let nyquist_hz = (path.sample_rate_hz / 2.0).min(f64::from(PATH_MAX_FREQ_HZ));
            let increasing = freqs.windows(2).all(|w| w[0] < w[1]);
            let in_range = freqs.iter().all(|f| f.is_finite() && *f > 0.0 && *f < nyquist_hz);
            if freqs.is_empty() || freqs.len() > PATH_POINTS || !increasing || !in_range {
                return Err(RigError::PathFrequencies { freqs_hz: freqs.clone(), nyquist_hz });
            }
            if !(path.amp_um.is_finite() && path.amp_um > 0.0 && path.settle_s >= 0.0 && path.measure_s > 0.0) {
                return Err(RigError::PathSettings);
            }
        }
        Ok(())
    }

    /// The full calibration: every step with its default settings.
    pub fn full() -> Self {
        Self { path: Some(PathConfig::default()), ..Self::default() }
    }

    /// A short calibration (the path at 10 and 40 Hz with short settling, fewer `K_dv`
    /// points), about 3 s of machine time, for tests.
    pub fn quick() -> Self {
        Self {
            offset: OffsetConfig { fit_voltages_v: vec![-0.2, 0.0, 0.2], search_codes: 2, ..OffsetConfig::default() },
            kdv: KdvConfig {
                voltages_v: vec![0.0, 1.0, -1.0, 2.0, 0.0],
                settle_s: 0.1,
                average_s: 0.03,
                ..KdvConfig::default()
            },
            path: Some(PathConfig {
                freqs_hz: vec![10.0, 40.0],
                settle_s: 0.25,
                measure_s: 0.5,
                ..PathConfig::default()
            }),
            enable: EnableConfig { settle_s: 0.15, window_s: 0.05, ..EnableConfig::default() },
        }
    }
}

/// How the co-processor booted.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct BootState {
    /// Where its configuration came from.
    pub config_source: ConfigSource,
    /// The parameters in force.
    pub params: FeedforwardParams,
    /// Whether compensation is asked for.
    pub enabled: bool,
    /// The supervisor's thresholds in force.
    pub supervisor: SupervisorParams,
}

impl BootState {
    /// Reads it from the co-processor's status.
    pub fn read(coprocessor: &mut dyn Coprocessor) -> Result<Self, RigError> {
        let status = status(coprocessor)?;
        Ok(Self {
            config_source: status.config_source,
            params: status.params,
            enabled: status.enabled,
            supervisor: status.supervisor_params,
        })
    }
}

/// A sentence on where a configuration came from.
pub fn describe_config_source(source: ConfigSource) -> &'static str {
    match source {
        ConfigSource::Stored => "loaded its stored calibration (record valid: magic, version, CRC, parameters)",
        ConfigSource::Defaults => "found no calibration in its config store: it runs on safe defaults (compensation off, offset 0 V)",
        ConfigSource::DefaultsAfterCorrupt => {
            "found its config store CORRUPT (bad magic, version, CRC or parameters) and ignored it: it runs on safe defaults (compensation off, offset 0 V)"
        }
    }
}

impl fmt::Display for BootState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "the co-processor {}", describe_config_source(self.config_source))
    }
}

/// Storing the calibration and reading it back.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct StoreCheck {
    /// `SaveConfig` was acknowledged.
    pub saved: bool,
    /// The parameters in force after `SetParams` are the calibration, bit for bit.
    pub live_params_match: bool,
    /// Where the configuration came from after the reboot.
    pub config_source_after_reboot: ConfigSource,
    /// The parameters loaded after the reboot are the calibration, bit for bit.
    pub stored_params_match: bool,
    /// The supervisor's thresholds after the reboot are those in force when it was saved.
    pub stored_supervisor_match: bool,
}

impl StoreCheck {
    /// Everything read back as written.
    pub fn passed(&self) -> bool {
        self.saved
            && self.live_params_match
            && self.stored_params_match
            && self.stored_supervisor_match
            && self.config_source_after_reboot == ConfigSource::Stored
    }
}

/// What the calibration did and found. The first fields are the summary (`--json`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CalibrationReport {
    /// "hil" (the firmware in QEMU) or "sim" (its core on the host).
    pub coprocessor: String,
    /// The offset stored, V.
    pub offset_v: f64,
    /// `K_dv` stored, um per V.
    pub k_dv_um_per_v: f64,
    /// RMS residual of the `K_dv` fit, um.
    pub k_dv_fit_residual_um: f64,
    /// `K_vc` stored, pulses per V.
    pub k_vc_pulses_per_v: f64,
    /// The analogue path's measured points (empty when not measured).
    pub path: Vec<PathPoint>,
    /// Everything stored was read back, the firmware loaded it after a reboot and switching
    /// compensation on moved the axis by less than one pulse.
    pub verified: bool,
    /// Where the co-processor's configuration came from after the verifying reboot.
    pub config_source: ConfigSource,
    /// Where it came from when the calibration started.
    pub boot_config_source: ConfigSource,
    /// Step 1 in detail.
    pub offset: OffsetReport,
    /// Step 2 in detail.
    pub kdv: KdvReport,
    /// The parameters stored.
    pub params: FeedforwardParams,
    /// Steps 4 and 5.
    pub store: StoreCheck,
    /// Step 6.
    pub enable: EnableCheck,
}

/// Runs the calibration on `board` against an emulated machine (`plant` with `effects`,
/// noise `seed`) at rest. `progress` hears of each step as it starts.
pub fn calibrate(
    board: &mut dyn Board,
    plant: &PlantParams,
    effects: &[EffectSpec],
    seed: u64,
    config: &CalibrationConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<CalibrationReport, RigError> {
    config.validate()?;
    let mut machine = Machine::new(plant, effects, seed)?;
    let boot = BootState::read(board.coprocessor())?;
    progress(&boot.to_string());

    let Measured { params, offset, kdv, path, rest_tick } =
        measure_params(board.coprocessor(), &mut machine, plant, config, progress)?;
    let fs_v = f64::from(params.dac_full_scale_v);
    let mut rig = RestRig::new(board.coprocessor(), &mut machine, fs_v, rest_tick);

    progress("step 4: storing the calibration in the co-processor's config store");
    rig.request("the calibrated parameters", Request::SetParams(params))?;
    let saved = match board_request(&mut rig, Request::SaveConfig)? {
        Response::Ack => true,
        Response::Rejected(Rejection::Store) => false,
        other => return Err(RigError::Unexpected { request: "SaveConfig", response: Box::new(other) }),
    };
    let live = rig.status()?;
    let live_params_match = live.params == params;

    progress("step 5: rebooting the co-processor and reading back what it loaded");
    board.reboot()?;
    let reloaded = BootState::read(board.coprocessor())?;
    let store = StoreCheck {
        saved,
        live_params_match,
        config_source_after_reboot: reloaded.config_source,
        stored_params_match: reloaded.params == params,
        stored_supervisor_match: reloaded.supervisor == live.supervisor_params,
    };

    progress("step 6: switching compensation on at rest");
    let mut rig = RestRig::new(board.coprocessor(), &mut machine, fs_v, 0);
    let enable = enable_check(&mut rig, plant.interface.pulse_nm, reloaded.params.enable_ramp_ticks, &config.enable)?;
    let verified = offset.nulled() && store.passed() && enable.passed();
    Ok(CalibrationReport {
        coprocessor: board.kind().to_string(),
        offset_v: f64::from(params.offset_v),
        k_dv_um_per_v: f64::from(params.k_dv_um_per_v),
        k_dv_fit_residual_um: kdv.residual_rms_um,
        k_vc_pulses_per_v: f64::from(params.k_vc_pulses_per_v),
        path,
        verified,
        config_source: reloaded.config_source,
        boot_config_source: boot.config_source,
        offset,
        kdv,
        params,
        store,
        enable,
    })
}

/// What steps 1-3 measured.
pub struct Measured {
    /// The parameters: the co-processor's hardware settings with the measured offset,
    /// `K_dv`, `K_vc` and (where measured) the analogue path's table.
    pub params: FeedforwardParams,
    /// Step 1 in detail.
    pub offset: OffsetReport,
    /// Step 2 in detail.
    pub kdv: KdvReport,
    /// Step 3's points (empty when not measured).
    pub path: Vec<PathPoint>,
    /// The tick the rest rig reached.
    rest_tick: u64,
}

/// Steps 1-3 of the calibration on `coprocessor` against `machine` (any [`Plant`]) at rest:
/// compensation off, the program cleared, then the offset, `K_dv` and (with `config.path`) the
/// analogue path. `plant` gives only the starting parameters ([`machine_params`]).
/// The calibration runs them before it stores; a cut on the emulated machine runs them before
/// it starts, as a lab calibrates its co-processor before cutting.
pub fn measure_params(
    coprocessor: &mut dyn Coprocessor,
    machine: &mut dyn Plant,
    plant: &PlantParams,
    config: &CalibrationConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<Measured, RigError> {
    // The DAC's full scale, slew limit and ramp are the co-processor's hardware settings;
    // offset, K_dv and K_vc are what this measures (the plant's values are no more than a
    // starting point).
    let base = machine_params(plant, 0.0);
    base.validate().map_err(|error| RigError::StartingParams { error })?;
    let fs_v = f64::from(base.dac_full_scale_v);
    expect_ack("switching compensation off", coprocessor.request(Request::SetEnabled(false))?)?;
    expect_ack("clearing the program", coprocessor.request(Request::ClearProgram)?)?;
    expect_ack("the starting parameters", coprocessor.request(Request::SetParams(base))?)?;

    let mut rig = RestRig::new(coprocessor, machine, fs_v, 0);
    progress("step 1: the interface offset (DAC codes against the controller's input reading, axis at rest)");
    let offset = measure_offset(&mut rig, &base, &config.offset)?;
    progress("step 2: K_dv (known voltages held, the probe at the TCP)");
    let kdv = measure_kdv(&mut rig, &base, offset.offset_v, &config.kdv)?;
    let mut params = FeedforwardParams {
        offset_v: offset.offset_v as f32,
        k_dv_um_per_v: kdv.k_dv_um_per_v as f32,
        k_vc_pulses_per_v: offset.k_vc_pulses_per_v as f32,
        ..base
    };
    params.validate().map_err(|error| RigError::MeasuredParams { error, params: Box::new(params) })?;
    let path = match &config.path {
        Some(path_config) => {
            progress("step 3: the analogue path's phase (a sine through the analogue input at each frequency)");
            let (cop, machine, tick) = rig.parts();
            let (points, ticks) = measure_path_counted(cop, machine, params, path_config, tick)?;
            rig.advanced(ticks, -offset.offset_v);
            params.analogue_path = path_table(&points, path_config.amp_um)?;
            points
        }
        None => Vec::new(),
    };
    Ok(Measured { params, offset, kdv, path, rest_tick: rig.tick() })
}

fn board_request(rig: &mut RestRig<'_>, request: Request) -> Result<Response, RigError> {
    let (cop, _, _) = rig.parts();
    cop.request(request)
}

fn yes_no(ok: bool) -> &'static str {
    if ok {
        "yes"
    } else {
        "NO"
    }
}

impl fmt::Display for CalibrationReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let o = &self.offset;
        let k = &self.kdv;
        let pulse_nm = self.enable.pulse_nm;
        writeln!(
            f,
            "co-processor ({}): at the start it {}",
            self.coprocessor,
            describe_config_source(self.boot_config_source)
        )?;
        writeln!(f, "1. interface offset (axis at rest, controller's analogue input off)")?;
        for p in &o.fit_points {
            writeln!(
                f,
                "     DAC {:>+6} = {:>+9.3} mV -> controller reads {:>+9.3} mV = {:>+7.1} pulses",
                p.dac_code,
                p.dac_v * 1e3,
                p.ain_read_v * 1e3,
                p.ain_pulses
            )?;
        }
        writeln!(
            f,
            "   fit: reading = {:.5} x DAC {:+.3} mV (residual {:.3} mV RMS); K_vc = {:.1} pulses/V",
            o.interface_gain,
            o.interface_offset_v * 1e3,
            o.fit_residual_v * 1e3,
            o.k_vc_pulses_per_v
        )?;
        let search: Vec<String> =
            o.search_points.iter().map(|p| format!("{} -> {:+.1}", p.dac_code, p.ain_pulses)).collect();
        writeln!(f, "   codes around the null (code -> pulses): {}", search.join(", "))?;
        writeln!(
            f,
            "   offset set to {:+.3} mV (DAC code {} at rest): the controller makes {:+.1} pulses at rest (uncalibrated, 0 V: {:+.1} pulses = {:+.1} nm)",
            self.offset_v * 1e3,
            o.rest_dac_code,
            o.rest_pulses,
            o.uncalibrated_pulses,
            o.uncalibrated_pulses * pulse_nm
        )?;
        writeln!(f, "2. K_dv (controller's analogue input on, voltages about the rest code, probe at the TCP)")?;
        for p in &k.points {
            writeln!(
                f,
                "     {:>+7.4} V -> TCP {:>+8.4} um (encoder {:>+8.4} um), residual {:>+7.4} um",
                p.volts, p.z_tcp_um, p.z_enc_um, p.residual_um
            )?;
        }
        writeln!(
            f,
            "   K_dv = {:.5} um/V (encoder {:.5} um/V), fit residual {:.4} um RMS (max {:.4} um), drift {:+.4} um/s",
            self.k_dv_um_per_v, k.k_dv_encoder_um_per_v, self.k_dv_fit_residual_um, k.residual_max_um, k.drift_um_per_s
        )?;
        if self.path.is_empty() {
            writeln!(f, "3. analogue path: not measured (empty table: no phase correction)")?;
        } else {
            let cells: Vec<String> = self
                .path
                .iter()
                .map(|p| format!("{:.0} Hz |H| {:.3} {:+.2} deg", p.freq_hz, p.gain, p.phase_deg))
                .collect();
            writeln!(f, "3. analogue path (DAC -> TCP): {}", cells.join("; "))?;
        }
        let s = &self.store;
        writeln!(
            f,
            "4. stored (SetParams, SaveConfig): saved {}, parameters read back identical {}",
            yes_no(s.saved),
            yes_no(s.live_params_match)
        )?;
        writeln!(
            f,
            "5. after a reboot the co-processor {}; parameters identical {}, supervisor thresholds identical {}",
            describe_config_source(s.config_source_after_reboot),
            yes_no(s.stored_params_match),
            yes_no(s.stored_supervisor_match)
        )?;
        let e = &self.enable;
        writeln!(
            f,
            "6. compensation switched on at rest: the controller added at most {} pulses ({:.1} nm); the probe moved {:+.2} nm (limit: one pulse, {} nm)",
            e.added_pulses_max,
            e.added_pulses_max as f64 * pulse_nm,
            e.tcp_move_nm,
            pulse_nm
        )?;
        if self.verified {
            write!(
                f,
                "calibration VERIFIED: offset {:+.3} mV, K_dv {:.5} um/V, K_vc {:.1} pulses/V, {} path points",
                self.offset_v * 1e3,
                self.k_dv_um_per_v,
                self.k_vc_pulses_per_v,
                self.path.len()
            )
        } else {
            write!(f, "calibration NOT VERIFIED: {}", self.failures().join("; "))
        }
    }
}

impl CalibrationReport {
    /// Why the calibration is not verified (empty when it is).
    pub fn failures(&self) -> Vec<String> {
        let mut out = Vec::new();
        if !self.offset.nulled() {
            out.push(format!("the best offset leaves {:+.1} pulses at rest", self.offset.rest_pulses));
        }
        if !self.store.saved {
            out.push("the co-processor could not write its config store".into());
        }
        if !self.store.live_params_match {
            out.push("the parameters in force differ from those sent".into());
        }
        if self.store.config_source_after_reboot != ConfigSource::Stored {
            out.push(format!(
                "after the reboot the co-processor {}, not its stored calibration",
                describe_config_source(self.store.config_source_after_reboot)
            ));
        }
        if !self.store.stored_params_match {
            out.push("the parameters loaded after the reboot differ from those stored".into());
        }
        if !self.enable.passed() {
            out.push(format!(
                "switching on added {} pulses and moved the probe {:+.2} nm (limit one pulse, {} nm)",
                self.enable.added_pulses_max, self.enable.tcp_move_nm, self.enable.pulse_nm
            ));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::SimCoprocessor;
    use sts_twin_core::config::PersistentConfig;

    #[test]
    fn a_sim_calibration_is_stored_reloaded_and_enabling_moves_less_than_a_pulse() {
        let plant = PlantParams::default();
        let mut board = SimCoprocessor::boot(&[]);
        let mut heard = Vec::new();
        let report =
            calibrate(&mut board, &plant, &[], 3, &CalibrationConfig::quick(), &mut |s| heard.push(s.to_string()))
                .unwrap();
        assert!(report.verified, "{report}");
        assert_eq!(report.boot_config_source, ConfigSource::Defaults);
        assert_eq!(report.config_source, ConfigSource::Stored);
        assert!((report.offset_v - 0.012).abs() < 2e-4, "{report}");
        assert!((report.k_dv_um_per_v - 2.0).abs() < 0.02, "{report}");
        assert_eq!(report.enable.added_pulses_max, 0, "{report}");
        assert!(report.enable.tcp_true_move_nm.abs() < plant.interface.pulse_nm, "{report}");
        assert_eq!(report.path.len(), 2);
        assert_eq!(report.params.analogue_path.count, 2);
        // The store holds exactly the reported parameters.
        let stored = PersistentConfig::decode(board.twin().stored_config()).unwrap();
        assert_eq!(stored.params, report.params);
        assert_eq!(heard.len(), 7, "{heard:?}");
        let text = report.to_string();
        assert!(text.contains("calibration VERIFIED") && text.contains("K_dv = "), "{text}");
        let json = serde_json::to_value(&report).unwrap();
        for key in ["offset_v", "k_dv_um_per_v", "k_dv_fit_residual_um", "path", "verified", "config_source"] {
            assert!(json.get(key).is_some(), "{key} missing from {json}");
        }
        assert_eq!(json["config_source"], "Stored");

        // The same machine without the calibrated offset: switching on moves it by the
        // interface offset's 24 pulses.
        let uncalibrated = FeedforwardParams { offset_v: 0.0, ..report.params };
        expect_ack("params", board.request(Request::SetParams(uncalibrated)).unwrap()).unwrap();
        let mut machine = Machine::new(&plant, &[], 3).unwrap();
        let mut rig = RestRig::new(&mut board, &mut machine, 10.0, 0);
        let check =
            enable_check(&mut rig, plant.interface.pulse_nm, uncalibrated.enable_ramp_ticks, &EnableConfig::default())
                .unwrap();
        assert_eq!(check.added_pulses_max, 24, "{check:?}");
        assert!((check.tcp_true_move_nm - 24.0).abs() < 1.0, "{check:?}");
        assert!(!check.passed());
    }

    #[test]
    fn bad_path_frequencies_are_refused_before_measuring() {
        let plant = PlantParams::default();
        for freqs_hz in [vec![], vec![40.0, 10.0], vec![10.0, f64::NAN], vec![5000.0], vec![1.0; 9], vec![0.0, 10.0]] {
            let config = CalibrationConfig {
                path: Some(PathConfig { freqs_hz: freqs_hz.clone(), ..PathConfig::default() }),
                ..CalibrationConfig::quick()
            };
            let mut board = SimCoprocessor::boot(&[]);
            let mut heard = 0;
            let err = calibrate(&mut board, &plant, &[], 1, &config, &mut |_| heard += 1).unwrap_err();
            assert!(err.to_string().contains("analogue path"), "{freqs_hz:?}: {err}");
            assert_eq!(heard, 0, "{freqs_hz:?}");
        }
    }

    #[test]
    fn a_corrupt_store_boots_on_safe_defaults_and_says_so() {
        let plant = PlantParams::default();
        let mut board = SimCoprocessor::boot(&[]);
        let config = CalibrationConfig { path: None, ..CalibrationConfig::quick() };
        let report = calibrate(&mut board, &plant, &[], 4, &config, &mut |_| {}).unwrap();
        assert!(report.verified, "{report}");
        let mut record = board.twin().stored_config().to_vec();
        record[10] ^= 0x20;
        let mut corrupt = SimCoprocessor::boot(&record);
        let boot = BootState::read(&mut corrupt).unwrap();
        assert_eq!(boot.config_source, ConfigSource::DefaultsAfterCorrupt);
        assert_eq!(boot.params, FeedforwardParams::default());
        assert!(!boot.enabled);
        assert!(boot.to_string().contains("CORRUPT"), "{boot}");
        // Calibrating again repairs it and says how it started.
        let report = calibrate(&mut corrupt, &plant, &[], 4, &config, &mut |_| {}).unwrap();
        assert_eq!(report.boot_config_source, ConfigSource::DefaultsAfterCorrupt);
        assert!(report.to_string().contains("CORRUPT"));
        assert!(report.verified, "{report}");
        assert_eq!(report.config_source, ConfigSource::Stored);
    }
}
