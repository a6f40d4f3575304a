//! Resampling a measurement to the co-processor's servo rate.
//!
//! The twin is fitted and checked tick by tick at the rate the firmware runs (8 kHz): its
//! features are computed per sample and its per-tick terms count ticks. A lab's recorder may
//! run at another rate; the dataset format allows any. Every column of every group is
//! resampled to the servo rate by band-limited (windowed-sinc) interpolation at the exact
//! instants `k / rate`, with the cut-off below the lower of the two Nyquist frequencies.
//!
//! Written here rather than with an audio resampler (rubato and the like): those work on
//! streams in chunks with a start-up delay to trim and an interpolated sinc table; a
//! measurement record is resampled whole, at exact instants, and one weighted sum per output
//! sample does that in a few lines, the same bits on every machine.
//!
//! The kernel's weights (three trigonometric calls per tap, 80-odd taps per output sample)
//! were nearly all the cost. Every column of a group has the same instants, so the weights
//! are computed once per instant and applied to every column; at the usual ratios the
//! instants' phases repeat, so each phase's weights are computed once and kept; the
//! groups run in parallel. `sts-twin compare` on the 99-group measurement recorded at 10 kHz:
//! 133 s before, 4.1 s now (2 cores; 2.6 s for the same data at 8 kHz). The output is the
//! same bit for bit (a unit test checks it against the per-sample kernel).

use std::borrow::Cow;
use std::collections::HashMap;
use std::f64::consts::PI;

use rayon::prelude::*;
use sts_dataset::{Dataset, GroupData};
use sts_twin_core::SERVO_RATE_HZ;

/// Zero crossings of the sinc on each side of an output instant (at the cut-off).
const HALF_WIDTH_CROSSINGS: f64 = 32.0;
/// Cut-off as a fraction of the lower Nyquist frequency (room for the window's transition).
const CUTOFF_FRACTION: f64 = 0.95;

/// `dataset` at the servo rate: borrowed when it is at that rate already.
pub fn to_servo_rate(dataset: &Dataset) -> Cow<'_, Dataset> {
    if dataset.manifest.sample_rate_hz == f64::from(SERVO_RATE_HZ) {
        Cow::Borrowed(dataset)
    } else {
        Cow::Owned(resample(dataset, f64::from(SERVO_RATE_HZ)))
    }
}

/// `dataset` resampled to `rate_hz` (every column; `t_s` becomes `k / rate_hz`). The groups
/// are resampled in parallel; the result does not depend on the thread count.
pub fn resample(dataset: &Dataset, rate_hz: f64) -> Dataset {
    let mut manifest = dataset.manifest.clone();
    let from_hz = manifest.sample_rate_hz;
    manifest.sample_rate_hz = rate_hz;
    let groups = dataset.groups.par_iter().map(|g| resample_group(g, from_hz, rate_hz)).collect();
    Dataset { manifest, groups }
}

fn resample_group(group: &GroupData, from_hz: f64, to_hz: f64) -> GroupData {
    let n_in = group.len();
    // The output covers the input's span: instants k / to_hz up to the last input sample.
    let n_out = if n_in == 0 { 0 } else { ((n_in - 1) as f64 * to_hz / from_hz).floor() as usize + 1 };
    let kernel = Kernel::new(from_hz, to_hz);
    // An angle that wraps (a spindle's, 0..360 degrees) is unwrapped, resampled and wrapped
    // again.
    let spindle_unwrapped = group.spindle_deg.as_deref().map(unwrap_deg);
    let mut columns: Vec<&[f64]> = vec![&group.z_cmd_um, &group.z_enc_um, &group.z_tcp_um, &group.acc_mps2];
    let optional =
        [group.x_mm.as_deref(), group.x_acc_mps2.as_deref(), spindle_unwrapped.as_deref(), group.temp_c.as_deref()];
    columns.extend(optional.iter().flatten());
    let mut resampled = kernel.resample_columns(&columns, n_out, from_hz, to_hz).into_iter();
    let mut next = || resampled.next().unwrap_or_default();
    let (z_cmd_um, z_enc_um, z_tcp_um, acc_mps2) = (next(), next(), next(), next());
    let [x_mm, x_acc_mps2, spindle_deg, temp_c] = optional.map(|c| c.map(|_| next()));
    GroupData {
        t_s: (0..n_out).map(|k| k as f64 / to_hz).collect(),
        z_cmd_um,
        z_enc_um,
        z_tcp_um,
        acc_mps2,
        x_mm,
        x_acc_mps2,
        spindle_deg: spindle_deg.map(|deg| deg.into_iter().map(|d| d.rem_euclid(360.0)).collect()),
        temp_c,
    }
}

