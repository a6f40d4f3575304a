//! `diagnose`: which physical effect is missing from a model?
//!
//! The residual (measured minus predicted dynamic error, the model's firmware program as
//! `compare` computes it, over each group's last second) is explained in turn by each of the
//! nine candidate effects of the library, each a small physical model that is linear in its
//! coefficients given a few shape parameters (chosen from a grid):
//!
//! | effect | what explains the residual |
//! |---|---|
//! | `coulomb-friction` | a saturated sign of the slide's velocity (encoder), through a Laguerre model of the servo's disturbance response |
//! | `presliding-hysteresis` | a Dahl force of the slide's position (presliding distance `x0`), through the same filter |
//! | `structural-mode` | an extra compliance in phase with the acceleration (`A w^2`), growing with the frequency squared |
//! | `loop-delay` | a change of the closed loop with the jerk and snap of the command (`A w^3`, `A w^4`) |
//! | `thermal-drift` | a first-order drift over machine time (or the `temp_c` column) |
//! | `force-ripple` | sine and cosine of the encoder position over a pitch `p`, through the filter |
//! | `axis-coupling` | the `x_acc_mps2` column and the spindle angle's once-per-revolution sine |
//! | `sensor-gain` | the probe reading itself (probe scale), or the model's own prediction (accelerometer scale) |
//!
//! **The probe's scale first.** Ahead of the candidates, the slowest groups' in-phase ratios
//! of probe to command are read on the data itself ([`sts_analysis::probe_scale`]): a part
//! of them that is the same at every stroke names `sensor-gain` first, since a twin fitted on
//! such readings has learnt the scale as dynamics and every candidate is scored on readings it
//! distorts (module `probe_check`).
//!
//! Coefficients are fitted on training groups and scored on held-out groups (k folds by
//! group, round robin): the explained fraction is `1 - SS(residual - explained) / SS(residual)`
//! summed over held-out groups. It uses only the dataset's columns (optional ones when
//! present), never anything of the emulator.
//!
//! **Without the fundamental.** A twin fitted on the data it is diagnosed on (the lab's
//! workflow) has absorbed what an effect does to each group's fundamental, as far as its
//! formulas could, and left that part distorted; the effect still shows where formulas of the
//! fundamental cannot reach: harmonics, steps, trends, other lines. So the five candidates
//! whose signature reaches there (friction, hysteresis, drift, ripple, coupling) are scored
//! twice, on the residual and on the residual with each group's fundamental taken out (from
//! it and from the candidate's columns, by least squares), and keep the significant score, or
//! of two alike the one that explains more. Candidates rank by the residual RMS they explain,
//! the significant first. A structural mode, a loop delay and an accelerometer's gain change
//! the fundamental only: in the lab's workflow the formulas absorb them as they absorb the
//! clean machine's error, and `none` is then the right answer (the suite counts it so where the
//! twin's error stays within 1.5x of the clean twin's).
//!
//! **After the candidates, in the data's own error.** Where none is significant, two stages
//! look at the error's phasors at the command frequency rather than at a residual the twin's
//! formulas have bent: a structural mode inside the band (module `in_band`), then a late
//! setpoint (module `late_setpoint`: the axis's linear response from the command, a velocity
//! bank, against the twin's own residual, where the error at the slowest groups lags the
//! motion as a delay's does). A mode that a candidate names inside the band must also hold
//! there beyond that linear response, or the late setpoint, when significant, is named instead.
//!
//! **The test for `none`.** The best candidate is the verdict only if (1) it explains at least
//! [`MIN_EXPLAINED`] of the held-out residual, (2) its per-group reductions of the held-out
//! residual add up to more than chance allows: a one-sided sign-flip test over groups
//! (`sum / sqrt(sum of squares)`, normal approximation) of two statistics, the reductions of
//! each group's sum of squares and the same relative to it, at `p < ALPHA / 26` (Bonferroni
//! over the thirteen scores and the two statistics), and (3) what it explains is more than
//! the data's own floor: its RMS exceeds the part of the error that does not repeat from one
//! command period to the next (the sensors' noise; [`Repeatability::floor_um`]; less the
//! twin's drift and coupling terms, which do not repeat with the command either, once it
//! carries them) and [`NOT_REPEATING_MIN_UM`]. The floor is the data's, not the model's: a model fitted on the
//! same data (the lab's workflow) has the missing effect in its own held-out error, so a test
//! against that error would hide every effect it is asked to find.

mod candidates;
mod in_band;
mod late_setpoint;
mod probe_check;
pub mod structure;

use std::cell::OnceCell;
use std::f64::consts::PI;

use rayon::prelude::*;
use serde::Serialize;
use sts_dataset::Dataset;

use sts_analysis::repeat::{group_non_repeating_um, Repeatability, NOT_REPEATING_MIN_UM};
use sts_analysis::{self as analysis, GroupSample};
use sts_fit::effects::{terms_output, DataErrorPhasors};
use sts_model::replay::predict_group;
use sts_model::{Effect, ModelFile};
use sts_numerics::lsq::Stats;
use sts_twin_core::program::TickTerm;

