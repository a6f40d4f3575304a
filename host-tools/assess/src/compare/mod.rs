//! `compare`: a model's predicted dynamic error against the measured one, group by group.
//!
//! Predictions come from the model's firmware program (what the board computes): the program
//! is evaluated on each group's features (the firmware's own fixed-point code), and the
//! firmware's synthesiser ([`sts_twin_core::synth::Synth`]) turns its output and its per-tick
//! effect terms into the predicted waveform, tick by tick, in integer arithmetic. The measured
//! dynamic error is `z_tcp_um - z_cmd_um`. Scores are over each group's last second (the
//! targets' window), like the fit's.

pub mod signals;

use rayon::prelude::*;
use serde::Serialize;
use sts_dataset::Dataset;

use sts_analysis::repeat::Repeatability;
use sts_analysis::score::{phase_r_squared, r_squared};
use sts_analysis::sine::line_amp;
use sts_analysis::targets::PHASE_MIN_AMP_UM;
use sts_analysis::{self as analysis};
use sts_model::replay::{predict_group, program_output};
use sts_model::ModelFile;

use crate::AssessError;

/// Highest harmonic order of the command frequency reported in the residual spectrum.
pub const MAX_ORDER: usize = 10;

/// One group's comparison.
#[derive(Clone, Debug, Serialize)]
pub struct GroupComparison {
    /// Group index in the dataset.
    pub index: usize,
    /// The group's file.
    pub file: String,
    /// Command frequency, Hz.
    pub freq_hz: f64,
    /// Command amplitude, um.
    pub amp_um: f64,
    /// Machine time at the group's start, s.
    pub start_s: f64,
    /// Measured dynamic-error amplitude at the command frequency, um.
    pub measured_amp_um: f64,
    /// Predicted amplitude (program register 0), um.
    pub predicted_amp_um: f64,
    /// Measured phase relative to the command, degrees.
    pub measured_phase_deg: f64,
    /// Predicted phase (program register 1), degrees.
    pub predicted_phase_deg: f64,
    /// RMS of measured minus predicted waveform over the last second, um.
    pub waveform_rms_um: f64,
    /// Mean absolute error of the waveform over the last second, um.
    pub waveform_mae_um: f64,
    /// RMS of the measured dynamic error itself over the last second, um.
    pub measured_rms_um: f64,
    /// Mean of the residual over the last second, um (drifts and offsets).
    pub residual_mean_um: f64,
    /// Residual amplitude at harmonic orders 1..=MAX_ORDER of the command frequency, um.
    pub residual_harmonics_um: Vec<f64>,
    /// Whether the program evaluated (a failed evaluation predicts zero, as the firmware holds).
    pub program_ok: bool,
    /// The accelerometer's line at the command frequency over the RMS of the rest of its
    /// signal, over the last second: below [`ACC_SNR_BLIND`] the features mostly see noise.
    pub acc_snr: f64,
}

/// Accelerometer signal-to-noise ratio below which a group's features are mostly noise.
pub const ACC_SNR_BLIND: f64 = 1.0;

/// A spectral line of the residual that is not a harmonic of the command frequency.
#[derive(Clone, Debug, Serialize)]
pub struct Line {
    /// Frequency, Hz.
    pub freq_hz: f64,
    /// Mean amplitude over the groups, um.
    pub amp_um: f64,
}

/// Binned residual against a signal: where along the motion the error sits.
#[derive(Clone, Debug, Serialize)]
pub struct Binned {
    /// Signal name with unit, e.g. `velocity (normalised)`.
    pub signal: String,
    /// Bin centres.
    pub centres: Vec<f64>,
    /// RMS residual per bin, um.
    pub rms_um: Vec<f64>,
    /// Mean residual per bin, um.
    pub mean_um: Vec<f64>,
}

