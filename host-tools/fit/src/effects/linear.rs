//! The axis's linear response to the command, as per-tick terms: a setpoint delay and a
//! structural mode inside the measurement's band, the two effects whose error lives at the
//! command frequency but whose shape against frequency the amplitude and phase formulas do
//! not follow (a delay's error grows as the frequency, a resonance peaks between two of the
//! test's frequencies).
//!
//! - The velocity bank: a Laguerre bank (pole [`LAGUERRE_POLE`], 8 stages) on the command velocity,
//!   the velocity sign's input with a smoothing a quarter above the measurement's fastest
//!   velocity (linear over the measured range, bounded beyond). It is a general stable
//!   linear filter of the command on the servo's time scale: a setpoint delay
//!   (`cmd(t - tau) - cmd(t)`) and the servo's own lag.
//! - The resonance: [`TickTerm::Resonance`], the second-order high-pass of the command at the
//!   mode's frequency and damping (`sts_twin_core::synth::Resonance`), far too slow for the
//!   bank's pole.
//!
//! Both are fitted by least squares on the whole dynamic error (the formulas then fit what
//! they leave). The mode's frequency and damping come from a grid, each point scored at
//! the command frequency (per group the phasors of the command and of the error, the bank's
//! and the resonance's responses there in closed form): a small fit per point instead of a
//! pass over the samples.

use std::cell::OnceCell;

use rayon::prelude::*;
use sts_analysis::bases::laguerre;
use sts_analysis::response::{mode_grid, mode_high_pass, mul, phasor, velocity_bank, Complex};
use sts_dataset::Dataset;
use sts_model::Effect;
use sts_numerics::lsq::{least_squares, solve, Stats};
use sts_twin_core::program::{resonance_params_ok, TermInput, TickTerm, LAGUERRE_STAGES, VELOCITY_SMOOTH_32_BIT_LIMIT};
use sts_twin_core::synth::Resonance;
use sts_twin_core::SERVO_RATE_HZ;

use super::{term_input, GroupInputs};
use crate::FitError;
use sts_analysis::bases::LAGUERRE_POLE;

/// The velocity bank's input: the command velocity over 4 ticks, divided by a smoothing a
/// quarter above the fastest the measurement has (within the 32-bit division's range).
fn velocity_input(inputs: &[GroupInputs]) -> TermInput {
    let fastest = inputs
        .iter()
        .flat_map(|gi| gi.pos_nm.windows(5).map(|w| (i64::from(w[4]) - i64::from(w[0])).abs()))
        .max()
        .unwrap_or(0);
    let smooth = ((fastest as f64 * 1.25).ceil() as i32).clamp(1, VELOCITY_SMOOTH_32_BIT_LIMIT - 1);
    TermInput::VelocitySign { smooth_nm_per_4_ticks: smooth }
}

fn smoothing(kind: &TermInput) -> f64 {
    match *kind {
        TermInput::VelocitySign { smooth_nm_per_4_ticks } => f64::from(smooth_nm_per_4_ticks),
        _ => 1.0,
    }
}

/// Picometres of a coefficient in micrometres, refused where the firmware's i32 cannot hold it.
fn to_pm(effect: &str, value_um: f64) -> Result<i32, FitError> {
    let pm = (value_um * 1e6).round();
    if pm.is_nan() || pm.abs() >= f64::from(i32::MAX) {
        return Err(FitError::TermOutOfRange { effect: effect.into(), value_um });
    }
    Ok(pm as i32)
}

/// The bank's lag behind a steady velocity, us, from its gains (um per unit input): every
/// stage passes a constant `u` as `sqrt(1 - a^2) / (1 - a)`.
fn velocity_lag_us(gains_um: &[f64], kind: &TermInput) -> f64 {
    let dc = (1.0 - LAGUERRE_POLE * LAGUERRE_POLE).sqrt() / (1.0 - LAGUERRE_POLE);
    let um_per_unit = gains_um.iter().sum::<f64>() * dc;
    let um_per_s_per_unit = smoothing(kind) * 1e-3 / (4.0 / f64::from(SERVO_RATE_HZ));
    -um_per_unit / um_per_s_per_unit * 1e6
}

/// The whole dynamic error over a group's window, um.
fn dynamic_error(dataset: &Dataset, index: usize, gi: &GroupInputs) -> Vec<f64> {
    let g = &dataset.groups[index];
    (gi.start..g.len()).map(|k| g.z_tcp_um[k] - g.z_cmd_um[k]).collect()
}