use crate::AssessError;

/// Smallest held-out explained fraction of a verdict.
pub const MIN_EXPLAINED: f64 = 0.25;
/// Family-wise significance level of the sign tests (over every score and both statistics).
pub const ALPHA: f64 = 0.02;
/// Statistics the sign test is run with per candidate.
const STATISTICS: usize = 2;
/// Cross-validation folds.
pub const FOLDS: usize = 5;

/// One candidate's result.
#[derive(Clone, Debug, Serialize)]
pub struct Ranked {
    /// Canonical effect name.
    pub effect: String,
    /// Explained fraction of the residual on held-out groups (can be negative).
    pub explained_fraction: f64,
    /// One-sided sign-flip test p-value of the held-out groups' improvements: the smaller of
    /// the two statistics' (absolute and relative to each group's residual).
    pub p_value: f64,
    /// Held-out groups where the candidate lowered the residual.
    pub groups_improved: usize,
    /// Estimated parameters (name with unit, value).
    pub params: Vec<(String, f64)>,
    /// The evidence in words.
    pub evidence: String,
    /// Whether it passes the test.
    pub significant: bool,
    /// RMS of the residual it explains on held-out groups, um (what ranks the candidates).
    pub explained_rms_um: f64,
    /// Whether it was scored on the residual without each group's fundamental (its
    /// `explained_fraction` is then of that part).
    pub without_fundamental: bool,
}

/// The diagnosis.
#[derive(Clone, Debug, Serialize)]
pub struct Diagnosis {
    /// The best significant candidate, or `none`.
    pub verdict: String,
    /// Candidates, best first.
    pub ranking: Vec<Ranked>,
    /// RMS of the residual over every group's last second, um.
    pub residual_rms_um: f64,
    /// The model's own held-out waveform RMS, um (from its model file).
    pub model_cv_rms_um: f64,
    /// One sentence.
    pub summary: String,
    /// The statistical test, stated.
    pub test: String,
    /// The part of the measured error that does not repeat from one period to the next
    /// (positions of the diagnosed groups); see [`Diagnosis::not_repeating`].
    pub repeatability: Repeatability,
    /// The diagnosed groups' files, in the positions that `repeatability` uses.
    pub group_files: Vec<String>,
    /// When some groups do not repeat: which, and why no effect's term can explain that part.
    pub not_repeating: Option<String>,
    /// Where the residual lies (trend, fundamental, harmonics, the rest and its strongest
    /// line), whatever the candidates explain.
    pub structure: structure::Structure,
    /// When no candidate explains the residual yet it stands well above the data's floor:
    /// where it lies, in words, instead of the nearest wrong effect.
    pub unexplained: Option<String>,
}

impl Diagnosis {
    /// The files of the groups whose error does not repeat from one period to the next.
    pub fn not_repeating_files(&self) -> Vec<String> {
        self.repeatability.not_repeating.iter().filter_map(|&i| self.group_files.get(i)).cloned().collect()
    }
}

/// Everything a candidate may use about one group (last-second window plus whole-group
/// signals for filters that need the motion's history).
pub struct GroupCtx<'a> {
    /// The group's sample (features, targets).
    pub sample: &'a GroupSample,
    /// The group's data.
    pub data: &'a sts_dataset::GroupData,
    /// The model's predicted dynamic error over the whole group, um.
    pub predicted_um: Vec<f64>,
    /// First sample of the scored window.
    pub start: usize,
    /// Residual over the window, um.
    pub residual: Vec<f64>,
    /// Command phase (radians) over the window.
    pub theta: Vec<f64>,
    /// `sin` of [`GroupCtx::theta`], computed once for every candidate that needs it.
    pub sin_theta: Vec<f64>,
    /// `cos` of [`GroupCtx::theta`].
    pub cos_theta: Vec<f64>,
    /// Sample rate, Hz.
    pub sample_rate_hz: f64,
    /// Set when the residual has the group's fundamental taken out: candidates' columns lose
    /// theirs too ([`GroupCtx::stats`]).
    pub without_fundamental: Option<Fundamental>,
    /// The output of the model's terms that do not repeat with the command (a drift, an axis
    /// coupling) over the whole group, um, where it has any: taken out of the error before its
    /// non-repeating part sets the data's floor, since what the twin carries is no longer
    /// noise (an X slide's coupling raised the floor from 5 to 55 nm, hiding every effect
    /// below that once the coupling was carried).
    pub aperiodic_um: Option<Vec<f64>>,
}

/// A group's fundamental over the scored window (the command frequency's sine and cosine),
/// to take out of a residual and of a candidate's columns by least squares.
pub struct Fundamental {
    /// Inverse of the 2 x 2 Gram matrix of the group's `sin_theta` and `cos_theta`.
    inv_gram: [[f64; 2]; 2],
}

