//! `fit`: train the explainable twin on a dataset.
//!
//! 1. Features of each group's first 5 s with the firmware's own fixed-point code, targets
//!    (amplitude and phase of the dynamic error) over its last second.
//! 2. Symbolic regression of the amplitude and of the phase on the 12 features.
//! 3. Cross-validation by group (k folds, round robin): held-out R^2 and the held-out error of
//!    the predicted waveform.
//! 4. The firmware program compiled from the final formulas, in a model file.
//!
//! The phase of a dynamic error that is almost zero is noise; groups whose measured
//! amplitude is below [`PHASE_MIN_AMP_UM`] do not train or score the phase model (they are
//! still scored in the waveform error, where their error is as small as they are).

use std::f64::consts::PI;

use sts_dataset::Dataset;
use sts_symreg::{Expr, Matrix, SearchConfig, SearchResult};
use sts_twin_core::features::{FeatureConfig, FEATURE_LABELS};
use sts_twin_core::program::Program;

use crate::analysis::{self, sine::wrap_deg, GroupSample};
use crate::model::{compile_program, hex_encode, FrontEntry, Formula, GroupValidation, ModelFile, ProgramListing, Validation, MODEL_FORMAT};

/// Smallest measured dynamic-error amplitude whose phase trains and scores the phase model, um.
pub const PHASE_MIN_AMP_UM: f64 = 0.02;

/// Settings of a fit.
#[derive(Clone, Debug)]
pub struct FitConfig {
    /// Seed of the searches.
    pub seed: u64,
    /// Worker threads of each search (the result does not depend on it).
    pub threads: usize,
    /// Epochs of each search (the deterministic budget).
    pub max_epochs: usize,
    /// Optional wall-time cap per search (makes the result machine-speed dependent).
    pub time_budget_s: Option<f64>,
    /// Cross-validation folds (at least 2).
    pub folds: usize,
    /// Accelerometer scale to use instead of the manifest's, m/s^2 per LSB.
    pub acc_scale_override: Option<f64>,
}

impl Default for FitConfig {
    fn default() -> Self {
        Self { seed: 0, threads: 2, max_epochs: 60, time_budget_s: None, folds: 5, acc_scale_override: None }
    }
}

/// What a search is for, for progress reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Target {
    /// The amplitude model.
    Amplitude,
    /// The phase model.
    Phase,
}

/// Progress of a fit: which search runs and its current best formula.
#[derive(Clone, Debug)]
pub struct FitProgress {
    /// Searches done so far.
    pub searches_done: usize,
    /// Searches in total.
    pub searches_total: usize,
    /// The target of the running search.
    pub target: Target,
    /// The fold of the running search (`None` for the final fit on all groups).
    pub fold: Option<usize>,
    /// The currently selected formula and its loss.
    pub best: String,
}

fn search_config(config: &FitConfig, target: Target, fold: Option<usize>) -> SearchConfig {
    let mut search = SearchConfig::default();
    // Distinct but reproducible seeds per search.
    let salt = match target {
        Target::Amplitude => 0x0a,
        Target::Phase => 0x0b,
    };
    search.seed = config.seed.wrapping_mul(1_000_003).wrapping_add(salt * 1000 + fold.map_or(999, |f| f as u64));
    search.threads = config.threads.max(1);
    search.max_epochs = config.max_epochs;
    search.time_budget = config.time_budget_s.map(std::time::Duration::from_secs_f64);
    search
}

fn matrix(samples: &[&GroupSample]) -> anyhow::Result<Matrix> {
    let rows: Vec<Vec<f64>> = samples.iter().map(|s| s.features.iter().map(|&f| f64::from(f)).collect()).collect();
    Ok(Matrix::from_rows(&rows)?)
}

