//! Test support shared by the suites of this crate.

// Each test binary compiles this module and uses a part of it.
#![allow(dead_code)]

use std::sync::{Arc, Mutex};

use sts_dataset::Dataset;
use sts_emulator::{EffectSpec, MeasureConfig, PlantParams};
use sts_fit::{fit, FitConfig};
use sts_model::ModelFile;

/// The step dependence above which a machine hunts, nm: the probe's noise.
pub const HUNTING_STEP_NM: f64 = 5.0;

/// The RMS change of the encoder reading when the emulator integrates with 16 sub-steps per
/// tick instead of its 4, per group of the slow groups (1 and 5 Hz, 3 s): the group's
/// frequency (Hz), amplitude (um), the change's sum of squares (um^2) and its sample count. Large only where
/// the machine hunts: where a friction's Stribeck zone takes more damping than the servo
/// gives, the slide oscillates by itself, and the oscillation's phase depends on everything
/// down to the integration step, so no twin driven by the command can predict it.
fn step_dependence_per_group(plant: &PlantParams, effects: &[EffectSpec], seed: u64) -> Vec<(f64, f64, f64, usize)> {
    let config = MeasureConfig {
        plant: plant.clone(),
        effects: effects.to_vec(),
        seed,
        freqs_hz: vec![1.0, 5.0],
        duration_s: 3.0,
        ..MeasureConfig::default()
    };
    let mut fine = config.clone();
    fine.plant.servo.substeps = 16;
    let a = sts_emulator::measure::run(&config, &|_| {}).expect("measurement");
    let b = sts_emulator::measure::run(&fine, &|_| {}).expect("measurement");
    a.groups
        .iter()
        .zip(&b.groups)
        .zip(&a.manifest.groups)
        .map(|((ga, gb), info)| {
            let sum: f64 = ga.z_enc_um.iter().zip(&gb.z_enc_um).map(|(x, y)| (x - y).powi(2)).sum();
            let n = ga.z_enc_um.len().min(gb.z_enc_um.len());
            (info.freq_hz, info.amp_um, sum, n)
        })
        .collect()
}

/// [`step_dependence_per_group`] over all the slow groups, nm.
pub fn step_dependence_nm(plant: &PlantParams, effects: &[EffectSpec], seed: u64) -> f64 {
    let groups = step_dependence_per_group(plant, effects, seed);
    let (sum, n) = groups.iter().fold((0.0, 0usize), |(s, n), g| (s + g.2, n + g.3));
    (sum / n.max(1) as f64).sqrt() * 1e3
}

/// The slow groups where the machine hunts (their reading changes by more than
/// [`HUNTING_STEP_NM`] with the integration step): frequency (Hz) and amplitude (um).
pub fn hunting_groups(plant: &PlantParams, effects: &[EffectSpec], seed: u64) -> Vec<(f64, f64)> {
    step_dependence_per_group(plant, effects, seed)
        .into_iter()
        .filter(|g| (g.2 / g.3.max(1) as f64).sqrt() * 1e3 > HUNTING_STEP_NM)
        .map(|g| (g.0, g.1))
        .collect()
}

/// The measurement test on `plant` with `effects` (seed `seed`): the paper's grid, or with
/// `paper_grid` false CI's (the same 99 groups, each only as long as the feature window needs).
pub fn measure(plant: &PlantParams, paper_grid: bool, effects: Vec<EffectSpec>, seed: u64) -> Dataset {
    let mut config = MeasureConfig { plant: plant.clone(), effects, seed, ..MeasureConfig::default() };
    if !paper_grid {
        config.duration_s = 5.5;
    }
    sts_emulator::measure::run(&config, &|_| {}).expect("measurement")
}

/// The twin of `plant` without hidden effects, fitted with `epochs` epochs on its measurement
/// (seed 1; the paper's grid, or with `paper_grid` false CI's): the hidden-effect suites'
/// reference and the several-effects sets' clean twin. The fit is deterministic, so the tests
/// of this binary that ask for the same one share a single fit (the others wait for it).
pub fn clean_twin(plant: &PlantParams, paper_grid: bool, epochs: usize) -> Arc<ModelFile> {
    type Key = (String, bool, usize);
    static TWINS: Mutex<Vec<(Key, Arc<ModelFile>)>> = Mutex::new(Vec::new());
    let key = (format!("{plant:?}"), paper_grid, epochs);
    let mut twins = TWINS.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((_, twin)) = twins.iter().find(|(k, _)| *k == key) {
        return Arc::clone(twin);
    }
    let data = measure(plant, paper_grid, Vec::new(), 1);
    let config = FitConfig { max_epochs: epochs, ..FitConfig::default() };
    let twin = Arc::new(fit(&data, "clean machine", &config, &mut |_| {}).expect("the clean machine's fit"));
    twins.push((key, Arc::clone(&twin)));
    twin
}

/// The machine of a full run: the plant file named by `STS_PLANT` (keys left out keep the
/// default machine's values, as `sts-twin measure --plant` reads it), else the default
/// machine. The CI shares always run on the default machine. A relative path is taken from
/// the workspace's root, where the suites' commands are typed (cargo runs a test binary in
/// its crate's folder).
pub fn plant_from_env() -> PlantParams {
    match std::env::var_os("STS_PLANT") {
        Some(path) => {
            let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
            let path = root.join(path);
            PlantParams::from_file(&path).unwrap_or_else(|e| panic!("STS_PLANT={}: {e}", path.display()))
        }
        None => PlantParams::default(),
    }
}
