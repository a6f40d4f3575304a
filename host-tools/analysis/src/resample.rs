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

use std::borrow::Cow;
use std::f64::consts::PI;

use sts_dataset::{Dataset, GroupData};

/// The co-processor's servo rate, Hz.
pub const SERVO_RATE_HZ: f64 = sts_twin_core::SERVO_RATE_HZ as f64;

/// Zero crossings of the sinc on each side of an output instant (at the cut-off).
const HALF_WIDTH_CROSSINGS: f64 = 32.0;
/// Cut-off as a fraction of the lower Nyquist frequency (room for the window's transition).
const CUTOFF_FRACTION: f64 = 0.95;

/// `dataset` at the servo rate: borrowed when it is at that rate already.
pub fn to_servo_rate(dataset: &Dataset) -> Cow<'_, Dataset> {
    if dataset.manifest.sample_rate_hz == SERVO_RATE_HZ {
        Cow::Borrowed(dataset)
    } else {
        Cow::Owned(resample(dataset, SERVO_RATE_HZ))
    }
}

/// `dataset` resampled to `rate_hz` (every column; `t_s` becomes `k / rate_hz`).
pub fn resample(dataset: &Dataset, rate_hz: f64) -> Dataset {
    let mut manifest = dataset.manifest.clone();
    let from_hz = manifest.sample_rate_hz;
    manifest.sample_rate_hz = rate_hz;
    let groups = dataset.groups.iter().map(|g| resample_group(g, from_hz, rate_hz)).collect();
    Dataset { manifest, groups }
}

fn resample_group(group: &GroupData, from_hz: f64, to_hz: f64) -> GroupData {
    let n_in = group.len();
    // The output covers the input's span: instants k / to_hz up to the last input sample.
    let n_out = if n_in == 0 { 0 } else { ((n_in - 1) as f64 * to_hz / from_hz).floor() as usize + 1 };
    let kernel = Kernel::new(from_hz, to_hz);
    let column = |x: &[f64]| (0..n_out).map(|k| kernel.at(x, k as f64 * from_hz / to_hz)).collect::<Vec<f64>>();
    GroupData {
        t_s: (0..n_out).map(|k| k as f64 / to_hz).collect(),
        z_cmd_um: column(&group.z_cmd_um),
        z_enc_um: column(&group.z_enc_um),
        z_tcp_um: column(&group.z_tcp_um),
        acc_mps2: column(&group.acc_mps2),
        x_mm: group.x_mm.as_deref().map(column),
        x_acc_mps2: group.x_acc_mps2.as_deref().map(column),
        spindle_deg: group.spindle_deg.as_deref().map(|x| resample_angle_deg(x, &kernel, n_out, from_hz, to_hz)),
        temp_c: group.temp_c.as_deref().map(column),
    }
}

/// An angle that wraps (a spindle's, 0..360 degrees) is unwrapped, resampled and wrapped again.
fn resample_angle_deg(x: &[f64], kernel: &Kernel, n_out: usize, from_hz: f64, to_hz: f64) -> Vec<f64> {
    let mut unwrapped = Vec::with_capacity(x.len());
    let mut turns = 0.0;
    for (i, &deg) in x.iter().enumerate() {
        if i > 0 {
            let step = deg - x[i - 1];
            turns -= (step / 360.0).round();
        }
        unwrapped.push(deg + 360.0 * turns);
    }
    (0..n_out).map(|k| kernel.at(&unwrapped, k as f64 * from_hz / to_hz).rem_euclid(360.0)).collect()
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

    /// `x` at the fractional input index `pos`. The weights are normalised to sum to one, so
    /// that a constant stays constant up to the record's ends, where the window is cut.
    fn at(&self, x: &[f64], pos: f64) -> f64 {
        let first = (pos - self.half_width).ceil().max(0.0) as usize;
        let last = ((pos + self.half_width).floor() as usize).min(x.len().saturating_sub(1));
        let (mut sum, mut weights) = (0.0, 0.0);
        for (j, &v) in x.iter().enumerate().take(last + 1).skip(first) {
            let w = self.weight(pos - j as f64);
            sum += w * v;
            weights += w;
        }
        if weights != 0.0 {
            sum / weights
        } else {
            x.get(pos.round() as usize).copied().unwrap_or(0.0)
        }
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
                groups: vec![GroupInfo { file: "g.csv".into(), freq_hz: 40.0, amp_um: 5.0, start_s: 0.0 }],
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
            assert_eq!(d.manifest.sample_rate_hz, SERVO_RATE_HZ);
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
        let d = resample(&dataset(20_000.0, 1.0, |t| (2.0 * PI * 5000.0 * t).sin()), SERVO_RATE_HZ);
        let g = &d.groups[0];
        let rms = ((200..g.len() - 200).map(|k| g.acc_mps2[k].powi(2)).sum::<f64>() / (g.len() - 400) as f64).sqrt();
        assert!(rms < 1e-3, "aliased RMS {rms}");
    }

    #[test]
    fn a_dataset_at_the_servo_rate_is_not_copied() {
        let d = dataset(SERVO_RATE_HZ, 0.1, |t| t);
        assert!(matches!(to_servo_rate(&d), Cow::Borrowed(_)));
    }
}