fn bank_term(kind: TermInput, gains_um: &[f64], effect: &str) -> Result<TickTerm, FitError> {
    let mut gains_pm = [0i32; LAGUERRE_STAGES];
    for (g, t) in gains_pm.iter_mut().zip(gains_um) {
        *g = to_pm(effect, *t)?;
    }
    Ok(TickTerm::Laguerre { input: kind, pole_q30: (LAGUERRE_POLE * (1u64 << 30) as f64).round() as i32, gains_pm })
}

/// Least squares of the whole dynamic error on the velocity bank's stages and, with a unit
/// resonance, its output (the firmware's own filter) last: the coefficients, um per unit.
fn fit_on_samples(
    dataset: &Dataset,
    inputs: &[GroupInputs],
    kind: &TermInput,
    resonance: Option<&TickTerm>,
) -> Vec<f64> {
    let stats: Vec<Stats> = inputs
        .par_iter()
        .enumerate()
        .map(|(i, gi)| {
            let mut cols = laguerre(&term_input(kind, &gi.pos_nm), gi.start, LAGUERRE_POLE, LAGUERRE_STAGES);
            if let Some(mut r) = resonance.and_then(Resonance::new) {
                // Stepped from the group's first tick, as the firmware does; the window after.
                let out_um: Vec<f64> = gi.pos_nm.iter().map(|p| r.step(*p) as f64 * 1e-6).collect();
                cols.push(out_um[gi.start..].to_vec());
            }
            Stats::from_columns(&cols, &dynamic_error(dataset, i, gi))
        })
        .collect();
    solve(&stats.iter().collect::<Vec<_>>())
}

/// A setpoint delay: the velocity bank alone.
pub(super) fn fit_setpoint_delay(
    dataset: &Dataset,
    inputs: &[GroupInputs],
) -> Result<(TickTerm, Vec<(String, f64)>), FitError> {
    let kind = velocity_input(inputs);
    let theta = fit_on_samples(dataset, inputs, &kind, None);
    let term = bank_term(kind, &theta, Effect::SetpointDelay.name())?;
    Ok((
        term,
        vec![
            ("velocity_lag_us".into(), velocity_lag_us(&theta, &kind)),
            ("velocity_scale_nm_per_4_ticks".into(), smoothing(&kind)),
        ],
    ))
}

/// Per group the command's and the whole dynamic error's phasors at the command frequency,
/// and the frequencies: what the mode's grid is scored on.
struct ModePhasors {
    phasors: Vec<(Complex, Complex)>,
    freqs_hz: Vec<f64>,
    smooth: f64,
    top_hz: f64,
}

impl ModePhasors {
    fn new(dataset: &Dataset, inputs: &[GroupInputs], kind: &TermInput) -> Self {
        let freqs_hz: Vec<f64> = dataset.manifest.groups.iter().map(|g| g.freq_hz).collect();
        let top_hz = freqs_hz.iter().copied().fold(0.0, f64::max);
        let phasors = inputs
            .par_iter()
            .enumerate()
            .map(|(i, gi)| {
                let theta = &gi.theta[gi.start..];
                let g = &dataset.groups[i];
                (phasor(theta, &g.z_cmd_um[gi.start..]), phasor(theta, &dynamic_error(dataset, i, gi)))
            })
            .collect();
        Self { phasors, freqs_hz, smooth: smoothing(kind), top_hz }
    }

    /// Group `i`'s real and imaginary rows: the bank's stages, then the resonance when given.
    fn rows(&self, i: usize, mode: Option<(f64, f64)>) -> [[f64; LAGUERRE_STAGES + 1]; 2] {
        let (x, f) = (self.phasors[i].0, self.freqs_hz[i]);
        let bank: [Complex; LAGUERRE_STAGES] = velocity_bank(f, x, self.smooth, LAGUERRE_POLE);
        let m = mode.map_or((0.0, 0.0), |(mode_hz, zeta)| mul(mode_high_pass(f, mode_hz, zeta), x));
        let row =
            |part: fn(Complex) -> f64| std::array::from_fn(|k| part(if k < LAGUERRE_STAGES { bank[k] } else { m }));
        [row(|c| c.0), row(|c| c.1)]
    }

