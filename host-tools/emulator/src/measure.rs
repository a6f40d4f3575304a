//! The offline dynamic-error measurement test (paper, Section 3) on the emulated machine.
//!
//! Sinusoidal Z commands `A sin(2 pi f t)` at f = 1, 5, 10, ..., 40 Hz and A = 1..11 um
//! (99 groups, frequency-major order), 6 s each at 8 kHz, back to back on machine time
//! (group i starts at `i * duration_s`, plus lead-ins if configured). Each group starts from
//! rest at position zero (optionally with a lead-in of motion before recording); the
//! slow processes (ambient wander, thermal drift) follow machine time. Groups are simulated
//! in parallel, each with its own noise stream derived from the seed and the group index,
//! so the output is the same bit for bit whatever the number of threads.
//!
//! While Z runs its test, the X slide reciprocates slowly and the spindle turns (both
//! recorded), so couplings from those axes leave their trace in the data as they would on a
//! real machine.

use crate::effects::EffectSpec;
use crate::machine::{Machine, MachineError, MachineOptions, StepInput};
use crate::params::PlantParams;
use rayon::prelude::*;
use std::f64::consts::PI;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use sts_dataset::{Dataset, DatasetError, GroupData, GroupInfo, Manifest};
use sts_twin_core::{SERVO_RATE_HZ, TICK_S};

/// Why a measurement could not be made or written.
#[derive(Debug, thiserror::Error)]
pub enum MeasureError {
    /// The machine could not be built.
    #[error(transparent)]
    Machine(#[from] MachineError),
    /// The dataset could not be written.
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    /// A bad configuration value.
    #[error("measure: {0}")]
    Config(String),
}

/// The X slide's motion during the test: `center_mm + amp_mm sin(2 pi freq_hz t_machine)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct XMotion {
    /// Centre position, mm.
    pub center_mm: f64,
    /// Amplitude, mm.
    pub amp_mm: f64,
    /// Frequency, Hz.
    pub freq_hz: f64,
}

/// Configuration of the measurement test.
#[derive(Debug, Clone, PartialEq)]
pub struct MeasureConfig {
    /// The machine.
    pub plant: PlantParams,
    /// Enabled effects.
    pub effects: Vec<EffectSpec>,
    /// Seed of all noise.
    pub seed: u64,
    /// Command frequencies, Hz (outer loop).
    pub freqs_hz: Vec<f64>,
    /// Command amplitudes, um (inner loop).
    pub amps_um: Vec<f64>,
    /// Duration of one group, s.
    pub duration_s: f64,
    /// X slide motion.
    pub x_motion: XMotion,
    /// Spindle speed, rpm.
    pub spindle_rpm: f64,
    /// Motion before the recording starts, s (rounded up to whole command periods so the
    /// command still starts at zero). 0 (the default, the paper's Eq. 1): each group starts
    /// from rest at `t_s = 0`, so its first instants hold the start transient. A lead-in
    /// records the steady motion only, as a continuously running machine shows it.
    pub lead_in_s: f64,
}

impl Default for MeasureConfig {
    /// The paper's grid on the default machine, seed 1.
    fn default() -> Self {
        Self {
            plant: PlantParams::default(),
            effects: Vec::new(),
            seed: 1,
            freqs_hz: paper_freqs_hz(),
            amps_um: (1..=11).map(f64::from).collect(),
            duration_s: 6.0,
            x_motion: XMotion { center_mm: 5.0, amp_mm: 1.0, freq_hz: 2.25 },
            spindle_rpm: 90.0,
            lead_in_s: 0.0,
        }
    }
}

/// The paper's frequencies: 1, 5, 10, ..., 40 Hz.
pub fn paper_freqs_hz() -> Vec<f64> {
    std::iter::once(1.0).chain((1..=8).map(|k| 5.0 * k as f64)).collect()
}

impl MeasureConfig {
    /// The groups' manifest entries, in order.
    pub fn groups(&self) -> Vec<GroupInfo> {
        let mut out = Vec::new();
        for &freq_hz in &self.freqs_hz {
            for &amp_um in &self.amps_um {
                let i = out.len();
                let start_s = i as f64 * (self.duration_s + self.lead_in_s) + self.lead_in_s;
                out.push(GroupInfo::new(&format!("g{i:03}.csv"), freq_hz, amp_um, start_s));
            }
        }
        out
    }

    /// Samples per group.
    pub fn samples_per_group(&self) -> usize {
        (self.duration_s * f64::from(SERVO_RATE_HZ)).round() as usize
    }

    /// The manifest of the dataset this configuration writes (names no effect).
    pub fn manifest(&self) -> Manifest {
        let mut m = Manifest::new(
            f64::from(SERVO_RATE_HZ),
            &format!(
                "Offline dynamic-error measurement test on the emulated machine: {} groups of {} s at {} Hz, seed {}",
                self.freqs_hz.len() * self.amps_um.len(),
                self.duration_s,
                f64::from(SERVO_RATE_HZ),
                self.seed
            ),
            self.groups(),
        );
        m.acc_mps2_per_lsb = Some(self.plant.acc_mps2_per_lsb());
        m
    }