fn run_search(
    samples: &[&GroupSample],
    target: Target,
    search: &SearchConfig,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<SearchResult> {
    let rows: Vec<&GroupSample> = match target {
        Target::Amplitude => samples.to_vec(),
        Target::Phase => samples.iter().copied().filter(|s| s.targets.de_amp_um >= PHASE_MIN_AMP_UM).collect(),
    };
    if rows.len() < 4 {
        anyhow::bail!("only {} groups can train the {target:?} model; at least 4 are needed", rows.len());
    }
    let x = matrix(&rows)?;
    let y: Vec<f64> = rows
        .iter()
        .map(|s| match target {
            Target::Amplitude => s.targets.de_amp_um,
            Target::Phase => s.targets.de_phase_deg,
        })
        .collect();
    let result = sts_symreg::fit(&x, &y, search, |p| {
        if let Some(member) = p.front.get(p.selected) {
            progress(&format!("{} (loss {:.3e})", member.expr.to_infix_rounded(&FEATURE_LABELS, 4), member.loss));
        }
    })?;
    Ok(result)
}

/// R^2 of predictions against measurements.
pub fn r_squared(measured: &[f64], predicted: &[f64]) -> f64 {
    let n = measured.len().min(predicted.len());
    if n == 0 {
        return f64::NAN;
    }
    let mean = measured[..n].iter().sum::<f64>() / n as f64;
    let total: f64 = measured[..n].iter().map(|m| (m - mean).powi(2)).sum();
    let residual: f64 = measured[..n].iter().zip(&predicted[..n]).map(|(m, p)| (m - p).powi(2)).sum();
    if total == 0.0 {
        return if residual == 0.0 { 1.0 } else { f64::NEG_INFINITY };
    }
    1.0 - residual / total
}

/// Phase R^2 on wrapped differences (a 359 vs -1 degree pair is a 0 degree error).
pub fn phase_r_squared(measured_deg: &[f64], predicted_deg: &[f64]) -> f64 {
    let unwrapped: Vec<f64> = measured_deg.iter().zip(predicted_deg).map(|(m, p)| m + wrap_deg(p - m)).collect();
    r_squared(measured_deg, &unwrapped)
}

/// The error of a predicted waveform `amp sin(theta_cmd + phase)` against the measured
/// dynamic error over the group's target window: (mean absolute, RMS), um.
pub fn waveform_error(dataset: &Dataset, sample: &GroupSample, amp_um: f64, phase_deg: f64) -> (f64, f64) {
    let group = &dataset.groups[sample.index];
    let t = &sample.targets;
    let (mut abs_sum, mut sq_sum, mut n) = (0.0, 0.0, 0usize);
    for i in t.window_start..group.len() {
        let theta = 2.0 * PI * t.freq_hz * group.t_s[i] + t.cmd.phase_rad;
        let predicted = amp_um * (theta + phase_deg.to_radians()).sin();
        let measured = group.z_tcp_um[i] - group.z_cmd_um[i];
        let e = measured - predicted;
        abs_sum += e.abs();
        sq_sum += e * e;
        n += 1;
    }
    let n = n.max(1) as f64;
    (abs_sum / n, (sq_sum / n).sqrt())
}

/// Predictions of a compiled program for a group: (amplitude um, phase deg), as the firmware
/// computes them (f32). A failed evaluation predicts zero.
pub fn predict(program: &Program, sample: &GroupSample) -> (f64, f64) {
    match program.evaluate(&sample.features) {
        Ok(out) => (f64::from(out.amp_um()), f64::from(out.phase_deg())),
        Err(_) => (0.0, 0.0),
    }
}

fn formula(result: &SearchResult, r2_cv: f64) -> Formula {
    let best = result.best();
    Formula {
        formula: best.expr.to_infix(&FEATURE_LABELS),
        expr: best.expr.clone(),
        complexity: best.complexity,
        r2_train: best.r2,
        r2_cv,
        front: result
            .front
            .iter()
            .map(|m| FrontEntry { formula: m.expr.to_infix_rounded(&FEATURE_LABELS, 5), loss: m.loss, complexity: m.complexity, score: m.score })
            .collect(),
        selection: format!("(variable xN is feature f(N+1)) {}", result.explanation),
    }
}

/// Fits the twin on `dataset`. `progress` is called with a line describing the search under
/// way and its current best formula.
pub fn fit(dataset: &Dataset, description: &str, config: &FitConfig, progress: &mut dyn FnMut(&FitProgress)) -> anyhow::Result<ModelFile> {
    let feature_config: FeatureConfig = analysis::feature_config_for(dataset, config.acc_scale_override);
    let samples = analysis::group_samples(dataset, &feature_config)?;
    let folds = config.folds.max(2).min(samples.len().max(2));
    let total = 2 * folds + 2;
    let mut done = 0usize;
    let mut searches = |subset: &[&GroupSample], target: Target, fold: Option<usize>| -> anyhow::Result<SearchResult> {
        let search = search_config(config, target, fold);
        let mut report = |best: &str| progress(&FitProgress { searches_done: done, searches_total: total, target, fold, best: best.to_string() });
        let result = run_search(subset, target, &search, &mut report);
        done += 1;
        result
    };

    // Held-out predictions, fold by fold.
    let mut held_out = vec![(0.0f64, 0.0f64); samples.len()];
    for fold in 0..folds {
        let train: Vec<&GroupSample> = samples.iter().filter(|s| s.index % folds != fold).collect();
        let amp = searches(&train, Target::Amplitude, Some(fold))?;
        let phase = searches(&train, Target::Phase, Some(fold))?;
        let program = compile_program(&amp.best().expr, &phase.best().expr).map_err(|e| anyhow::anyhow!("fold {fold}: {e}"))?;
        for s in samples.iter().filter(|s| s.index % folds == fold) {
            held_out[s.index] = predict(&program, s);
        }
    }
    let amp_final = searches(&samples.iter().collect::<Vec<_>>(), Target::Amplitude, None)?;
    let phase_final = searches(&samples.iter().collect::<Vec<_>>(), Target::Phase, None)?;
    let program = compile_program(&amp_final.best().expr, &phase_final.best().expr).map_err(|e| anyhow::anyhow!("final model: {e}"))?;

    let validation = validate(dataset, &samples, &held_out, folds);
    let mut postcard_buf = [0u8; 1024];
    let bytes = postcard::to_slice(&program, &mut postcard_buf).map_err(|e| anyhow::anyhow!("cannot serialise the program: {e}"))?;
    Ok(ModelFile {
        format: MODEL_FORMAT.to_string(),
        description: description.to_string(),
        feature_config,
        amplitude: formula(&amp_final, validation.amplitude_r2),
        phase: formula(&phase_final, validation.phase_r2),
        program: ProgramListing { id: program.id, code_hex: hex_encode(&program.code), consts: program.consts.to_vec(), terms: program.terms.len() },
        program_postcard_hex: hex_encode(bytes),
        validation,
    })
}

fn validate(dataset: &Dataset, samples: &[GroupSample], held_out: &[(f64, f64)], folds: usize) -> Validation {
    let mut groups = Vec::with_capacity(samples.len());
    let (mut mae_sum, mut sq_sum) = (0.0, 0.0);
    for (s, &(amp, phase)) in samples.iter().zip(held_out) {
        let (mae, rms) = waveform_error(dataset, s, amp, phase);
        mae_sum += mae;
        sq_sum += rms * rms;
        groups.push(GroupValidation {
            file: s.info.file.clone(),
            freq_hz: s.info.freq_hz,
            amp_um: s.info.amp_um,
            measured_amp_um: s.targets.de_amp_um,
            predicted_amp_um: amp,
            measured_phase_deg: s.targets.de_phase_deg,
            predicted_phase_deg: phase,
            waveform_mae_um: mae,
            waveform_rms_um: rms,
        });
    }
    let measured_amp: Vec<f64> = samples.iter().map(|s| s.targets.de_amp_um).collect();
    let predicted_amp: Vec<f64> = held_out.iter().map(|h| h.0).collect();
    let phased: Vec<usize> = (0..samples.len()).filter(|&i| samples[i].targets.de_amp_um >= PHASE_MIN_AMP_UM).collect();
    let measured_phase: Vec<f64> = phased.iter().map(|&i| samples[i].targets.de_phase_deg).collect();
    let predicted_phase: Vec<f64> = phased.iter().map(|&i| held_out[i].1).collect();
    let n = samples.len().max(1) as f64;
    Validation {
        folds,
        amplitude_r2: r_squared(&measured_amp, &predicted_amp),
        phase_r2: phase_r_squared(&measured_phase, &predicted_phase),
        waveform_mae_um: mae_sum / n,
        waveform_rms_um: (sq_sum / n).sqrt(),
        groups,
    }
}

/// Expressions of a model, for export.
pub fn model_exprs(model: &ModelFile) -> (&Expr, &Expr) {
    (&model.amplitude.expr, &model.phase.expr)
}