impl Fundamental {
    fn new(sin: &[f64], cos: &[f64]) -> Option<Self> {
        let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
        let (ss, sc, cc) = (dot(sin, sin), dot(sin, cos), dot(cos, cos));
        let det = ss * cc - sc * sc;
        (det > 1e-9 * ss * cc).then(|| Self { inv_gram: [[cc / det, -sc / det], [-sc / det, ss / det]] })
    }

    /// `x` minus its least-squares fit by the fundamental `sin`, `cos` (those it was made from).
    pub fn remove(&self, x: &[f64], sin: &[f64], cos: &[f64]) -> Vec<f64> {
        let dot = |a: &[f64]| a.iter().zip(x).map(|(p, q)| p * q).sum::<f64>();
        let (bs, bc) = (dot(sin), dot(cos));
        let a = self.inv_gram[0][0] * bs + self.inv_gram[0][1] * bc;
        let b = self.inv_gram[1][0] * bs + self.inv_gram[1][1] * bc;
        x.iter().zip(sin.iter().zip(cos)).map(|(v, (s, c))| v - a * s - b * c).collect()
    }
}

impl GroupCtx<'_> {
    /// The non-repeating part of the group's error in steady motion, less the model's terms
    /// that do not repeat with the command ([`GroupCtx::aperiodic_um`]).
    fn non_repeating_um(&self) -> Option<f64> {
        group_non_repeating_um(self.data, self.sample, self.sample_rate_hz, self.aperiodic_um.as_deref())
    }

    /// The least-squares statistics of `columns` (over the window) against the residual, the
    /// columns' fundamental taken out when the residual's is.
    pub fn stats(&self, columns: &[Vec<f64>]) -> Stats {
        match &self.without_fundamental {
            None => Stats::from_columns(columns, &self.residual),
            Some(f) => {
                let removed: Vec<Vec<f64>> =
                    columns.iter().map(|c| f.remove(c, &self.sin_theta, &self.cos_theta)).collect();
                Stats::from_columns(&removed, &self.residual)
            }
        }
    }

    /// The same group with the fundamental taken out of its residual (`None` where the window
    /// is too short to tell sine from cosine).
    fn fundamental_free(&self) -> Option<Self> {
        let f = Fundamental::new(&self.sin_theta, &self.cos_theta)?;
        Some(Self {
            sample: self.sample,
            data: self.data,
            predicted_um: self.predicted_um.clone(),
            start: self.start,
            residual: f.remove(&self.residual, &self.sin_theta, &self.cos_theta),
            theta: self.theta.clone(),
            sin_theta: self.sin_theta.clone(),
            cos_theta: self.cos_theta.clone(),
            sample_rate_hz: self.sample_rate_hz,
            without_fundamental: Some(f),
            // The floor is read on the groups as they are.
            aperiodic_um: None,
        })
    }
}

/// One-sided sign-flip (randomisation) test of `sum(d) > 0`: under the null hypothesis each
/// group's improvement is as likely negative as positive, so `sum(d) / sqrt(sum(d^2))` is
/// approximately standard normal; the p-value of the observed sum. Unlike a rank test it
/// weighs groups by how much they gain, so an effect confined to a few groups (the fastest,
/// say) is not outvoted by many groups with nothing to explain.
pub fn sign_flip_p(d: &[f64]) -> f64 {
    let sum: f64 = d.iter().filter(|x| x.is_finite()).sum();
    let sq: f64 = d.iter().filter(|x| x.is_finite()).map(|x| x * x).sum();
    if sq <= 0.0 {
        return 1.0;
    }
    0.5 * libm::erfc(sum / sq.sqrt() / std::f64::consts::SQRT_2)
}

/// The scores tested: every candidate on the residual, and those whose signature reaches
/// beyond the fundamental also on the residual without it.
fn scores_tested() -> usize {
    Effect::ALL.len() + Effect::ALL.iter().filter(|c| c.beyond_the_fundamental()).count()
}

/// The p-value a candidate must be below: Bonferroni over the scores tested and the statistics.
pub fn significance_threshold() -> f64 {
    ALPHA / (scores_tested() * STATISTICS) as f64
}

/// The fewest groups on which a candidate can be significant at all: the sign-flip
/// statistic `sum(d) / sqrt(sum(d^2))` is at most `sqrt(n)` (every group improved alike), so
/// on fewer groups than this even a perfect candidate's p-value stays above
/// [`significance_threshold`] (11 groups at the default threshold), and `none` says nothing
/// of the residual.
pub fn groups_needed() -> usize {
    let threshold = significance_threshold();
    (1..=100_000).find(|&n| sign_flip_p(&vec![1.0; n]) < threshold).unwrap_or(100_000)
}

/// The residual's sum of squares over `groups` and its number of samples.
fn sums_of_squares(groups: &[GroupCtx]) -> (f64, usize) {
    let ss = groups.iter().map(|c| c.residual.iter().map(|r| r * r).sum::<f64>()).sum();
    (ss, groups.iter().map(|c| c.residual.len()).sum())
}

