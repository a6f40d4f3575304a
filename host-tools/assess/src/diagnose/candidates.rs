//! The nine candidate effects: regressors of the residual, cross-validated by group.

use std::f64::consts::PI;

use rayon::prelude::*;

use sts_analysis::bases::{laguerre, LAGUERRE_POLE};
use sts_analysis::response::{delay, mode_grid, mode_high_pass, mul, phasor_of, sine_weights, velocity_bank, Complex};
use sts_analysis::sine::line_amp;
use sts_model::Effect;
use sts_numerics::lsq::{solve, Stats};

use super::GroupCtx;
use sts_twin_core::program::LAGUERRE_STAGES;
use sts_twin_core::SERVO_RATE_HZ;

/// Reference frequency normalising the frequency powers, Hz.
const F_REF_HZ: f64 = 40.0;

/// A candidate's cross-validated result.
pub struct Evaluated {
    /// Per held-out group: `SS(r) - SS(r - explained)`.
    pub improvements: Vec<f64>,
    /// Parameters from the fit on all groups.
    pub params: Vec<(String, f64)>,
    /// Words.
    pub evidence: String,
    /// Whether the dataset has what the candidate needs.
    pub testable: bool,
}

/// Slide velocity from the encoder, um/s (difference over +-4 samples).
pub fn encoder_velocity(ctx: &GroupCtx) -> Vec<f64> {
    let x = &ctx.data.z_enc_um;
    let n = x.len();
    let h = 4usize;
    (0..n)
        .map(|k| {
            let a = k.saturating_sub(h);
            let b = (k + h).min(n - 1);
            (x[b] - x[a]) * ctx.sample_rate_hz / (b - a).max(1) as f64
        })
        .collect()
}

/// The Dahl state of a position signal with presliding distance `x0_um`.
pub fn dahl(x: &[f64], x0_um: f64) -> Vec<f64> {
    let mut u = 0.0f64;
    let mut prev = x.first().copied().unwrap_or(0.0);
    x.iter()
        .map(|&xi| {
            let dx = xi - prev;
            prev = xi;
            u = (u + dx / x0_um * (1.0 - u * dx.signum())).clamp(-1.0, 1.0);
            u
        })
        .collect()
}

/// The variant whose least-squares fit over `groups` leaves the least, and its theta (the
/// first variant's where no fit leaves a finite sum, so the theta has its columns' length
/// whatever the data).
fn best_variant(stats: &[Vec<Stats>], groups: &[usize]) -> (usize, Vec<f64>) {
    let mut best: Option<(usize, Vec<f64>, f64)> = None;
    for (v, st) in stats.iter().enumerate() {
        let train: Vec<&Stats> = groups.iter().map(|&g| &st[g]).collect();
        let theta = solve(&train);
        let sse: f64 = train.iter().map(|s| s.sse(&theta)).sum();
        // NaN loses to any number; the first variant stands until one is better.
        let better = match &best {
            None => true,
            Some((_, _, b)) => sse < *b || (b.is_nan() && !sse.is_nan()),
        };
        if better {
            best = Some((v, theta, sse));
        }
    }
    best.map_or((0, Vec::new()), |(v, theta, _)| (v, theta))
}

/// Cross-validation over grid variants: `stats[v][g]` for variant v, group g.
/// Returns per-group held-out improvements, the variant chosen on all groups and its theta.
fn cross_validate(stats: &[Vec<Stats>], folds: usize) -> (Vec<f64>, usize, Vec<f64>) {
    let n = stats.first().map_or(0, |s| s.len());
    let mut improvements = vec![0.0; n];
    for fold in 0..folds {
        let train: Vec<usize> = (0..n).filter(|g| g % folds != fold).collect();
        let (v, theta) = best_variant(stats, &train);
        for g in (0..n).filter(|g| g % folds == fold) {
            let s = &stats[v][g];
            improvements[g] = s.residual_ss() - s.sse(&theta);
        }
    }
    let (v, theta) = best_variant(stats, &(0..n).collect::<Vec<_>>());
    (improvements, v, theta)
}

/// [`cross_validate`] of what the variants' columns add to nuisance columns that every
/// variant has first: per held-out group, `SS(r - nuisance fit) - SS(r - variant fit)`, both
/// fitted on the other folds. Returns the improvements, the variant chosen on all groups and
/// its theta (the nuisance coefficients first).
fn cross_validate_beyond(nuisance: &[Stats], stats: &[Vec<Stats>], folds: usize) -> (Vec<f64>, usize, Vec<f64>) {
    let n = nuisance.len();
    let mut improvements = vec![0.0; n];
    for fold in 0..folds {
        let train: Vec<usize> = (0..n).filter(|g| g % folds != fold).collect();
        let base_theta = solve(&train.iter().map(|&g| &nuisance[g]).collect::<Vec<_>>());
        let (v, theta) = best_variant(stats, &train);
        for g in (0..n).filter(|g| g % folds == fold) {
            improvements[g] = nuisance[g].sse(&base_theta) - stats[v][g].sse(&theta);
        }
    }
    let (v, theta) = best_variant(stats, &(0..n).collect::<Vec<_>>());
    (improvements, v, theta)
}