/// `deg` (wrapping at 360) without its wraps.
fn unwrap_deg(deg: &[f64]) -> Vec<f64> {
    let mut unwrapped = Vec::with_capacity(deg.len());
    let mut turns = 0.0;
    for (i, &d) in deg.iter().enumerate() {
        if i > 0 {
            let step = d - deg[i - 1];
            turns -= (step / 360.0).round();
        }
        unwrapped.push(d + 360.0 * turns);
    }
    unwrapped
}

/// Output instants whose weights are computed together (about 700 KB of weights).
const BLOCK_INSTANTS: usize = 1024;

/// One output instant's taps: the input samples `first..first + len` with the weights at
/// `offset..offset + len` of the block's weights, and their sum.
struct Taps {
    /// The fractional input index of the instant.
    pos: f64,
    first: usize,
    offset: usize,
    len: usize,
    weight_sum: f64,
}

/// Phases whose weights are kept (at most about 3 MB of weights).
const MAX_KNOWN_PHASES: usize = 4096;

/// Weights already computed, by phase (`pos - first` as bits, the tap count). At the usual
/// ratios the phases repeat: 10 kHz to 8 kHz has 4, 9.6 kHz 5, 44.1 kHz 80, so the
/// trigonometry runs a few times per group; at a ratio that does not repeat, every instant
/// computes its own.
#[derive(Default)]
struct KnownPhases {
    index: HashMap<(u64, usize), (usize, f64)>,
    weights: Vec<f64>,
}

/// The interpolation kernel: a Blackman-windowed sinc with the cut-off `cutoff` (cycles per
/// input sample), `half_width` input samples on each side.
struct Kernel {
    cutoff: f64,
    half_width: f64,
}

impl Kernel {
    fn new(from_hz: f64, to_hz: f64) -> Self {
        let cutoff = 0.5 * CUTOFF_FRACTION * (to_hz / from_hz).min(1.0);
        Self { cutoff, half_width: HALF_WIDTH_CROSSINGS / (2.0 * cutoff) }
    }

    fn weight(&self, u: f64) -> f64 {
        if u.abs() >= self.half_width {
            return 0.0;
        }
        let x = 2.0 * self.cutoff * u;
        let sinc = if x == 0.0 { 1.0 } else { (PI * x).sin() / (PI * x) };
        let w = 0.5 + 0.5 * u / self.half_width; // 0..1 across the window
        let blackman = 0.42 - 0.5 * (2.0 * PI * w).cos() + 0.08 * (4.0 * PI * w).cos();
        2.0 * self.cutoff * sinc * blackman
    }

    /// The taps of the instant `pos` (a fractional input index) in a record of `n_in`
    /// samples, their weights appended to `weights` (from `known` when its phase was seen).
    fn taps(&self, n_in: usize, pos: f64, weights: &mut Vec<f64>, known: &mut KnownPhases) -> Taps {
        let first = (pos - self.half_width).ceil().max(0.0) as usize;
        let last = ((pos + self.half_width).floor() as usize).min(n_in.saturating_sub(1));
        let offset = weights.len();
        let count = (last + 1).saturating_sub(first);
        // Past the first half window (`first > 0`: `pos` > `half_width`), every `pos - j` of
        // the taps is exact in f64, so the weights depend only on `pos - first` and the count.
        let phase = (first > 0).then(|| ((pos - first as f64).to_bits(), count));
        if let Some(&(at, weight_sum)) = phase.as_ref().and_then(|p| known.index.get(p)) {
            weights.extend_from_slice(&known.weights[at..at + count]);
            return Taps { pos, first, offset, len: count, weight_sum };
        }
        let mut weight_sum = 0.0;
        for j in first..=last {
            let w = self.weight(pos - j as f64);
            weights.push(w);
            weight_sum += w;
        }
        if let Some(phase) = phase.filter(|_| known.index.len() < MAX_KNOWN_PHASES) {
            known.index.insert(phase, (known.weights.len(), weight_sum));
            known.weights.extend_from_slice(&weights[offset..]);
        }
        Taps { pos, first, offset, len: count, weight_sum }
    }

