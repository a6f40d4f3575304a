//! Where the residual lies, whatever the candidates say: each group's window split by least
//! squares into a trend (mean and slope), the command's fundamental, its harmonics 2f-7f and
//! the rest, and the rest's strongest spectral line pooled over the groups. When no candidate
//! explains the residual yet it stands above the data's floor, this is what the user is shown
//! instead of the nearest wrong effect.

use rustfft::num_complex::Complex;
use rustfft::FftPlannerScalar;
use serde::Serialize;

use sts_numerics::lsq::{solve, Stats};

use super::GroupCtx;

/// Highest harmonic of the command frequency fitted.
pub const MAX_HARMONIC: usize = 7;
/// A line is not reported within this distance of a group's harmonic, Hz.
const HARMONIC_GUARD_HZ: f64 = 1.5;

/// One part of the residual: its RMS over the groups split and the groups where it is largest.
#[derive(Clone, Debug, Serialize)]
pub struct Part {
    /// RMS over the windows of the groups split, um.
    pub rms_um: f64,
    /// The groups where it is largest, largest first (at most three): their index among the
    /// diagnosed groups and the part's RMS there, um.
    pub largest: Vec<(usize, f64)>,
}

/// The residual's strongest line outside the command's harmonics.
#[derive(Clone, Debug, Serialize)]
pub struct Line {
    /// Its frequency, Hz (to the windows' resolution).
    pub freq_hz: f64,
    /// Its RMS, pooled over the groups, um.
    pub rms_um: f64,
}

/// The residual split by where it lies.
#[derive(Clone, Debug, Serialize)]
pub struct Structure {
    /// Mean and slope over each window.
    pub trend: Part,
    /// The command frequency.
    pub fundamental: Part,
    /// Harmonics 2f to 7f of the command frequency.
    pub harmonics: Part,
    /// What is left: lines at other frequencies, steps, noise.
    pub rest: Part,
    /// The rest's strongest line (none when the windows are too short).
    pub line: Option<Line>,
    /// How many groups were left out of the split, their error not repeating.
    pub groups_left_out: usize,
    /// The RMS of the residual over the groups split, um.
    pub residual_rms_um: f64,
}

/// A group's parts' sums of squares, in the order trend, fundamental, harmonics, rest; and
/// the rest itself.
fn split_group(residual: &[f64], theta: &[f64]) -> ([f64; 4], Vec<f64>) {
    let n = residual.len();
    let mid = (n as f64 - 1.0) / 2.0;
    let mut columns: Vec<Vec<f64>> = vec![vec![1.0; n], (0..n).map(|k| (k as f64 - mid) / n.max(1) as f64).collect()];
    for h in 1..=MAX_HARMONIC {
        columns.push(theta.iter().map(|t| (h as f64 * t).sin()).collect());
        columns.push(theta.iter().map(|t| (h as f64 * t).cos()).collect());
    }
    let b = solve(&[&Stats::from_columns(&columns, residual)]);
    let part = |range: std::ops::Range<usize>| -> Vec<f64> {
        (0..n).map(|k| range.clone().map(|j| b.get(j).copied().unwrap_or(0.0) * columns[j][k]).sum()).collect()
    };
    let (trend, fundamental, harmonics) = (part(0..2), part(2..4), part(4..columns.len()));
    let rest: Vec<f64> = (0..n).map(|k| residual[k] - trend[k] - fundamental[k] - harmonics[k]).collect();
    let ss = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>();
    ([ss(&trend), ss(&fundamental), ss(&harmonics), ss(&rest)], rest)
}

/// The strongest line of the rests' pooled power spectrum (Hann window, each group's own
/// harmonics left out), with its RMS.
fn strongest_line(rests: &[(Vec<f64>, f64)], sample_rate_hz: f64) -> Option<Line> {
    let n = rests.iter().map(|(r, _)| r.len()).min()?;
    if n < 64 {
        return None;
    }
    // The scalar planner: the SIMD one instantiates every kernel of every instruction set, and
    // this crate compiled in 36 s instead of 10 s for a few transforms per diagnosis.
    let fft = FftPlannerScalar::<f64>::new().plan_fft_forward(n);
    let hann: Vec<f64> = (0..n).map(|k| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * k as f64 / n as f64).cos()).collect();
    // A sine of RMS a gives |X| = a * sqrt(2) * sum(hann) / 2 at its bin.
    let gain = hann.iter().sum::<f64>() / std::f64::consts::SQRT_2;
    let bin_hz = sample_rate_hz / n as f64;
    let mut power = vec![0.0; n / 2];
    let mut counted = vec![0usize; n / 2];
    for (rest, freq_hz) in rests {
        let mut buf: Vec<Complex<f64>> = rest[..n].iter().zip(&hann).map(|(x, w)| Complex::new(x * w, 0.0)).collect();
        fft.process(&mut buf);
        for (bin, p) in power.iter_mut().enumerate().skip(1) {
            let f = bin as f64 * bin_hz;
            let near_harmonic =
                (1..=MAX_HARMONIC).any(|h| (f - h as f64 * freq_hz).abs() <= HARMONIC_GUARD_HZ.max(bin_hz));
            if !near_harmonic {
                *p += buf[bin].norm_sqr();
                counted[bin] += 1;
            }
        }
    }
    let (bin, p) = power
        .iter()
        .zip(&counted)
        .enumerate()
        .filter(|(_, (_, c))| **c > 0)
        .map(|(bin, (p, c))| (bin, p / *c as f64))
        .max_by(|a, b| a.1.total_cmp(&b.1))?;
    Some(Line { freq_hz: bin as f64 * bin_hz, rms_um: p.sqrt() / gain })
}