/// A group's held-out reduction `d` of its residual's sum of squares `ss`, relative to that
/// sum (the group's explained fraction; 0 for a group without residual), at least -1. It
/// is at most 1 by construction; below, a group with next to no residual would let one
/// small misprediction outweigh every other group (a 6 Hz group at 0.6 of 35 groups once
/// gave -15.8 against +0.9 elsewhere), and the bound is odd-symmetric, so the sign-flip
/// test stays valid.
fn relative_improvement(d: f64, ss: f64) -> f64 {
    if ss > 0.0 {
        (d / ss).max(-1.0)
    } else {
        0.0
    }
}

/// A stage's held-out gain at the command frequency, from per-group squared phasor errors
/// `(without, with)` its term, through the test every candidate takes (the floor's condition
/// is the stage's own).
struct PhasorGain {
    /// The groups' reductions, `without - with`, um^2.
    reductions: Vec<f64>,
    /// The sign-flip test's p-value, the smaller of the absolute and the relative statistic.
    p_value: f64,
    /// The share of `without` the term takes.
    explained_fraction: f64,
    /// The RMS of what it takes, um (a phasor `q` is a sine of RMS `|q| / sqrt(2)`).
    explained_rms_um: f64,
}

impl PhasorGain {
    /// `None` without a group whose both errors are known.
    fn of(pairs: impl IntoIterator<Item = (f64, f64)>) -> Option<Self> {
        let pairs: Vec<(f64, f64)> = pairs.into_iter().filter(|(a, b)| a.is_finite() && b.is_finite()).collect();
        if pairs.is_empty() {
            return None;
        }
        let reductions: Vec<f64> = pairs.iter().map(|(a, b)| a - b).collect();
        let relative: Vec<f64> = pairs.iter().map(|(a, b)| relative_improvement(a - b, *a)).collect();
        let without_ss: f64 = pairs.iter().map(|(a, _)| a).sum();
        let gained: f64 = reductions.iter().sum();
        Some(Self {
            p_value: sign_flip_p(&reductions).min(sign_flip_p(&relative)),
            explained_fraction: if without_ss > 0.0 { gained / without_ss } else { 0.0 },
            explained_rms_um: (gained.max(0.0) / 2.0 / pairs.len() as f64).sqrt(),
            reductions,
        })
    }

    /// Groups the term made better.
    fn improved(&self) -> usize {
        self.reductions.iter().filter(|r| **r > 0.0).count()
    }

    /// Whether it passes the test, with what it takes above `min_rms_um`.
    fn significant(&self, min_rms_um: f64) -> bool {
        self.explained_fraction >= MIN_EXPLAINED
            && self.p_value < significance_threshold()
            && self.explained_rms_um > min_rms_um
    }
}

/// P(Binomial(n, 1/2) >= k).
pub fn sign_test_p(k: usize, n: usize) -> f64 {
    if n == 0 {
        return 1.0;
    }
    // Sum in log space.
    let ln_choose = |n: usize, k: usize| -> f64 { (1..=k).map(|i| ((n - k + i) as f64).ln() - (i as f64).ln()).sum() };
    let mut p = 0.0;
    for j in k..=n {
        p += (ln_choose(n, j) - n as f64 * std::f64::consts::LN_2).exp();
    }
    p.min(1.0)
}

/// Builds each group's context: the model's predictions and the residual over the last second.
pub fn contexts<'a>(
    dataset: &'a Dataset,
    samples: &'a [GroupSample],
    model: &ModelFile,
) -> Result<Vec<GroupCtx<'a>>, AssessError> {
    let program = model.firmware_program()?;
    let fs = dataset.manifest.sample_rate_hz;
    let aperiodic: Vec<TickTerm> = program
        .terms
        .iter()
        .filter(|t| matches!(t, TickTerm::Drift { .. } | TickTerm::AxisCoupling { .. }))
        .copied()
        .collect();
    Ok(samples
        .par_iter()
        .map(|s| {
            let data = &dataset.groups[s.index];
            let (predicted_um, _) = predict_group(&program, s, data, fs);
            let aperiodic_um = (!aperiodic.is_empty()).then(|| terms_output(&aperiodic, data, s.info.start_s, fs));
            let start = s.targets.window_start;
            let residual = (start..data.len()).map(|k| data.z_tcp_um[k] - data.z_cmd_um[k] - predicted_um[k]).collect();
            let theta: Vec<f64> = (start..data.len())
                .map(|k| 2.0 * PI * s.targets.freq_hz * data.t_s[k] + s.targets.cmd.phase_rad)
                .collect();
            let (sin_theta, cos_theta) = theta.iter().map(|t| t.sin_cos()).unzip();
            GroupCtx {
                sample: s,
                data,
                predicted_um,
                start,
                residual,
                theta,
                sin_theta,
                cos_theta,
                sample_rate_hz: fs,
                without_fundamental: None,
                aperiodic_um,
            }
        })
        .collect())
}