    /// `x` at the instant of `taps`. The weights are normalised to sum to one, so that a
    /// constant stays constant up to the record's ends, where the window is cut.
    fn apply(taps: &Taps, weights: &[f64], x: &[f64]) -> f64 {
        let mut sum = 0.0;
        for (w, v) in weights[taps.offset..taps.offset + taps.len].iter().zip(&x[taps.first..]) {
            sum += w * v;
        }
        if taps.weight_sum != 0.0 {
            sum / taps.weight_sum
        } else {
            x.get(taps.pos.round() as usize).copied().unwrap_or(0.0)
        }
    }

    /// Every column (each as long as the first) at the instants `k / to_hz`, `k < n_out`.
    fn resample_columns(&self, columns: &[&[f64]], n_out: usize, from_hz: f64, to_hz: f64) -> Vec<Vec<f64>> {
        let n_in = columns.first().map_or(0, |c| c.len());
        if columns.iter().any(|c| c.len() != n_in) {
            // Not from a dataset file (its rows give every column the same length): each
            // column with taps of its own length.
            return columns.iter().flat_map(|c| self.resample_columns(&[c], n_out, from_hz, to_hz)).collect();
        }
        let mut out: Vec<Vec<f64>> = columns.iter().map(|_| Vec::with_capacity(n_out)).collect();
        let (mut block, mut weights) = (Vec::with_capacity(BLOCK_INSTANTS), Vec::new());
        let mut known = KnownPhases::default();
        for start in (0..n_out).step_by(BLOCK_INSTANTS) {
            block.clear();
            weights.clear();
            for k in start..(start + BLOCK_INSTANTS).min(n_out) {
                block.push(self.taps(n_in, k as f64 * from_hz / to_hz, &mut weights, &mut known));
            }
            for (x, y) in columns.iter().zip(&mut out) {
                y.extend(block.iter().map(|taps| Self::apply(taps, &weights, x)));
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sts_dataset::{GroupInfo, Manifest};

    fn dataset(rate_hz: f64, seconds: f64, f: impl Fn(f64) -> f64) -> Dataset {
        let n = (seconds * rate_hz) as usize;
        let mut g = GroupData::with_len(n);
        for k in 0..n {
            let t = k as f64 / rate_hz;
            g.t_s[k] = t;
            g.z_cmd_um[k] = f(t);
            g.z_enc_um[k] = f(t);
            g.z_tcp_um[k] = f(t);
            g.acc_mps2[k] = f(t);
        }
        g.spindle_deg = Some((0..n).map(|k| (k as f64 / rate_hz * 3000.0).rem_euclid(360.0)).collect());
        Dataset {
            manifest: Manifest {
                format: "sts-twin-dataset/1".into(),
                sample_rate_hz: rate_hz,
                description: String::new(),
                acc_mps2_per_lsb: None,
                groups: vec![GroupInfo::new("g.csv", 40.0, 5.0, 0.0)],
            },
            groups: vec![g],
        }
    }

    #[test]
    fn a_sine_at_another_rate_lands_on_the_servo_rates_instants() {
        let sine = |t: f64| 5.0 * (2.0 * PI * 40.0 * t + 0.3).sin() + 1.0 * (2.0 * PI * 1234.0 * t).sin();
        for rate_hz in [10_000.0, 20_000.0, 5_000.0, 12_345.6] {
            let recorded = dataset(rate_hz, 1.0, sine);
            let d = to_servo_rate(&recorded);
            let g = &d.groups[0];
            assert_eq!(d.manifest.sample_rate_hz, f64::from(SERVO_RATE_HZ));
            assert!((g.t_s[1] - 1.0 / 8000.0).abs() < 1e-15);
            // Away from the record's ends (the window cut there), within 1e-4 of the signal.
            let worst = (100..g.len() - 100).map(|k| (g.z_tcp_um[k] - sine(g.t_s[k])).abs()).fold(0.0, f64::max);
            assert!(worst < 1e-4, "{rate_hz} Hz: worst error {worst}");
            // The spindle's angle stays in [0, 360) and follows its 3000 deg/s.
            let s = g.spindle_deg.as_ref().unwrap();
            assert!(s.iter().all(|a| (0.0..360.0).contains(a)));
            assert!((s[4000] - (4000.0 / 8000.0 * 3000.0f64).rem_euclid(360.0)).abs() < 1e-4, "{}", s[4000]);
        }
    }

    #[test]
    fn downsampling_removes_what_the_servo_rate_cannot_carry() {
        // 5 kHz at 20 kHz would alias to 3 kHz at 8 kHz; it is filtered out instead.
        let d = resample(&dataset(20_000.0, 1.0, |t| (2.0 * PI * 5000.0 * t).sin()), f64::from(SERVO_RATE_HZ));
        let g = &d.groups[0];
        let rms = ((200..g.len() - 200).map(|k| g.acc_mps2[k].powi(2)).sum::<f64>() / (g.len() - 400) as f64).sqrt();
        assert!(rms < 1e-3, "aliased RMS {rms}");
    }

    /// The kernel applied one output sample and one column at a time, as it was before the
    /// weights were shared between the columns: the reference for bit-identity.
    fn at_one_by_one(kernel: &Kernel, x: &[f64], pos: f64) -> f64 {
        let first = (pos - kernel.half_width).ceil().max(0.0) as usize;
        let last = ((pos + kernel.half_width).floor() as usize).min(x.len().saturating_sub(1));
        let (mut sum, mut weights) = (0.0, 0.0);
        for (j, &v) in x.iter().enumerate().take(last + 1).skip(first) {
            let w = kernel.weight(pos - j as f64);
            sum += w * v;
            weights += w;
        }
        if weights != 0.0 {
            sum / weights
        } else {
            x.get(pos.round() as usize).copied().unwrap_or(0.0)
        }
    }

    #[test]
    fn shared_weights_give_the_one_by_one_kernels_bits() {
        let signal = |t: f64| 3.0 * (2.0 * PI * 37.0 * t).sin() + 0.2 * (2.0 * PI * 2900.0 * t + 1.0).cos() + t;
        for (from_hz, to_hz, seconds) in [(10_000.0, 8000.0, 0.3), (12_345.6, 8000.0, 0.25), (5_000.0, 8000.0, 0.3)] {
            let mut recorded = dataset(from_hz, seconds, signal);
            // Columns of their own (and an unequal length: not from a file, but allowed).
            let g = &mut recorded.groups[0];
            g.temp_c = Some(g.t_s.iter().map(|t| 20.0 + t).collect());
            g.x_mm = Some(g.t_s.iter().take(g.len() - 7).map(|t| t * t).collect());
            let source = recorded.groups[0].clone();
            let d = resample(&recorded, to_hz);
            let g = &d.groups[0];
            let kernel = Kernel::new(from_hz, to_hz);
            let pos = |k: usize| k as f64 * from_hz / to_hz;
            let columns = [
                (&source.z_cmd_um, &g.z_cmd_um),
                (&source.acc_mps2, &g.acc_mps2),
                (source.temp_c.as_ref().unwrap(), g.temp_c.as_ref().unwrap()),
                (source.x_mm.as_ref().unwrap(), g.x_mm.as_ref().unwrap()),
            ];
            for (i, (x, y)) in columns.into_iter().enumerate() {
                assert_eq!(y.len(), g.len(), "{from_hz} Hz, column {i}");
                for (k, &v) in y.iter().enumerate() {
                    assert_eq!(
                        v.to_bits(),
                        at_one_by_one(&kernel, x, pos(k)).to_bits(),
                        "{from_hz} Hz, column {i}, sample {k}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_dataset_at_the_servo_rate_is_not_copied() {
        let d = dataset(f64::from(SERVO_RATE_HZ), 0.1, |t| t);
        assert!(matches!(to_servo_rate(&d), Cow::Borrowed(_)));
    }
}