    /// Least squares of the error's phasors of the groups `train` allows on the bank and (when
    /// given) the mode: the coefficients and the residual RMS.
    fn fit(&self, train: &(dyn Fn(usize) -> bool + Sync), mode: Option<(f64, f64)>) -> Option<(Vec<f64>, f64)> {
        let mut rows = Vec::with_capacity(2 * self.phasors.len());
        let mut y = Vec::with_capacity(2 * self.phasors.len());
        for (i, (_, e)) in self.phasors.iter().enumerate().filter(|(i, _)| train(*i)) {
            rows.extend(self.rows(i, mode));
            y.extend([e.0, e.1]);
        }
        if mode.is_some() {
            least_squares(&rows, &y).map(|f| (f.coefficients.clone(), f.residual_rms))
        } else {
            let bank: Vec<[f64; LAGUERRE_STAGES]> = rows.iter().map(|r| std::array::from_fn(|k| r[k])).collect();
            least_squares(&bank, &y).map(|f| {
                let mut c = f.coefficients.clone();
                c.push(0.0);
                (c, f.residual_rms)
            })
        }
    }

    /// Per group, the squared phasor error the bank alone leaves, fitted on the other folds
    /// (NaN where a fold could not be fitted), um^2.
    fn bank_only_held_out(&self, folds: usize) -> Vec<f64> {
        let n = self.phasors.len();
        let mut ss = vec![f64::NAN; n];
        for fold in 0..folds {
            let train = |i: usize| i % folds != fold;
            if let Some((bank, _)) = self.fit(&train, None) {
                for (i, s) in ss.iter_mut().enumerate().filter(|(i, _)| !train(*i)) {
                    *s = self.group_ss(i, &bank, None);
                }
            }
        }
        ss
    }

    fn sse_at(&self, train: &(dyn Fn(usize) -> bool + Sync), point: (f64, f64)) -> f64 {
        self.fit(train, Some(point)).map_or(f64::INFINITY, |(_, rms)| rms)
    }

    /// Group `i`'s squared phasor error left by the coefficients, um^2.
    fn group_ss(&self, i: usize, coefficients: &[f64], mode: Option<(f64, f64)>) -> f64 {
        let e = self.phasors[i].1;
        let [re, im] = self.rows(i, mode);
        let dot = |r: &[f64; LAGUERRE_STAGES + 1]| r.iter().zip(coefficients).map(|(a, b)| a * b).sum::<f64>();
        (e.0 - dot(&re)).powi(2) + (e.1 - dot(&im)).powi(2)
    }

    fn best_of(&self, train: &(dyn Fn(usize) -> bool + Sync), grid: &[(f64, f64)]) -> (f64, f64) {
        let scores: Vec<f64> = grid.par_iter().map(|p| self.sse_at(train, *p)).collect();
        let best = scores.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1)).map_or(0, |(i, _)| i);
        grid[best]
    }

    /// The mode that fits the groups `train` allows best: the grid, then 0.5% and 10% steps
    /// around its best point (between two of the test's frequencies a mode's frequency and
    /// damping trade against each other, and the groups beside the resonance see a few percent
    /// of either). `None` when the best lies above the band (the formulas carry that one);
    /// `in_band_only` searches inside the band alone.
    fn search(&self, train: &(dyn Fn(usize) -> bool + Sync), in_band_only: bool) -> Option<(f64, f64)> {
        let mut grid = mode_grid(self.top_hz);
        if in_band_only {
            grid.retain(|(f, _)| *f < self.top_hz);
        }
        let (coarse_hz, coarse_zeta) = self.best_of(train, &grid);
        if coarse_hz >= self.top_hz {
            return None;
        }
        let fine: Vec<(f64, f64)> = (-8..=8)
            .flat_map(|i| {
                (-7..=7).map(move |j| {
                    let zeta = (coarse_zeta * 1.1f64.powi(j)).clamp(0.01, 0.9);
                    (coarse_hz * (1.0 + 0.005 * f64::from(i)), zeta)
                })
            })
            .collect();
        Some(self.best_of(train, &fine))
    }
}