/// Diagnoses `model` on `dataset`.
pub fn diagnose(dataset: &Dataset, model: &ModelFile) -> Result<Diagnosis, AssessError> {
    let corrected = model.probe_corrected(dataset);
    let dataset: &Dataset = &corrected;
    let mut feature_config = model.feature_config;
    feature_config.sample_rate_hz = dataset.manifest.sample_rate_hz as f32;
    let skip_s = model.training.as_ref().map_or(analysis::DEFAULT_SKIP_S, |t| t.skip_s);
    let samples = analysis::group_samples_skipping(dataset, &feature_config, skip_s)?;
    let ctx = contexts(dataset, &samples, model)?;
    let mut d = diagnose_contexts(&ctx, model.validation.waveform_rms_um);
    d.test.push_str(&format!(
        " Where none is significant, the residual at the command frequency exceeds {:.0}x the data's floor and the twin carries no resonance, the data's own error is searched for a mode inside the band: its phasors at the command frequency fitted with a velocity bank alone and with a resonance beside it, held out by fold of groups, the per-group reductions through the same test; a significant mode is the verdict. Where still none is and the twin carries nothing driven by the command's velocity, while the error at the slowest frequency lags the motion as a delay's does (in quadrature with it, at most {:.0} deg short of it, where the servo's own in-phase error would pull it, and {:.0} deg past it, where a servo's own first-order lag would turn it), the same phasors are fitted with the velocity bank alone, held out, against the twin's own residual there, through the same test, with what the bank takes at least {:.1}x the floor; a significant gain names setpoint-delay (also over a mode named inside the band that adds nothing to the bank in the data's own error).",
        in_band::FUNDAMENTAL_OVER_FLOOR,
        late_setpoint::DELAY_PHASE_SHORT_DEG,
        late_setpoint::DELAY_PHASE_PAST_DEG,
        late_setpoint::GAIN_OVER_FLOOR
    ));
    let data_error = DataError { dataset, phasors: OnceCell::new() };
    let found = if d.verdict == "none" {
        match in_band::look(&data_error, model, &d)?.filter(|m| m.significant) {
            Some(mode) => Some(mode),
            None => late_setpoint::look(&data_error, model, &ctx, &d)?.filter(|m| m.significant),
        }
    } else if named_mode_in_band(&d, &ctx) {
        // A mode named on the residual inside the band must hold in the data's own error
        // beyond the axis's linear response; a late setpoint's error, bent by the formulas,
        // can take a resonance's shape on the residual.
        match late_setpoint::look(&data_error, model, &ctx, &d)?.filter(|m| m.significant) {
            Some(late) if !in_band::mode_beyond_linear_response(&data_error, &d)? => Some(late),
            _ => None,
        }
    } else {
        None
    };
    if let Some(found) = found {
        d.ranking.retain(|r| r.effect != found.effect);
        d.verdict = found.effect.clone();
        d.summary = format!("{}: {}", found.effect, found.evidence);
        d.unexplained = None;
        d.ranking.insert(0, found);
    }
    Ok(d)
}

/// The data's own error at the command frequency, for the stages that read it rather than
/// the twin's residual (the in-band mode, the late setpoint): built when the first of them
/// asks, once for both.
struct DataError<'a> {
    dataset: &'a Dataset,
    phasors: OnceCell<DataErrorPhasors>,
}

impl DataError<'_> {
    fn phasors(&self) -> Result<&DataErrorPhasors, AssessError> {
        if let Some(phasors) = self.phasors.get() {
            return Ok(phasors);
        }
        let phasors = DataErrorPhasors::new(self.dataset, FOLDS)?;
        Ok(self.phasors.get_or_init(|| phasors))
    }
}

/// Whether the verdict is a structural mode the candidate found inside the test's band.
fn named_mode_in_band(d: &Diagnosis, ctx: &[GroupCtx]) -> bool {
    let top_hz = ctx.iter().map(|c| c.sample.info.freq_hz).fold(0.0, f64::max);
    d.verdict == Effect::StructuralMode.name()
        && d.ranking
            .first()
            .is_some_and(|r| r.effect == d.verdict && r.params.iter().any(|(name, f)| name == "freq_hz" && *f < top_hz))
}