/// One group's window as the split reads it.
pub struct Window<'a> {
    /// The group's position among the diagnosed groups.
    pub position: usize,
    /// The residual, um.
    pub residual: &'a [f64],
    /// The command's phase at each sample, rad.
    pub theta: &'a [f64],
    /// The command's frequency, Hz.
    pub freq_hz: f64,
}

/// Splits the residual of every group but those at the positions `leave_out` (the groups
/// whose error does not repeat: what no twin can predict is not structure a candidate
/// misses). [`Part::largest`] keeps the positions in `ctx`.
pub fn split(ctx: &[GroupCtx], leave_out: &[usize]) -> Structure {
    let windows: Vec<Window> = ctx
        .iter()
        .enumerate()
        .filter(|(i, _)| !leave_out.contains(i))
        .map(|(position, c)| Window {
            position,
            residual: &c.residual,
            theta: &c.theta,
            freq_hz: c.sample.targets.freq_hz,
        })
        .collect();
    split_windows(&windows, ctx.len(), ctx.first().map_or(0.0, |c| c.sample_rate_hz))
}

/// Splits the given windows, `groups` of them diagnosed in all.
pub fn split_windows(windows: &[Window], groups: usize, sample_rate_hz: f64) -> Structure {
    let per_group: Vec<([f64; 4], Vec<f64>)> = windows.iter().map(|w| split_group(w.residual, w.theta)).collect();
    let total_n: usize = windows.iter().map(|w| w.residual.len()).sum::<usize>().max(1);
    let part = |i: usize| -> Part {
        let rms_um = (per_group.iter().map(|g| g.0[i]).sum::<f64>() / total_n as f64).sqrt();
        let mut by_group: Vec<(usize, f64)> = per_group
            .iter()
            .zip(windows)
            .map(|(g, w)| (w.position, (g.0[i] / w.residual.len().max(1) as f64).sqrt()))
            .collect();
        by_group.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        by_group.truncate(3);
        Part { rms_um, largest: by_group }
    };
    let rests: Vec<(Vec<f64>, f64)> = per_group.iter().zip(windows).map(|(g, w)| (g.1.clone(), w.freq_hz)).collect();
    let residual_ss: f64 = windows.iter().flat_map(|w| w.residual).map(|r| r * r).sum();
    Structure {
        trend: part(0),
        fundamental: part(1),
        harmonics: part(2),
        rest: part(3),
        line: strongest_line(&rests, sample_rate_hz),
        groups_left_out: groups - windows.len(),
        residual_rms_um: (residual_ss / total_n as f64).sqrt(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_part_lands_where_it_was_put() {
        let fs = 8000.0;
        let f0 = 20.0;
        let theta: Vec<f64> = (0..8000).map(|k| 2.0 * std::f64::consts::PI * f0 * k as f64 / fs).collect();
        let residual: Vec<f64> = theta
            .iter()
            .enumerate()
            .map(|(k, t)| {
                let line = 0.02 * (2.0 * std::f64::consts::PI * 137.0 * k as f64 / fs).sin();
                0.05 + 0.1 * (t + 0.3).sin() + 0.03 * (3.0 * t).cos() + line
            })
            .collect();
        let (ss, rest) = split_group(&residual, &theta);
        let rms = |s: f64| (s / 8000.0).sqrt();
        assert!((rms(ss[0]) - 0.05).abs() < 1e-3, "trend {}", rms(ss[0]));
        assert!((rms(ss[1]) - 0.1 / 2f64.sqrt()).abs() < 1e-3, "fundamental {}", rms(ss[1]));
        assert!((rms(ss[2]) - 0.03 / 2f64.sqrt()).abs() < 1e-3, "harmonics {}", rms(ss[2]));
        assert!((rms(ss[3]) - 0.02 / 2f64.sqrt()).abs() < 1e-3, "rest {}", rms(ss[3]));
        let line = strongest_line(&[(rest, f0)], fs).expect("a line");
        assert_eq!(line.freq_hz, 137.0);
        assert!((line.rms_um - 0.02 / 2f64.sqrt()).abs() < 2e-3, "{line:?}");
    }

    #[test]
    fn groups_left_out_are_not_in_any_part() {
        let fs = 8000.0;
        let theta: Vec<f64> = (0..4000).map(|k| 2.0 * std::f64::consts::PI * 20.0 * k as f64 / fs).collect();
        let quiet: Vec<f64> = theta.iter().map(|t| 0.01 * t.sin()).collect();
        let hunting: Vec<f64> = theta.iter().map(|t| 0.5 * (3.0 * t).sin() + 0.2).collect();
        let window = |position, residual| Window { position, residual, theta: &theta, freq_hz: 20.0 };
        let s = split_windows(&[window(0, &quiet), window(2, &quiet)], 3, fs);
        assert_eq!(s.groups_left_out, 1);
        assert!((s.residual_rms_um - 0.01 / 2f64.sqrt()).abs() < 1e-6, "{}", s.residual_rms_um);
        assert!(s.harmonics.rms_um < 1e-6 && s.trend.rms_um < 1e-6, "{s:?}");
        assert_eq!(s.fundamental.largest.iter().map(|p| p.0).collect::<Vec<_>>(), vec![0, 2]);
        let all = split_windows(&[window(0, &quiet), window(1, &hunting), window(2, &quiet)], 3, fs);
        assert_eq!(all.groups_left_out, 0);
        assert_eq!(all.harmonics.largest[0].0, 1);
        assert!(all.residual_rms_um > 0.2, "{}", all.residual_rms_um);
    }
}
