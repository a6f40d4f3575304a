//! The axis's linear response to the command, as per-tick terms: a setpoint delay and a
//! structural mode inside the measurement's band, the two effects whose error lives at the
//! command frequency but whose shape against frequency the amplitude and phase formulas do
//! not follow (a delay's error grows as the frequency, a resonance peaks between two of the
//! test's frequencies).
//!
//! - The velocity bank: a Laguerre bank (pole [`POLE`], 8 stages) on the command velocity,
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

use rayon::prelude::*;
use sts_analysis::bases::laguerre;
use sts_analysis::lsq::{least_squares, solve, Stats};
use sts_analysis::resample::SERVO_RATE_HZ;
use sts_analysis::response::{mode_grid, mode_high_pass, mul, phasor, velocity_bank, Complex};
use sts_dataset::Dataset;
use sts_twin_core::program::{resonance_params_ok, TermInput, TickTerm, LAGUERRE_STAGES, VELOCITY_SMOOTH_32_BIT_LIMIT};
use sts_twin_core::synth::Resonance;

use super::{term_input, GroupInputs, POLE};
use crate::FitError;

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
    let dc = (1.0 - POLE * POLE).sqrt() / (1.0 - POLE);
    let um_per_unit = gains_um.iter().sum::<f64>() * dc;
    let um_per_s_per_unit = smoothing(kind) * 1e-3 / (4.0 / SERVO_RATE_HZ);
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
    Ok(TickTerm::Laguerre { input: kind, pole_q30: (POLE * (1u64 << 30) as f64).round() as i32, gains_pm })
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
            let mut cols = laguerre(&term_input(kind, &gi.pos_nm), gi.start, POLE, LAGUERRE_STAGES);
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
    let term = bank_term(kind, &theta, "setpoint-delay")?;
    Ok((
        term,
        vec![
            ("velocity_lag_us".into(), velocity_lag_us(&theta, &kind)),
            ("velocity_scale_nm_per_4_ticks".into(), smoothing(&kind)),
        ],
    ))
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
    let smooth = smoothing(&kind);
    let freqs_hz: Vec<f64> = dataset.manifest.groups.iter().map(|g| g.freq_hz).collect();
    let top_hz = freqs_hz.iter().copied().fold(0.0, f64::max);
    // Per group: the command's and the error's phasors.
    let phasors: Vec<(Complex, Complex)> = inputs
        .par_iter()
        .enumerate()
        .map(|(i, gi)| {
            let theta = &gi.theta[gi.start..];
            let g = &dataset.groups[i];
            (phasor(theta, &g.z_cmd_um[gi.start..]), phasor(theta, &dynamic_error(dataset, i, gi)))
        })
        .collect();
    // The grid `diagnose` names a mode from.
    let grid = mode_grid(top_hz);
    let sse_at = |&(mode_hz, zeta): &(f64, f64)| -> f64 {
        let mut rows: Vec<[f64; LAGUERRE_STAGES + 1]> = Vec::with_capacity(2 * phasors.len());
        let mut y = Vec::with_capacity(2 * phasors.len());
        for ((x, e), f) in phasors.iter().zip(&freqs_hz) {
            let bank: [Complex; LAGUERRE_STAGES] = velocity_bank(*f, *x, smooth, POLE);
            let mode = mul(mode_high_pass(*f, mode_hz, zeta), *x);
            rows.push(std::array::from_fn(|k| if k < LAGUERRE_STAGES { bank[k].0 } else { mode.0 }));
            rows.push(std::array::from_fn(|k| if k < LAGUERRE_STAGES { bank[k].1 } else { mode.1 }));
            y.extend([e.0, e.1]);
        }
        least_squares(&rows, &y).map_or(f64::INFINITY, |fit| fit.residual_rms)
    };
    let best_of = |grid: &[(f64, f64)]| -> (f64, f64) {
        let scores: Vec<f64> = grid.par_iter().map(sse_at).collect();
        let best = scores.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1)).map_or(0, |(i, _)| i);
        grid[best]
    };
    let (coarse_hz, coarse_zeta) = best_of(&grid);
    if coarse_hz >= top_hz {
        return Ok(None);
    }
    // Then 0.5% and 10% steps around it: between two of the test's frequencies a mode's
    // frequency and damping trade against each other, and the groups beside the resonance
    // see a few percent of either.
    let fine: Vec<(f64, f64)> = (-8..=8)
        .flat_map(|i| {
            (-7..=7).map(move |j| {
                let zeta = (coarse_zeta * 1.1f64.powi(j)).clamp(0.01, 0.9);
                (coarse_hz * (1.0 + 0.005 * f64::from(i)), zeta)
            })
        })
        .collect();
    let (mode_hz, zeta) = best_of(&fine);
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
    let bank = bank_term(kind, &theta[..LAGUERRE_STAGES], "structural-mode")?;
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