/// Diagnoses prepared group contexts; `model_cv_rms_um` is the model's own held-out error.
pub fn diagnose_contexts(ctx: &[GroupCtx], model_cv_rms_um: f64) -> Diagnosis {
    let n = ctx.len();
    let (residual_ss, total_n) = sums_of_squares(ctx);
    let residual_rms_um = (residual_ss / total_n.max(1) as f64).sqrt();
    let folds = FOLDS.min(n).max(2);
    let repeatability = Repeatability::from_groups(ctx.par_iter().map(GroupCtx::non_repeating_um).collect());
    // The data's floor; unknown (groups too short) counts as none, leaving the minimum.
    let floor_um = repeatability.known_floor_um();
    // A twin fitted on this data has absorbed what an effect does to each group's
    // fundamental, as far as its formulas could, and left it distorted; the effect still shows
    // in what the formulas cannot touch (harmonics, steps, trends, lines). So the candidates
    // whose signature reaches there are also scored without the fundamental.
    let free: Option<Vec<GroupCtx>> = ctx.par_iter().map(GroupCtx::fundamental_free).collect();
    let score = |cand: &Effect, groups: &[GroupCtx], evaluated: candidates::Evaluated| -> Ranked {
        let group_ss: Vec<f64> = groups.iter().map(|c| c.residual.iter().map(|r| r * r).sum::<f64>()).collect();
        let (total_ss, total_n) = sums_of_squares(groups);
        let improved = evaluated.improvements.iter().filter(|d| **d > 0.0).count();
        // Absolute reductions weigh the groups with the most residual, which finds an
        // effect confined to the slow, small groups (friction); relative ones weigh every
        // group alike, which finds one spread over all the fast groups of a small grid
        // (a delay, on 35 groups) where a few large ones would outvote the rest.
        let relative: Vec<f64> =
            evaluated.improvements.iter().zip(&group_ss).map(|(d, ss)| relative_improvement(*d, *ss)).collect();
        let p_value = sign_flip_p(&evaluated.improvements).min(sign_flip_p(&relative));
        let explained_fraction =
            if total_ss > 0.0 { evaluated.improvements.iter().sum::<f64>() / total_ss } else { 0.0 };
        let explained_rms_um = (explained_fraction.max(0.0) * total_ss / total_n.max(1) as f64).sqrt();
        let significant = evaluated.testable
            && explained_fraction >= MIN_EXPLAINED
            && p_value < significance_threshold()
            && explained_rms_um > floor_um.max(NOT_REPEATING_MIN_UM);
        let without_fundamental = groups.first().is_some_and(|g| g.without_fundamental.is_some());
        Ranked {
            effect: cand.name().to_string(),
            explained_fraction,
            p_value,
            groups_improved: improved,
            params: evaluated.params,
            evidence: if without_fundamental {
                format!(
                    "{} (in the residual without each group's fundamental, which a twin fitted on this data absorbs)",
                    evaluated.evidence
                )
            } else {
                evaluated.evidence
            },
            significant,
            explained_rms_um,
            without_fundamental,
        }
    };
    let results: Vec<Ranked> = Effect::ALL
        .par_iter()
        .map(|cand| {
            let free = free.as_deref().filter(|_| cand.beyond_the_fundamental());
            let (on_whole, on_free) = candidates::evaluate_pair(*cand, ctx, free, folds);
            let whole = score(cand, ctx, on_whole);
            match free.zip(on_free) {
                Some((free, on_free)) => {
                    let beyond = score(cand, free, on_free);
                    // The significant score, and of two, the one that explains more.
                    if (beyond.significant && !whole.significant)
                        || (beyond.significant == whole.significant && beyond.explained_rms_um > whole.explained_rms_um)
                    {
                        beyond
                    } else {
                        whole
                    }
                }
                None => whole,
            }
        })
        .collect();
    let mut ranking = results;
    // The significant first, each kind by the residual RMS explained.
    ranking.sort_by(|a, b| {
        b.significant
            .cmp(&a.significant)
            .then(b.explained_rms_um.total_cmp(&a.explained_rms_um))
            .then(a.effect.cmp(&b.effect))
    });
    // A probe's scale error comes first: every candidate above is scored on readings it
    // distorts, and a twin fitted on them has learnt it as dynamics.
    if let Some(probe) = probe_check::probe_scale_error(ctx) {
        ranking.retain(|r| r.effect != probe.effect);
        ranking.insert(0, probe);
    }
    // The significant rank first, so the first is the verdict if any is.
    let verdict = match ranking.first() {
        Some(best) if best.significant => best.effect.clone(),
        _ => "none".to_string(),
    };
    let summary = match ranking.first() {
        Some(best) if best.significant => format!(
            "{} explains {:.0}% of the held-out residual (RMS {:.1} nm; the data's floor, what does not repeat from period to period, is {:.1} nm): {}",
            best.effect,
            best.explained_fraction * 100.0,
            residual_rms_um * 1e3,
            floor_um * 1e3,
            best.evidence
        ),
        Some(best) if n < groups_needed() => format!(
            "no candidate can be significant on {n} groups: the sign-flip test's p-value is at least {:.1e} there (every group improved alike), above the {:.1e} it asks; measure at least {} groups (the paper's grid has 99); the best, {}, explains {:.0}% of the residual (RMS {:.1} nm) on these (p = {:.1e})",
            sign_flip_p(&vec![1.0; n]),
            significance_threshold(),
            groups_needed(),
            best.effect,
            best.explained_fraction * 100.0,
            residual_rms_um * 1e3,
            best.p_value
        ),
        Some(best) => format!(
            "no candidate explains a significant part of the residual (RMS {:.1} nm; the data's floor, what does not repeat from period to period, is {:.1} nm); the best, {}, explains {:.0}% (p = {:.1e})",
            residual_rms_um * 1e3,
            floor_um * 1e3,
            best.effect,
            best.explained_fraction * 100.0,
            best.p_value
        ),
        None => "no groups".to_string(),
    };
    let test = format!(
        "Test: each candidate's coefficients are fitted on {folds} - 1 folds of groups and scored on the held-out fold, on the residual and, for the {} whose signature reaches beyond the fundamental, also on the residual without each group's fundamental. A score is significant when it explains at least {:.0}% of its residual, its per-group reductions of that residual add up to more than chance allows (one-sided sign-flip test over groups, sum / sqrt(sum of squares) against the normal, of the reductions and of the reductions relative to each group's residual, p < {ALPHA}/{} = {:.2e}, Bonferroni over the {} scores and the 2 statistics), and the residual RMS it explains exceeds the data's own floor, the part of the error that does not repeat from one command period to the next (the lower quartile over the groups, {:.1} nm, and at least {:.0} nm). The verdict is the significant candidate that explains the most residual RMS, else none. Ahead of them, the probe's scale is read on the slowest groups, where the servo follows the command: their in-phase ratios of probe to command as 1 + c + d / stroke (weighted by the stroke squared); a c of at least {:.1}% and {} standard errors whose part of the motion holds at least {:.0}% of the error there names sensor-gain first.",
        Effect::ALL.iter().filter(|c| c.beyond_the_fundamental()).count(),
        MIN_EXPLAINED * 100.0,
        scores_tested() * STATISTICS,
        significance_threshold(),
        scores_tested(),
        floor_um * 1e3,
        NOT_REPEATING_MIN_UM * 1e3,
        sts_analysis::probe_scale::SCALE_TOLERANCE * 100.0,
        sts_analysis::probe_scale::SCALE_MIN_T,
        MIN_EXPLAINED * 100.0
    );
    let not_repeating = repeatability.describe(|i| (ctx[i].sample.info.freq_hz, ctx[i].sample.info.amp_um));
    // Where the error does not repeat (a hunting axis) no twin can follow it: the structure,
    // and whether it stands above the floor, are read over the other groups (all of them
    // where none repeats).
    let leave_out: &[usize] = if repeatability.not_repeating.len() < n { &repeatability.not_repeating } else { &[] };
    let structure = structure::split(ctx, leave_out);
    // A line that holds most of what lies beyond the command's harmonics is not the sensors'
    // noise even where it sets the floor (it does not repeat with the command's period).
    let dominant_line = structure.line.as_ref().filter(|l| {
        l.rms_um > NOT_REPEATING_MIN_UM && l.rms_um * l.rms_um >= DOMINANT_LINE_SHARE * structure.rest.rms_um.powi(2)
    });
    let unexplained = if verdict != "none" {
        None
    } else if structure.residual_rms_um > UNEXPLAINED_OVER_FLOOR * floor_um.max(NOT_REPEATING_MIN_UM) {
        Some(describe_unexplained(&structure, floor_um, ctx))
    } else {
        dominant_line.map(|l| {
            format!(
                "a line at {:.0} Hz holds {:.1} nm, {:.0}% of what lies beyond the command's harmonics and trends ({:.1} nm): a vibration the command does not drive (a source on the machine or its floor), which no twin driven by the command can predict{}",
                l.freq_hz,
                l.rms_um * 1e3,
                100.0 * (l.rms_um / structure.rest.rms_um).powi(2).min(1.0),
                structure.rest.rms_um * 1e3,
                if l.rms_um * l.rms_um >= 0.5 * floor_um * floor_um { "; it is most of the data's floor here" } else { "" }
            )
        })
    };
    Diagnosis {
        verdict,
        ranking,
        residual_rms_um,
        model_cv_rms_um,
        summary,
        test,
        repeatability,
        group_files: ctx.iter().map(|c| c.sample.info.file.clone()).collect(),
        not_repeating,
        structure,
        unexplained,
    }
}