/// A structural mode inside the band, found in the data's own error: where its frequency and
/// damping lie, and per group how much of the error at the command frequency it takes beyond
/// the axis's linear response, held out.
#[derive(Clone, Debug)]
pub struct InBandModeEvidence {
    /// The mode's frequency, Hz (from every group).
    pub freq_hz: f64,
    /// Its damping ratio.
    pub damping: f64,
    /// Per group, held out (k folds by group, round robin, the mode searched on the other
    /// folds): the squared phasor error at the command frequency that the velocity bank alone
    /// leaves, and that the bank with the resonance leaves, um^2. A phasor `q` is the sine
    /// `Re(q e^(j theta))`, of RMS `|q| / sqrt(2)`.
    pub bank_only_ss_um2: Vec<f64>,
    /// As `bank_only_ss_um2`, with the resonance.
    pub with_mode_ss_um2: Vec<f64>,
}

/// The data's own error at the command frequency per group, the phasors that both
/// [`DataErrorPhasors::in_band_mode`] and [`DataErrorPhasors::linear_response`] read, built
/// once (with what the velocity bank alone leaves of them, held out, on first use): a diagnosis
/// that asks for both pays for the group inputs and the bank's folds once.
pub struct DataErrorPhasors {
    m: ModePhasors,
    folds: usize,
    bank_only_ss_um2: OnceCell<Vec<f64>>,
}

impl DataErrorPhasors {
    /// The phasors of `dataset`'s groups; `folds` score what is fitted on them held out.
    pub fn new(dataset: &Dataset, folds: usize) -> Result<Self, FitError> {
        let inputs = super::all_group_inputs(dataset)?;
        let kind = velocity_input(&inputs);
        let m = ModePhasors::new(dataset, &inputs, &kind);
        let folds = folds.clamp(2, m.phasors.len().max(2));
        Ok(Self { m, folds, bank_only_ss_um2: OnceCell::new() })
    }

    fn bank_only_ss_um2(&self) -> &[f64] {
        self.bank_only_ss_um2.get_or_init(|| self.m.bank_only_held_out(self.folds))
    }

    /// Looks for a structural mode inside the measurement's band in the data's own error (not
    /// a twin's residual, which a twin fitted on the same data has distorted where its formulas
    /// absorbed the mode): the grid `fit --effect structural-mode` chooses from, so `None`
    /// exactly where that fit would leave the mode to the formulas.
    pub fn in_band_mode(&self) -> Option<InBandModeEvidence> {
        let (m, folds) = (&self.m, self.folds);
        let (freq_hz, damping) = m.search(&|_| true, false)?;
        let n = m.phasors.len();
        let mut with_mode_ss_um2 = vec![f64::NAN; n];
        for fold in 0..folds {
            let train = |i: usize| i % folds != fold;
            let Some(mode) = m.search(&train, true) else {
                continue;
            };
            let Some((with_mode, _)) = m.fit(&train, Some(mode)) else {
                continue;
            };
            for i in (0..n).filter(|i| !train(*i)) {
                with_mode_ss_um2[i] = m.group_ss(i, &with_mode, Some(mode));
            }
        }
        Some(InBandModeEvidence {
            freq_hz,
            damping,
            bank_only_ss_um2: self.bank_only_ss_um2().to_vec(),
            with_mode_ss_um2,
        })
    }

    /// [`LinearResponseEvidence`] of the data's own error.
    pub fn linear_response(&self) -> LinearResponseEvidence {
        let m = &self.m;
        let slowest_freq_hz = m.freqs_hz.iter().copied().fold(f64::INFINITY, f64::min);
        // Sum of E conj(C) and of |C|^2 over the slowest groups: E / C weighted by |C|^2.
        let (mut re, mut im, mut cc) = (0.0, 0.0, 0.0);
        for ((c, e), f) in m.phasors.iter().zip(&m.freqs_hz) {
            if *f <= slowest_freq_hz {
                re += e.0 * c.0 + e.1 * c.1;
                im += e.1 * c.0 - e.0 * c.1;
                cc += c.0 * c.0 + c.1 * c.1;
            }
        }
        let w = 2.0 * std::f64::consts::PI * slowest_freq_hz;
        let (slowest_phase_deg, slowest_lag_us) =
            if cc > 0.0 { (im.atan2(re).to_degrees(), -im / cc / w * 1e6) } else { (f64::NAN, f64::NAN) };
        LinearResponseEvidence {
            bank_only_ss_um2: self.bank_only_ss_um2().to_vec(),
            slowest_freq_hz,
            slowest_phase_deg,
            slowest_lag_us,
        }
    }
}