/// Contribution (over the window) of columns `x` with coefficients `theta`.
fn contribution(x: &[Vec<f64>], theta: &[f64]) -> Vec<f64> {
    let n = x.first().map_or(0, |c| c.len());
    (0..n).map(|k| x.iter().zip(theta).map(|(c, t)| c[k] * t).sum()).collect()
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// Odd-harmonic descriptor: mean residual at 3f and 5f for the smallest and largest
/// command amplitudes, um.
fn odd_harmonics_by_amplitude(ctx: &[GroupCtx]) -> (f64, f64) {
    let amps: Vec<f64> = ctx.iter().map(|c| c.sample.info.amp_um).collect();
    let lo = amps.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = amps.iter().copied().fold(0.0, f64::max);
    let mean_at = |target: f64| {
        let sel: Vec<&GroupCtx> = ctx.iter().filter(|c| (c.sample.info.amp_um - target).abs() < 1e-9).collect();
        let sum: f64 = sel
            .iter()
            .map(|c| {
                let t = &c.data.t_s[c.start..];
                line_amp(t, &c.residual, 3.0 * c.sample.info.freq_hz)
                    + line_amp(t, &c.residual, 5.0 * c.sample.info.freq_hz)
            })
            .sum();
        sum / sel.len().max(1) as f64
    };
    (mean_at(lo), mean_at(hi))
}

fn cmd_amp(c: &GroupCtx) -> f64 {
    c.sample.targets.cmd.amp
}

/// `effect`'s cross-validated evaluation as a candidate on the groups `whole` and, where given,
/// on `free`, the same groups with each one's fundamental taken out of the residual: the
/// columns that read the data alone are built once for both (the same results as two
/// evaluations, in less time).
pub fn evaluate_pair(
    effect: Effect,
    whole: &[GroupCtx],
    free: Option<&[GroupCtx]>,
    folds: usize,
) -> (Evaluated, Option<Evaluated>) {
    // The candidates whose columns read the residual: one evaluation per set.
    let each =
        |evaluate: fn(&[GroupCtx], usize) -> Evaluated| (evaluate(whole, folds), free.map(|f| evaluate(f, folds)));
    match effect {
        Effect::CoulombFriction => {
            let columns = friction_columns(whole);
            (friction(whole, &columns, folds), free.map(|f| friction(f, &columns, folds)))
        }
        Effect::PreslidingHysteresis => {
            let columns = hysteresis_columns(whole);
            (hysteresis(whole, &columns, folds), free.map(|f| hysteresis(f, &columns, folds)))
        }
        Effect::ForceRipple => ripple(whole, free, folds),
        Effect::StructuralMode => each(mode),
        Effect::LoopDelay => each(loop_delay),
        Effect::SetpointDelay => each(setpoint_delay),
        Effect::ThermalDrift => each(thermal),
        Effect::AxisCoupling => each(coupling),
        Effect::SensorGain => each(gain),
    }
}

/// The smoothing velocities of [`friction`]'s grid, um/s.
const FRICTION_SMOOTHING_UM_PER_S: [f64; 4] = [3.0, 10.0, 30.0, 100.0];

/// [`friction`]'s columns per group and grid variant: they read the data alone, so every set
/// of the same groups shares them.
fn friction_columns(ctx: &[GroupCtx]) -> Vec<Vec<Vec<Vec<f64>>>> {
    ctx.par_iter()
        .map(|c| {
            let v = encoder_velocity(c);
            FRICTION_SMOOTHING_UM_PER_S
                .iter()
                .map(|vs| {
                    let u: Vec<f64> = v.iter().map(|x| (x / vs).clamp(-1.0, 1.0)).collect();
                    laguerre(&u, c.start, LAGUERRE_POLE, LAGUERRE_STAGES)
                })
                .collect()
        })
        .collect()
}

fn friction(ctx: &[GroupCtx], columns: &[Vec<Vec<Vec<f64>>>], folds: usize) -> Evaluated {
    let smooth_grid = FRICTION_SMOOTHING_UM_PER_S;
    let stats: Vec<Vec<Stats>> = (0..smooth_grid.len())
        .map(|v| ctx.par_iter().zip(columns).map(|(c, cols)| c.stats(&cols[v])).collect())
        .collect();
    let (improvements, v, theta) = cross_validate(&stats, folds);
    let contrib_rms = rms(&columns.iter().flat_map(|cols| contribution(&cols[v], &theta)).collect::<Vec<f64>>());
    let (small, large) = odd_harmonics_by_amplitude(ctx);
    Evaluated {
        improvements,
        params: vec![("smoothing_velocity_um_per_s".into(), smooth_grid[v]), ("reversal_error_rms_nm".into(), contrib_rms * 1e3)],
        evidence: format!(
            "error steps at every velocity reversal of the slide (a force that flips with the sign of the velocity, through the servo's disturbance response); odd harmonics 3f+5f of {:.0} nm at the smallest stroke and {:.0} nm at the largest: about the same size, so relative to the motion they fall with amplitude",
            small * 1e3,
            large * 1e3
        ),
        testable: true,
    }
}

/// The presliding distances of [`hysteresis`]'s grid, um.
const HYSTERESIS_X0_UM: [f64; 4] = [0.1, 0.3, 1.0, 3.0];

/// [`hysteresis`]'s columns per group and grid variant, shared as [`friction_columns`]'.
fn hysteresis_columns(ctx: &[GroupCtx]) -> Vec<Vec<Vec<Vec<f64>>>> {
    ctx.par_iter()
        .map(|c| {
            HYSTERESIS_X0_UM
                .iter()
                .map(|x0| laguerre(&dahl(&c.data.z_enc_um, *x0), c.start, LAGUERRE_POLE, LAGUERRE_STAGES))
                .collect()
        })
        .collect()
}

fn hysteresis(ctx: &[GroupCtx], columns: &[Vec<Vec<Vec<f64>>>], folds: usize) -> Evaluated {
    let x0_grid = HYSTERESIS_X0_UM;
    let stats: Vec<Vec<Stats>> =
        (0..x0_grid.len()).map(|v| ctx.par_iter().zip(columns).map(|(c, cols)| c.stats(&cols[v])).collect()).collect();
    let (improvements, v, theta) = cross_validate(&stats, folds);
    let contrib_rms = rms(&columns.iter().flat_map(|cols| contribution(&cols[v], &theta)).collect::<Vec<f64>>());
    let (small, large) = odd_harmonics_by_amplitude(ctx);
    Evaluated {
        improvements,
        params: vec![("presliding_distance_um".into(), x0_grid[v]), ("hysteresis_error_rms_nm".into(), contrib_rms * 1e3)],
        evidence: format!(
            "a spring-like force that saturates after a presliding distance of about {} um (Dahl): small strokes change mainly the fundamental, large strokes saturate it into odd harmonics (3f+5f: {:.0} nm at the smallest stroke, {:.0} nm at the largest: they grow with amplitude)",
            x0_grid[v],
            small * 1e3,
            large * 1e3
        ),
        testable: true,
    }
}

/// Per group: the statistics of `[sin theta, cos theta]` against the residual, from which
/// every variant of a candidate that lives at the command frequency is mixed
/// ([`Stats::mixed`]).
fn fundamental_stats(ctx: &[GroupCtx]) -> Vec<Stats> {
    ctx.par_iter().map(|c| c.stats(&[c.sin_theta.clone(), c.cos_theta.clone()])).collect()
}

/// Highest command frequency of the test, Hz.
fn band_top_hz(ctx: &[GroupCtx]) -> f64 {
    ctx.iter().map(|c| c.sample.info.freq_hz).fold(0.0, f64::max)
}

/// A structural mode between slide and tool, inside the test band or above it: the tool
/// moves by `g H(f) x_slide` with `H = r^2 / (1 - r^2 + 2 j zeta r)`, `r = f / f_mode`
/// (a second-order resonance driven by the slide's acceleration), `g` complex (two linear
/// coefficients: the modal gain on `H`, and the acceleration's quadrature for how the
/// accelerometer's view of the mode moved the twin's own prediction). On the grid of mode
/// frequencies and damping ratios that `fit --effect` uses ([`mode_grid`]); `H` is normalised
/// to `(f / 40 Hz)^2` far below the mode, where it reduces to an error in phase with the
/// acceleration.
fn mode(ctx: &[GroupCtx], folds: usize) -> Evaluated {
    let top_hz = band_top_hz(ctx);
    let variants = mode_grid(top_hz);
    let base = fundamental_stats(ctx);
    let slide: Vec<Complex> =
        ctx.par_iter().map(|c| phasor_of(&c.sin_theta, &c.cos_theta, &c.data.z_enc_um[c.start..])).collect();
    // The weights on `[sin, cos]` of the mode's motion of the tool on a slide of phasor `p`.
    let mode_weights = |c: &GroupCtx, (f_mode, zeta): (f64, f64), p: Complex| {
        let h = mode_high_pass(c.sample.info.freq_hz, f_mode, zeta);
        let norm = (F_REF_HZ / f_mode).powi(2);
        let [in_phase, _] = sine_weights(mul((h.0 / norm, h.1 / norm), p));
        in_phase
    };
    let stats: Vec<Vec<Stats>> = variants
        .par_iter()
        .map(|v| {
            ctx.iter()
                .zip(&base)
                .zip(&slide)
                .map(|((c, b), p)| {
                    // The mode's response, and the acceleration's quadrature (the old twin's
                    // prediction moved by what the accelerometer sees of the mode).
                    let w2 = (c.sample.info.freq_hz / F_REF_HZ).powi(2);
                    let [_, quadrature] = sine_weights((w2 * p.0, w2 * p.1));
                    b.mixed(&[mode_weights(c, *v, *p), quadrature])
                })
                .collect()
        })
        .collect();
    let plain = cross_validate(&stats, folds);
    // The same mode beyond a smooth linear response of the axis (a velocity bank on the
    // command, as `fit` carries it): a twin fitted on this data has followed a resonance
    // with its formulas as far as they could, and left a residual that a mode alone does not
    // fit. The credit is what the mode adds to the bank, held out.
    let bank: Vec<Vec<Vec<f64>>> = ctx
        .par_iter()
        .map(|c| {
            let x = phasor_of(&c.sin_theta, &c.cos_theta, &c.data.z_cmd_um[c.start..]);
            let stages: [Complex; LAGUERRE_STAGES] = velocity_bank(c.sample.info.freq_hz, x, 1e3, LAGUERRE_POLE);
            stages
                .iter()
                .map(|s| {
                    let [in_phase, _] = sine_weights(*s);
                    in_phase
                })
                .collect()
        })
        .collect();
    let bank_stats: Vec<Stats> = base.iter().zip(&bank).map(|(b, w)| b.mixed(w)).collect();
    let both: Vec<Vec<Stats>> = variants
        .par_iter()
        .map(|v| {
            ctx.iter()
                .zip(&base)
                .zip(&slide)
                .zip(&bank)
                .map(|(((c, b), p), w)| {
                    let mut columns = w.clone();
                    columns.push(mode_weights(c, *v, *p));
                    b.mixed(&columns)
                })
                .collect()
        })
        .collect();
    let beyond = cross_validate_beyond(&bank_stats, &both, folds);
    let beyond_bank = beyond.0.iter().sum::<f64>() > plain.0.iter().sum::<f64>();
    let (improvements, best, theta) = if beyond_bank {
        let (improvements, best, theta) = beyond;
        // The mode's coefficient is the last.
        (improvements, best, vec![theta.last().copied().unwrap_or(0.0), 0.0])
    } else {
        plain
    };
    let (f_mode, zeta) = variants[best];
    let g = theta.first().copied().unwrap_or(0.0).hypot(theta.get(1).copied().unwrap_or(0.0));
    let in_band = f_mode < top_hz;
    if in_band {
        // The tool's extra motion at the resonance per unit of slide motion.
        let peak = g * (F_REF_HZ / f_mode).powi(-2) / (2.0 * zeta);
        Evaluated {
            improvements,
            params: vec![
                ("freq_hz".into(), f_mode),
                ("damping".into(), zeta),
                ("peak_error_per_um".into(), peak),
            ],
            evidence: format!(
                "the error resonates against frequency at about {f_mode:.1} Hz inside the test band (damping ratio about {zeta:.2}): it grows towards that frequency, turns its phase by half a turn through it, and stays at about {:.2}% of the stroke above it (at the resonance {:.1}%): a structural mode between slide and tool that the measurement test excites",
                g * (F_REF_HZ / f_mode).powi(-2) * 100.0,
                peak * 100.0
            ),
            testable: true,
        }
    } else {
        // Transient line: the residual's strongest line above 100 Hz in each group's first 0.25 s.
        let line_hz = transient_line_hz(ctx);
        Evaluated {
            improvements,
            params: vec![
                ("extra_error_at_40hz_per_um".into(), g),
                ("freq_hz".into(), f_mode),
                ("ringing_line_hz".into(), line_hz),
            ],
            evidence: format!(
                "an extra error in phase with the acceleration, growing with the frequency squared ({:.2}% of the stroke at 40 Hz), and the start of each group rings at about {:.0} Hz: a structural mode between slide and tool, above the test band",
                g * 100.0,
                line_hz
            ),
            testable: true,
        }
    }
}

/// Loop delay: less phase margin, the closed loop's response changing as the frequency cubed
/// (jerk) and to the fourth (snap) at the bottom of the band.
fn loop_delay(ctx: &[GroupCtx], folds: usize) -> Evaluated {
    let columns: Vec<Vec<Vec<f64>>> = ctx
        .iter()
        .map(|c| {
            let w = c.sample.info.freq_hz / F_REF_HZ;
            let a = cmd_amp(c);
            vec![
                c.cos_theta.iter().map(|v| a * w.powi(3) * v).collect(),
                c.sin_theta.iter().map(|v| a * w.powi(4) * v).collect(),
            ]
        })
        .collect();
    let stats: Vec<Vec<Stats>> = vec![ctx.iter().zip(&columns).map(|(c, cols)| c.stats(cols)).collect()];
    let (improvements, _, theta) = cross_validate(&stats, folds);
    let lead = theta.first().copied().unwrap_or(0.0);
    let phase_deg_at_40 = lead.abs().atan().to_degrees();
    Evaluated {
        improvements,
        params: vec![
            ("jerk_coefficient_at_40hz_per_um".into(), lead),
            ("snap_coefficient_at_40hz_per_um".into(), theta.get(1).copied().unwrap_or(0.0)),
        ],
        evidence: format!(
            "the phase of the error shifts increasingly towards the highest frequencies (about {:.2} deg per um of stroke at 40 Hz, as the frequency cubed) while low frequencies are untouched: less phase margin from an extra delay in the servo loop",
            phase_deg_at_40
        ),
        testable: true,
    }
}

/// Setpoint delay: the whole response late by `tau`, the loop unchanged. The tool's motion
/// `y(t)` becomes `y(t - tau)`, so the error gains `Re((e^(-j w tau) - 1) Y e^(j theta))`, `Y`
/// the measured tool motion's phasor: at the bottom of the band in quadrature with the motion
/// and in proportion to the frequency (where a loop delay grows as its cube). A grid of delays
/// with one free scale (a negative one: the setpoint now arrives earlier).
fn setpoint_delay(ctx: &[GroupCtx], folds: usize) -> Evaluated {
    let delays_us: Vec<f64> = (0..32).map(|i| 20.0 * 1.18f64.powi(i)).collect();
    let base = fundamental_stats(ctx);
    let tool: Vec<Complex> =
        ctx.par_iter().map(|c| phasor_of(&c.sin_theta, &c.cos_theta, &c.data.z_tcp_um[c.start..])).collect();
    let stats: Vec<Vec<Stats>> = delays_us
        .par_iter()
        .map(|tau_us| {
            ctx.iter()
                .zip(&base)
                .zip(&tool)
                .map(|((c, b), y)| {
                    let phi = 2.0 * PI * c.sample.info.freq_hz * tau_us * 1e-6;
                    let d = delay(phi);
                    let late = mul((d.0 - 1.0, d.1), *y);
                    b.mixed(&sine_weights(late)[..1])
                })
                .collect()
        })
        .collect();
    let (improvements, best, theta) = cross_validate(&stats, folds);
    let delay_us = delays_us[best] * theta.first().copied().unwrap_or(0.0);
    let lag_deg_at_40 = 360.0 * F_REF_HZ * delay_us * 1e-6;
    Evaluated {
        improvements,
        params: vec![("delay_us".into(), delay_us), ("phase_lag_at_40hz_deg".into(), lag_deg_at_40)],
        evidence: format!(
            "the whole response is {:.0} us {} ({:.2} deg at 40 Hz): an error in quadrature with the motion, growing in proportion to the frequency from the slowest groups on, the servo's own response unchanged: a delay ahead of the servo loop (the setpoint or the command path), not inside it",
            delay_us.abs(),
            if delay_us >= 0.0 { "late" } else { "early" },
            lag_deg_at_40.abs()
        ),
        testable: true,
    }
}

fn transient_line_hz(ctx: &[GroupCtx]) -> f64 {
    let fs = ctx.first().map_or(f64::from(SERVO_RATE_HZ), |c| c.sample_rate_hz);
    let n = (0.25 * fs) as usize;
    let mut spectrum = vec![0.0; 1000];
    for c in ctx {
        if c.data.len() < n {
            continue;
        }
        let r: Vec<f64> = (0..n).map(|k| c.data.z_tcp_um[k] - c.data.z_cmd_um[k] - c.predicted_um[k]).collect();
        let t = &c.data.t_s[..n];
        for (i, s) in spectrum.iter_mut().enumerate().skip(120).step_by(4) {
            *s += line_amp(t, &r, i as f64);
        }
    }
    spectrum.iter().enumerate().skip(120).max_by(|a, b| a.1.total_cmp(b.1)).map_or(0.0, |(i, _)| i as f64)
}

fn thermal(ctx: &[GroupCtx], folds: usize) -> Evaluated {
    let tau_grid = [100.0, 300.0, 1000.0, 3000.0, 10000.0];
    let has_temp = ctx.iter().all(|c| c.data.temp_c.is_some());
    let mut variants: Vec<Vec<Stats>> = tau_grid
        .iter()
        .map(|tau| {
            ctx.iter()
                .map(|c| {
                    let t0 = c.sample.info.start_s;
                    let e: Vec<f64> = c.data.t_s[c.start..].iter().map(|t| (-(t0 + t) / tau).exp()).collect();
                    c.stats(&[vec![1.0; e.len()], e])
                })
                .collect()
        })
        .collect();
    if has_temp {
        let mean_t: f64 = ctx.iter().map(|c| c.data.temp_c.as_ref().map_or(0.0, |v| v[c.start])).sum::<f64>()
            / ctx.len().max(1) as f64;
        variants.push(
            ctx.iter()
                .map(|c| {
                    let temp = c
                        .data
                        .temp_c
                        .as_ref()
                        .map(|v| v[c.start..].iter().map(|x| x - mean_t).collect::<Vec<f64>>())
                        .unwrap_or_default();
                    c.stats(&[vec![1.0; temp.len()], temp])
                })
                .collect(),
        );
    }
    let (improvements, v, theta) = cross_validate(&variants, folds);
    let means: Vec<(f64, f64)> = ctx
        .iter()
        .map(|c| (c.sample.info.start_s, c.residual.iter().sum::<f64>() / c.residual.len().max(1) as f64))
        .collect();
    let span = means.iter().map(|m| m.1).fold(f64::NEG_INFINITY, f64::max)
        - means.iter().map(|m| m.1).fold(f64::INFINITY, f64::min);
    let t_span = means.last().map_or(0.0, |m| m.0) - means.first().map_or(0.0, |m| m.0);
    let mut params = vec![("drift_span_um".into(), span)];
    let evidence = if v < tau_grid.len() {
        params.push(("time_constant_s".into(), tau_grid[v]));
        format!(
            "the mean error drifts by {:.2} um over {:.0} min of machine time (first-order, time constant about {:.0} s) whatever the frequency and amplitude: thermal growth of the tool side",
            span,
            t_span / 60.0,
            tau_grid[v]
        )
    } else {
        params.push(("um_per_k".into(), theta.get(1).copied().unwrap_or(0.0)));
        format!(
            "the mean error follows the machine temperature ({:.2} um per K; {:.2} um over {:.0} min) whatever the frequency and amplitude: thermal growth of the tool side",
            theta.get(1).copied().unwrap_or(0.0),
            span,
            t_span / 60.0
        )
    };
    Evaluated { improvements, params, evidence, testable: true }
}

/// [`Effect::ForceRipple`] on `whole` and on `free`, the same groups without each one's
/// fundamental: each position sine is computed once for both where their searches reach the
/// same pitches, and each result is what a search of that set alone gives.
fn ripple(whole: &[GroupCtx], free: Option<&[GroupCtx]>, folds: usize) -> (Evaluated, Option<Evaluated>) {
    let sets: Vec<&[GroupCtx]> = std::iter::once(whole).chain(free).collect();
    // Pitch search on the unfiltered position sine over the slowest groups, where the servo
    // follows a position-periodic error without filtering (peak velocity at most 100 um/s, or
    // the slowest fifth). The sets share their groups, so they share which are slow.
    let vpeak = |c: &GroupCtx| 2.0 * PI * c.sample.info.freq_hz * cmd_amp(c);
    let mut speeds: Vec<f64> = whole.iter().map(vpeak).collect();
    speeds.sort_by(f64::total_cmp);
    let limit = speeds.get(speeds.len() / 5).copied().unwrap_or(0.0).max(100.0);
    let slow: Vec<usize> = (0..whole.len()).filter(|&g| vpeak(&whole[g]) <= limit).collect();
    // The best pitch of `pitches` and its coefficients, for each of the sets `which`.
    let search = |pitches: &[f64], which: &[usize]| -> Vec<(f64, Vec<f64>)> {
        // raw[p][g][k]: pitch p, slow group g, set which[k].
        let raw: Vec<Vec<Vec<Stats>>> = pitches
            .par_iter()
            .map(|p| {
                slow.iter()
                    .map(|&g| {
                        let c = &whole[g];
                        let (s, co) = position_sine(&c.data.z_enc_um[c.start..], *p);
                        let columns = [s, co];
                        which.iter().map(|&k| sets[k][g].stats(&columns)).collect()
                    })
                    .collect()
            })
            .collect();
        (0..which.len())
            .map(|k| {
                let of_set: Vec<Vec<Stats>> =
                    raw.iter().map(|per_group| per_group.iter().map(|st| st[k].clone()).collect()).collect();
                let (_, best, theta) = cross_validate(&of_set, folds);
                (pitches[best], theta)
            })
            .collect()
    };
    // Each set's search on its own grid, one search for the sets whose grids are the same.
    let search_each = |grids: Vec<Vec<f64>>| -> Vec<(f64, Vec<f64>)> {
        let mut found: Vec<Option<(f64, Vec<f64>)>> = vec![None; grids.len()];
        for k in 0..grids.len() {
            if found[k].is_some() {
                continue;
            }
            let which: Vec<usize> = (k..grids.len()).filter(|&j| found[j].is_none() && grids[j] == grids[k]).collect();
            for (j, result) in which.iter().zip(search(&grids[k], &which)) {
                found[*j] = Some(result);
            }
        }
        found.into_iter().flatten().collect()
    };
    // A grid of 4% steps, then 0.25% and 0.02% around its best: over a travel of ten pitches
    // a 4% error in the pitch turns the sine half a period against the error.
    let coarse = search_each(vec![(0..60).map(|i| 1.04f64.powi(i)).collect(); sets.len()]);
    let fine = search_each(
        coarse.iter().map(|(c, _)| (-16..=16).map(|k| c * (1.0 + 0.0025 * f64::from(k))).collect()).collect(),
    );
    let best = search_each(
        fine.iter().map(|(f, _)| (-12..=12).map(|k| f * (1.0 + 0.0002 * f64::from(k))).collect()).collect(),
    );
    // Filtered model at each set's pitch, its columns built once per pitch.
    let mut columns_at: Vec<(f64, Vec<Vec<Vec<f64>>>)> = Vec::new();
    let mut column_index = Vec::with_capacity(best.len());
    for (pitch, _) in &best {
        if let Some(i) = columns_at.iter().position(|(p, _)| p == pitch) {
            column_index.push(i);
        } else {
            column_index.push(columns_at.len());
            let columns = whole
                .par_iter()
                .map(|c| {
                    let (s, co) = position_sine(&c.data.z_enc_um, *pitch);
                    let mut cols = laguerre(&s, c.start, LAGUERRE_POLE, 2 * LAGUERRE_STAGES);
                    cols.extend(laguerre(&co, c.start, LAGUERRE_POLE, 2 * LAGUERRE_STAGES));
                    cols
                })
                .collect();
            columns_at.push((*pitch, columns));
        }
    }
    let evaluate = |k: usize| {
        let (pitch, theta_raw) = &best[k];
        let amp_nm = theta_raw.first().copied().unwrap_or(0.0).hypot(theta_raw.get(1).copied().unwrap_or(0.0)) * 1e3;
        let columns = &columns_at[column_index[k]].1;
        let stats = vec![sets[k].iter().zip(columns).map(|(c, cols)| c.stats(cols)).collect()];
        let (improvements, _, _) = cross_validate(&stats, folds);
        Evaluated {
            improvements,
            params: vec![("pitch_um".into(), *pitch), ("amplitude_nm".into(), amp_nm)],
            evidence: format!(
                "the error repeats with the slide's position every {:.2} um ({:.0} nm at slow speed), not with time: an encoder interpolation error or motor force ripple; at higher speeds the servo filters it (or its resonance amplifies it)",
                pitch, amp_nm
            ),
            testable: true,
        }
    };
    (evaluate(0), free.map(|_| evaluate(1)))
}

/// The sine and cosine of the slide's position `x_um` over a pitch, in one pass, so that the
/// compiler takes both from one `sincos` (the same values as `sin` and `cos`: `diagnose --json`
/// byte-identical, 4% faster on 99 groups with the pitch search's 118 pitches).
fn position_sine(x_um: &[f64], pitch_um: f64) -> (Vec<f64>, Vec<f64>) {
    x_um.iter()
        .map(|x| {
            let angle = 2.0 * PI * x / pitch_um;
            (angle.sin(), angle.cos())
        })
        .unzip()
}

fn coupling(ctx: &[GroupCtx], folds: usize) -> Evaluated {
    let has_x = ctx.iter().all(|c| c.data.x_acc_mps2.is_some() || c.data.x_mm.is_some());
    let has_spindle = ctx.iter().all(|c| c.data.spindle_deg.is_some());
    if !has_x && !has_spindle {
        return Evaluated {
            improvements: vec![0.0; ctx.len()],
            params: Vec::new(),
            evidence: "not testable: the dataset has no x_acc_mps2, x_mm or spindle_deg column".into(),
            testable: false,
        };
    }
    let columns: Vec<Vec<Vec<f64>>> = ctx
        .iter()
        .map(|c| {
            let mut cols = Vec::new();
            if has_x {
                let xacc: Vec<f64> = match (&c.data.x_acc_mps2, &c.data.x_mm) {
                    (Some(a), _) => a[c.start..].to_vec(),
                    (None, Some(x)) => {
                        let dt = 1.0 / c.sample_rate_hz;
                        (c.start..x.len())
                            .map(|k| {
                                if k >= 1 && k + 1 < x.len() {
                                    (x[k + 1] - 2.0 * x[k] + x[k - 1]) * 1e-3 / (dt * dt)
                                } else {
                                    0.0
                                }
                            })
                            .collect()
                    }
                    _ => vec![0.0; c.residual.len()],
                };
                cols.push(xacc);
            }
            if has_spindle {
                let sp = c.data.spindle_deg.as_ref().map(|v| &v[c.start..]).unwrap_or(&[]);
                cols.push(sp.iter().map(|d| d.to_radians().sin()).collect());
                cols.push(sp.iter().map(|d| d.to_radians().cos()).collect());
            }
            cols
        })
        .collect();
    let stats = vec![ctx.iter().zip(&columns).map(|(c, cols)| c.stats(cols)).collect()];
    let (improvements, _, theta) = cross_validate(&stats, folds);
    let mut params = Vec::new();
    let mut words = Vec::new();
    let mut i = 0;
    let coefficient = |k: usize| theta.get(k).copied().unwrap_or(0.0);
    if has_x {
        params.push(("x_um_per_mps2".into(), coefficient(0)));
        words.push(format!("the error follows the X slide's acceleration ({:.2} um per m/s^2)", coefficient(0)));
        i = 1;
    }
    if has_spindle {
        let amp = coefficient(i).hypot(coefficient(i + 1));
        params.push(("spindle_um".into(), amp));
        words.push(format!("a once-per-revolution component of the spindle of {:.0} nm", amp * 1e3));
    }
    Evaluated {
        improvements,
        params,
        evidence: format!("{}: motion of another axis reaches the tool in Z", words.join(" and ")),
        testable: true,
    }
}

fn gain(ctx: &[GroupCtx], folds: usize) -> Evaluated {
    let probe: Vec<Stats> = ctx.iter().map(|c| c.stats(&[c.data.z_tcp_um[c.start..].to_vec()])).collect();
    let acc: Vec<Stats> = ctx.iter().map(|c| c.stats(&[c.predicted_um[c.start..].to_vec()])).collect();
    let (improvements, v, theta) = cross_validate(&[probe, acc], folds);
    let k = theta.first().copied().unwrap_or(0.0);
    if v == 0 {
        Evaluated {
            improvements,
            params: vec![("probe_gain".into(), 1.0 + k)],
            evidence: format!(
                "an error in phase with the motion, proportional to the stroke at every frequency down to the slowest: the capacitance probe reads {:.1}% {} (scale error)",
                k.abs() * 100.0,
                if k >= 0.0 { "too much" } else { "too little" }
            ),
            testable: true,
        }
    } else {
        Evaluated {
            improvements,
            params: vec![("prediction_scale".into(), 1.0 + k)],
            evidence: format!(
                "the measured error is {:.1}% {} than the model predicts from the accelerometer at every frequency, in proportion to the prediction: the accelerometer's scale differs from the one the model was trained with",
                k.abs() * 100.0,
                if k >= 0.0 { "larger" } else { "smaller" }
            ),
            testable: true,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn laguerre_bank_has_unit_energy_impulse_responses() {
        let mut u = vec![0.0; 4000];
        u[0] = 1.0;
        let out = laguerre(&u, 0, 0.9, 4);
        for stage in &out {
            let energy: f64 = stage.iter().map(|v| v * v).sum();
            assert!((energy - 1.0).abs() < 1e-6, "{energy}");
        }
    }

    #[test]
    fn dahl_saturates() {
        let x: Vec<f64> = (0..1000).map(|k| k as f64 * 0.01).collect();
        let u = dahl(&x, 0.5);
        assert!(u[999] > 0.99 && u[10] < 0.3);
    }
}