/// The comparison of one model with a dataset.
#[derive(Clone, Debug, Serialize)]
pub struct Comparison {
    /// The model's description.
    pub model: String,
    /// RMS of measured minus predicted dynamic error over every group's last second, um.
    pub waveform_rms_um: f64,
    /// Mean absolute waveform error over every group's last second, um.
    pub waveform_mae_um: f64,
    /// RMS of the measured dynamic error itself over every group's last second, um.
    pub measured_rms_um: f64,
    /// R^2 of predicted against measured amplitudes.
    pub amplitude_r2: f64,
    /// R^2 of predicted against measured phases (wrapped differences; groups whose measured
    /// amplitude is at least the fit's phase threshold).
    pub phase_r2: f64,
    /// Mean residual amplitude over groups at orders 1..=MAX_ORDER, um.
    pub harmonics_um: Vec<f64>,
    /// Residual lines that are not harmonics of the command (strongest first).
    pub other_lines: Vec<Line>,
    /// Residual against position, velocity, acceleration (normalised by their peaks).
    pub binned: Vec<Binned>,
    /// The part of the measured error that does not repeat from one period to the next (no
    /// model driven by the command can predict it); positions follow `groups`.
    pub repeatability: Repeatability,
    /// Per group, in dataset order.
    pub groups: Vec<GroupComparison>,
}

impl Comparison {
    /// Positions in `groups` of the groups whose accelerometer barely sees the motion
    /// (signal-to-noise below [`ACC_SNR_BLIND`]), as [`Comparison::worst`] gives them.
    pub fn acc_blind(&self) -> Vec<usize> {
        (0..self.groups.len()).filter(|&i| self.groups[i].acc_snr < ACC_SNR_BLIND).collect()
    }

    /// One paragraph for a person when the accelerometer barely sees the motion in some groups.
    pub fn describe_acc_blind(&self) -> Option<String> {
        let positions = self.acc_blind();
        if positions.is_empty() {
            return None;
        }
        let snr: Vec<f64> = positions.iter().map(|&p| self.groups[p].acc_snr).collect();
        let (lo, hi) = (snr.iter().copied().fold(f64::INFINITY, f64::min), snr.iter().copied().fold(0.0, f64::max));
        let ss = |g: &GroupComparison| g.waveform_rms_um * g.waveform_rms_um;
        let share = positions.iter().map(|&p| ss(&self.groups[p])).sum::<f64>()
            / self.groups.iter().map(ss).sum::<f64>().max(1e-300);
        Some(format!(
            "in {} group{} ({}) its line at the command frequency is only {} of the rest of its signal: \
             it barely sees the motion there, the features are mostly noise and the formulas extrapolate. Those groups hold {:.0}% of the waveform error{}",
            positions.len(),
            if positions.len() == 1 { "" } else { "s" },
            sts_analysis::repeat::group_places(&positions, |p| (self.groups[p].freq_hz, self.groups[p].amp_um)),
            sts_analysis::repeat::range_text(format!("{lo:.2}"), format!("{hi:.2}")),
            share * 100.0,
            if share > positions.len() as f64 / self.groups.len() as f64 { "; a quieter sensor, or larger strokes at those frequencies, would help the twin there." } else { " (no more than their share of the groups)." }
        ))
    }

    /// Indices of the `n` worst groups by waveform RMS.
    pub fn worst(&self, n: usize) -> Vec<usize> {
        let mut order: Vec<usize> = (0..self.groups.len()).collect();
        order.sort_by(|&a, &b| {
            self.groups[b].waveform_rms_um.total_cmp(&self.groups[a].waveform_rms_um).then(a.cmp(&b))
        });
        order.truncate(n);
        order
    }
}

/// Per-group data kept for the report: the last second's measured and predicted waveforms.
#[derive(Clone, Debug)]
pub struct GroupWaves {
    /// Time since the group's start, s.
    pub t_s: Vec<f64>,
    /// Measured dynamic error, um.
    pub measured_um: Vec<f64>,
    /// Predicted dynamic error, um.
    pub predicted_um: Vec<f64>,
}