    /// Checks the configuration (frequencies, amplitudes, durations) before anything runs.
    pub fn check(&self) -> Result<(), MeasureError> {
        let bad = |m: &str| Err(MeasureError::Config(m.into()));
        if self.freqs_hz.is_empty() || self.amps_um.is_empty() {
            return bad("no frequencies or amplitudes");
        }
        if self.freqs_hz.iter().any(|f| !(f.is_finite() && *f > 0.0 && *f < f64::from(SERVO_RATE_HZ) / 2.0)) {
            return bad("frequencies must be in (0, 4000) Hz");
        }
        if self.amps_um.iter().any(|a| !(a.is_finite() && *a >= 0.0)) {
            return bad("amplitudes must be zero or positive");
        }
        if !(self.duration_s.is_finite() && self.duration_s >= 2.0 * TICK_S && self.duration_s <= 3600.0) {
            return bad("duration_s must be in [0.00025, 3600] s");
        }
        if !(self.lead_in_s.is_finite() && (0.0..=60.0).contains(&self.lead_in_s)) {
            return bad("lead_in_s must be in [0, 60] s");
        }
        Ok(())
    }
}

/// Simulates group `index` of the configuration.
pub fn simulate_group(config: &MeasureConfig, index: usize) -> Result<GroupData, MeasureError> {
    config.check()?;
    let info =
        config.groups().into_iter().nth(index).ok_or_else(|| MeasureError::Config(format!("no group {index}")))?;
    // Lead-in: whole command periods, so the command is zero when the motion starts.
    let lead_s = (config.lead_in_s * info.freq_hz).ceil() / info.freq_hz;
    let lead_ticks = (lead_s / TICK_S).round() as usize;
    let machine_start_s = info.start_s - lead_ticks as f64 * TICK_S;
    let options = MachineOptions { seed: config.seed, start_s: machine_start_s, stream: index as u64 };
    let mut machine = Machine::with_options(&config.plant, &config.effects, options)?;
    let xm = config.x_motion;
    let x_at = |t: f64| xm.center_mm + xm.amp_mm * (2.0 * PI * xm.freq_hz * t).sin();
    machine.prime_x(x_at(machine_start_s - 2.0 * TICK_S), x_at(machine_start_s - TICK_S));
    let n = config.samples_per_group();
    let mut g = GroupData::with_len(n);
    let mut x_mm = vec![0.0; n];
    let mut x_acc = vec![0.0; n];
    let mut spindle = vec![0.0; n];
    let mut temp = vec![0.0; n];
    let w = 2.0 * PI * info.freq_hz;
    for k in 0..lead_ticks + n {
        // Time since the recording's start (negative during the lead-in).
        let t = (k as f64 - lead_ticks as f64) * TICK_S;
        let t_machine = info.start_s + t;
        let input = StepInput {
            z_cmd_um: info.amp_um * (w * t).sin(),
            x_mm: x_at(t_machine),
            spindle_deg: (config.spindle_rpm / 60.0 * 360.0 * t_machine).rem_euclid(360.0),
            analog_in_v: 0.0,
            analog_enabled: false,
        };
        let out = machine.step(&input);
        let Some(r) = k.checked_sub(lead_ticks) else { continue };
        g.t_s[r] = r as f64 * TICK_S;
        g.z_cmd_um[r] = input.z_cmd_um;
        g.z_enc_um[r] = out.z_enc_um;
        g.z_tcp_um[r] = out.z_tcp_um;
        g.acc_mps2[r] = out.acc_mps2;
        x_mm[r] = input.x_mm;
        x_acc[r] = out.x_acc_mps2;
        spindle[r] = input.spindle_deg;
        temp[r] = out.temp_c;
    }
    g.x_mm = Some(x_mm);
    g.x_acc_mps2 = Some(x_acc);
    g.spindle_deg = Some(spindle);
    g.temp_c = Some(temp);
    Ok(g)
}

/// Runs the whole test in memory. `progress` is called with the number of groups done.
pub fn run(config: &MeasureConfig, progress: &(dyn Fn(usize) + Sync)) -> Result<Dataset, MeasureError> {
    config.check()?;
    let count = config.freqs_hz.len() * config.amps_um.len();
    let done = AtomicUsize::new(0);
    let results: Vec<Result<GroupData, MeasureError>> = (0..count)
        .into_par_iter()
        .map(|i| {
            let r = simulate_group(config, i);
            progress(done.fetch_add(1, Ordering::Relaxed) + 1);
            r
        })
        .collect();
    let groups = results.into_iter().collect::<Result<Vec<_>, _>>()?;
    Ok(Dataset { manifest: config.manifest(), groups })
}

/// Runs the whole test and writes the dataset as the directory `dir`, one group file as soon
/// as it is simulated (memory stays at a few groups), into a fresh directory beside `dir`
/// that replaces it once whole ([`sts_dataset::output::StagedDir`]): killed part-way, it
/// leaves `dir` as it was. Returns the manifest written.
pub fn run_to_dir(
    config: &MeasureConfig,
    dir: &Path,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Manifest, MeasureError> {
    config.check()?;
    let mut manifest = config.manifest();
    let staged = sts_dataset::output::StagedDir::new(dir)?;
    let done = AtomicUsize::new(0);
    let results: Vec<Result<(), MeasureError>> = manifest
        .groups
        .par_iter_mut()
        .enumerate()
        .map(|(i, info)| {
            let group = simulate_group(config, i)?;
            sts_dataset::write_group(staged.path(), info, &group)?;
            progress(done.fetch_add(1, Ordering::Relaxed) + 1);
            Ok(())
        })
        .collect();
    results.into_iter().collect::<Result<Vec<()>, _>>()?;
    sts_dataset::write_manifest(staged.path(), &manifest)?;
    staged.commit()?;
    Ok(manifest)
}