/// Share of the power beyond the command's harmonics and trends that makes the strongest
/// line there worth a report.
pub const DOMINANT_LINE_SHARE: f64 = 0.5;

/// A residual this many times the data's floor (or [`NOT_REPEATING_MIN_UM`]) that no
/// candidate explains is reported as structure left unexplained.
pub const UNEXPLAINED_OVER_FLOOR: f64 = 2.0;

/// Where an unexplained residual lies, in words: its parts above half the floor, largest
/// first, each with the groups where it is largest.
fn describe_unexplained(s: &structure::Structure, floor_um: f64, ctx: &[GroupCtx]) -> String {
    let residual_rms_um = s.residual_rms_um;
    let at = |part: &structure::Part| -> String {
        part.largest
            .iter()
            .map(|&(i, rms_um)| {
                let info = &ctx[i].sample.info;
                format!("{} Hz {} um: {:.1} nm", info.freq_hz, info.amp_um, rms_um * 1e3)
            })
            .collect::<Vec<_>>()
            .join("; ")
    };
    let mut parts: Vec<(f64, String)> = vec![
        (
            s.fundamental.rms_um,
            format!(
                "at the command frequency {:.1} nm (largest at {})",
                s.fundamental.rms_um * 1e3,
                at(&s.fundamental)
            ),
        ),
        (
            s.harmonics.rms_um,
            format!(
                "in its harmonics 2f-{}f {:.1} nm (largest at {})",
                structure::MAX_HARMONIC,
                s.harmonics.rms_um * 1e3,
                at(&s.harmonics)
            ),
        ),
        (
            s.trend.rms_um,
            format!(
                "in a trend (mean and slope over each group) {:.1} nm (largest at {})",
                s.trend.rms_um * 1e3,
                at(&s.trend)
            ),
        ),
        (
            s.rest.rms_um,
            format!(
                "elsewhere {:.1} nm{}",
                s.rest.rms_um * 1e3,
                s.line.as_ref().map_or(String::new(), |l| format!(
                    ", its strongest line at {:.0} Hz ({:.1} nm)",
                    l.freq_hz,
                    l.rms_um * 1e3
                ))
            ),
        ),
    ];
    parts.sort_by(|a, b| b.0.total_cmp(&a.0));
    let shown: Vec<String> = parts.into_iter().filter(|(rms, _)| *rms > 0.5 * floor_um).map(|(_, text)| text).collect();
    // Almost all at the command frequency: what the amplitude and phase formulas are for.
    let cause = if ctx.len() < groups_needed() {
        format!(
            "on {} groups no candidate can be significant (the test needs at least {}), so this does not tell which effect it is",
            ctx.len(),
            groups_needed()
        )
    } else if s.fundamental.rms_um.powi(2) >= 0.8 * residual_rms_um.powi(2) {
        "the twin's amplitude and phase formulas do not reproduce those groups (a fit with more epochs or a larger complexity may), or an effect changes the response there in a way no candidate models".to_string()
    } else {
        "an effect outside the library's candidates, or one of them in a form they do not model".to_string()
    };
    let over = match s.groups_left_out {
        0 => String::new(),
        left_out => format!(" over the {} groups whose error repeats", ctx.len() - left_out),
    };
    format!(
        "the residual{over} (RMS {:.1} nm) is {:.1}x the data's floor ({:.1} nm), but no candidate explains it; it lies {}: {cause}",
        residual_rms_um * 1e3,
        residual_rms_um / floor_um.max(NOT_REPEATING_MIN_UM),
        floor_um * 1e3,
        if shown.is_empty() { "nowhere in particular".to_string() } else { shown.join(", ") }
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn too_few_groups_cannot_be_significant() {
        let n = groups_needed();
        // 0.02 over 28 scores and statistics: z above 3.19, so 11 groups.
        assert_eq!(n, 11, "{}", significance_threshold());
        assert!(sign_flip_p(&vec![1.0; n]) < significance_threshold());
        assert!(sign_flip_p(&vec![1.0; n - 1]) >= significance_threshold());
        // Unequal gains only lower the statistic.
        let mut d = vec![1.0; n - 1];
        d[0] = 5.0;
        assert!(sign_flip_p(&d) > sign_flip_p(&vec![1.0; n - 1]));
    }

    #[test]
    fn sign_test_probabilities() {
        assert!((sign_test_p(0, 10) - 1.0).abs() < 1e-12);
        assert!((sign_test_p(10, 10) - 1.0 / 1024.0).abs() < 1e-12);
        assert!((sign_test_p(9, 10) - 11.0 / 1024.0).abs() < 1e-12);
    }

    #[test]
    fn the_relative_statistic_finds_an_effect_the_largest_groups_outvote() {
        // Twelve fast groups, 80% of each explained; two large groups where the candidate
        // gains and loses about as much as the twelve have in all.
        let residual_ss: Vec<f64> = [[1.0; 12].as_slice(), &[100.0, 100.0]].concat();
        let d = [[0.8; 12].as_slice(), &[-30.0, 35.0]].concat();
        let relative: Vec<f64> = d.iter().zip(&residual_ss).map(|(d, ss)| relative_improvement(*d, *ss)).collect();
        assert!(sign_flip_p(&d) > 0.3, "absolute: {}", sign_flip_p(&d));
        assert!(sign_flip_p(&relative) < significance_threshold(), "relative: {}", sign_flip_p(&relative));
        assert_eq!(relative_improvement(1.0, 0.0), 0.0);
    }

    #[test]
    fn sign_flip_test() {
        let mut d = vec![-1e-6; 16];
        d.extend([5.0, 4.0, 6.0, 5.5, 4.5, 5.0, 6.0, 5.0]);
        assert!(sign_flip_p(&d) < 1e-2);
        assert!(sign_flip_p(&[1.0, -1.0, 1.0, -1.0]) > 0.4);
        assert_eq!(sign_flip_p(&[0.0, 0.0]), 1.0);
    }
}