/// [`DataErrorPhasors::in_band_mode`] of `dataset`; `folds` score it held out.
pub fn in_band_mode_evidence(dataset: &Dataset, folds: usize) -> Result<Option<InBandModeEvidence>, FitError> {
    Ok(DataErrorPhasors::new(dataset, folds)?.in_band_mode())
}

/// The axis's linear response to the command fitted on the data's own error (the velocity
/// bank alone, the term `fit --effect setpoint-delay` carries), and the error's lag at the
/// bottom of the band, where a delay ahead of the servo loop shows plainly.
#[derive(Clone, Debug)]
pub struct LinearResponseEvidence {
    /// Per group, held out (k folds by group, round robin): the squared phasor error at the
    /// command frequency that the velocity bank leaves, um^2 (as
    /// [`InBandModeEvidence::bank_only_ss_um2`]; NaN where a fold could not be fitted).
    pub bank_only_ss_um2: Vec<f64>,
    /// The test's slowest command frequency, Hz.
    pub slowest_freq_hz: f64,
    /// The error's phase against the command there, pooled over the strokes, degrees
    /// (a delay's error, `cmd(t - tau) - cmd(t)`, is at -90).
    pub slowest_phase_deg: f64,
    /// The lag of the whole response there, `-Im(E / C) / w` pooled over the strokes, us:
    /// every delay between the trajectory and the tool, the controller's pipeline included.
    pub slowest_lag_us: f64,
}

/// [`LinearResponseEvidence`] of the data's own error; `folds` score the bank held out.
pub fn linear_response_evidence(dataset: &Dataset, folds: usize) -> Result<LinearResponseEvidence, FitError> {
    Ok(DataErrorPhasors::new(dataset, folds)?.linear_response())
}

/// A mode inside the band as the command's and the error's phasors show it (frequency Hz,
/// damping ratio), for the servo-axis twin's second mode to start from; `None` where the best
/// mode lies above the band.
pub(super) fn in_band_mode_start(dataset: &Dataset, inputs: &[GroupInputs]) -> Option<(f64, f64)> {
    ModePhasors::new(dataset, inputs, &velocity_input(inputs)).search(&|_| true, false)
}

/// A structural mode inside the band: its frequency and damping from a grid (the error's
/// phasors against the velocity bank beside the resonance), then the bank and the resonance
/// fitted together on the samples. `None` when the best mode lies above the band (the
/// formulas carry that one, as before).
#[allow(clippy::type_complexity)]
pub(super) fn fit_mode(
    dataset: &Dataset,
    inputs: &[GroupInputs],
) -> Result<Option<(Vec<TickTerm>, Vec<(String, f64)>)>, FitError> {
    let kind = velocity_input(inputs);
    let Some((mode_hz, zeta)) = ModePhasors::new(dataset, inputs, &kind).search(&|_| true, false) else {
        return Ok(None);
    };
    // A band reaching past what the term holds (a mode above 1 kHz): the formulas carry it.
    if !resonance_params_ok(mode_hz as f32, zeta as f32, 1.0) {
        return Ok(None);
    }
    // The bank and the resonance (unit gain; valid, checked above) on the samples.
    let unit = TickTerm::Resonance { freq_hz: mode_hz as f32, damping: zeta as f32, gain: 1.0 };
    let theta = fit_on_samples(dataset, inputs, &kind, Some(&unit));
    let gain = theta.get(LAGUERRE_STAGES).copied().unwrap_or(0.0);
    let resonance = TickTerm::Resonance { freq_hz: mode_hz as f32, damping: zeta as f32, gain: gain as f32 };
    if !resonance_params_ok(mode_hz as f32, zeta as f32, gain as f32) {
        return Err(FitError::ResonanceOutOfRange { freq_hz: mode_hz, damping: zeta, gain });
    }
    let bank = bank_term(kind, &theta[..LAGUERRE_STAGES], Effect::StructuralMode.name())?;
    Ok(Some((
        vec![bank, resonance],
        vec![
            ("freq_hz".into(), mode_hz),
            ("damping".into(), zeta),
            ("tcp_gain".into(), gain),
            ("peak_error_per_um".into(), gain.abs() / (2.0 * zeta)),
            ("velocity_lag_us".into(), velocity_lag_us(&theta[..LAGUERRE_STAGES], &kind)),
        ],
    )))
}