/// Compares `model` with `dataset`. Also returns each group's last-second waveforms.
pub fn compare(dataset: &Dataset, model: &ModelFile) -> Result<(Comparison, Vec<GroupWaves>), AssessError> {
    let corrected = model.probe_corrected(dataset);
    let dataset: &Dataset = &corrected;
    let program = model.firmware_program()?;
    let mut feature_config = model.feature_config;
    feature_config.sample_rate_hz = dataset.manifest.sample_rate_hz as f32;
    let skip_s = model.training.as_ref().map_or(analysis::DEFAULT_SKIP_S, |t| t.skip_s);
    let samples = analysis::group_samples_skipping(dataset, &feature_config, skip_s)?;
    let fs = dataset.manifest.sample_rate_hz;
    let per_group: Vec<(GroupComparison, GroupWaves, Vec<f64>)> = samples
        .par_iter()
        .map(|s| {
            let group = &dataset.groups[s.index];
            let (pred, ok) = predict_group(&program, s, group, fs);
            let (out, _) = program_output(&program, s);
            let start = s.targets.window_start;
            let t = &group.t_s[start..];
            let measured: Vec<f64> = (start..group.len()).map(|k| group.z_tcp_um[k] - group.z_cmd_um[k]).collect();
            let predicted = pred[start..].to_vec();
            let residual: Vec<f64> = measured.iter().zip(&predicted).map(|(m, p)| m - p).collect();
            let n = residual.len().max(1) as f64;
            let rms = (residual.iter().map(|r| r * r).sum::<f64>() / n).sqrt();
            let mae = residual.iter().map(|r| r.abs()).sum::<f64>() / n;
            let mean = residual.iter().sum::<f64>() / n;
            let measured_rms = (measured.iter().map(|m| m * m).sum::<f64>() / n).sqrt();
            let harmonics = (1..=MAX_ORDER).map(|k| line_amp(t, &residual, k as f64 * s.info.freq_hz)).collect();
            let spectrum = signals::amplitude_spectrum(&residual);
            let acc_snr =
                sts_analysis::sine::fit_sine(t, &group.acc_mps2[start..], s.info.freq_hz).map_or(f64::NAN, |fit| {
                    if fit.residual_rms > 0.0 {
                        fit.amp / fit.residual_rms
                    } else {
                        f64::INFINITY
                    }
                });
            let g = GroupComparison {
                index: s.index,
                file: s.info.file.clone(),
                freq_hz: s.info.freq_hz,
                amp_um: s.info.amp_um,
                start_s: s.info.start_s,
                measured_amp_um: s.targets.de_amp_um,
                predicted_amp_um: f64::from(out.amp_um()),
                measured_phase_deg: s.targets.de_phase_deg,
                predicted_phase_deg: f64::from(out.phase_deg()),
                waveform_rms_um: rms,
                waveform_mae_um: mae,
                measured_rms_um: measured_rms,
                residual_mean_um: mean,
                residual_harmonics_um: harmonics,
                program_ok: ok,
                acc_snr,
            };
            (g, GroupWaves { t_s: t.to_vec(), measured_um: measured, predicted_um: predicted }, spectrum)
        })
        .collect();
    let mut groups = Vec::with_capacity(per_group.len());
    let mut waves = Vec::with_capacity(per_group.len());
    let mut spectra = Vec::with_capacity(per_group.len());
    for (g, w, s) in per_group {
        groups.push(g);
        waves.push(w);
        spectra.push(s);
    }
    let ng = groups.len().max(1) as f64;
    let waveform_rms_um = (groups.iter().map(|g| g.waveform_rms_um.powi(2)).sum::<f64>() / ng).sqrt();
    let waveform_mae_um = groups.iter().map(|g| g.waveform_mae_um).sum::<f64>() / ng;
    let measured_rms_um = (groups.iter().map(|g| g.measured_rms_um.powi(2)).sum::<f64>() / ng).sqrt();
    let m_amp: Vec<f64> = groups.iter().map(|g| g.measured_amp_um).collect();
    let p_amp: Vec<f64> = groups.iter().map(|g| g.predicted_amp_um).collect();
    let phased: Vec<&GroupComparison> = groups.iter().filter(|g| g.measured_amp_um >= PHASE_MIN_AMP_UM).collect();
    let m_ph: Vec<f64> = phased.iter().map(|g| g.measured_phase_deg).collect();
    let p_ph: Vec<f64> = phased.iter().map(|g| g.predicted_phase_deg).collect();
    let harmonics_um =
        (0..MAX_ORDER).map(|k| groups.iter().map(|g| g.residual_harmonics_um[k]).sum::<f64>() / ng).collect();
    let other_lines = signals::other_lines(&groups, &spectra, fs, 6);
    let binned = signals::binned_residuals(dataset, &samples, &waves, 24);
    let repeatability = Repeatability::of_samples(dataset, &samples);
    let comparison = Comparison {
        model: model.description.clone(),
        waveform_rms_um,
        waveform_mae_um,
        measured_rms_um,
        amplitude_r2: r_squared(&m_amp, &p_amp),
        phase_r2: phase_r_squared(&m_ph, &p_ph),
        harmonics_um,
        other_lines,
        binned,
        repeatability,
        groups,
    };
    Ok((comparison, waves))
}
