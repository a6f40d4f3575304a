//! f64 reference implementations of the features, a test oracle (included by the feature
//! tests and the accuracy bench with `#[path]`), written independently of the fixed-point
//! code from the definitions in `sts_twin_core::features`: two-pass central moments, the
//! spectrum by `rustfft` (a complex FFT of the full zero-padded length, in f64, independent
//! of the firmware's own fixed-point FFT) and natural logarithms. Tests compare the
//! fixed-point features against these.
#![allow(dead_code)]

use rustfft::num_complex::Complex;
use rustfft::FftPlannerScalar;
use std::f64::consts::PI;
use sts_twin_core::features::{
    FeatureConfig, FeatureError, BLOCK_SAMPLES, DISTINCT_POWER_GAIN, FEATURE_COUNT, MAX_WINDOW_SAMPLES,
    NOISE_FLOOR_FACTOR,
};

/// The reference features plus the intermediate spectrum, for diagnosing differences.
#[derive(Clone, Debug, PartialEq)]
pub struct ReferenceFeatures {
    /// f1..f12 by index, as in `Features::as_array`.
    pub values: [f64; FEATURE_COUNT],
    /// Power `|X_k|^2` for `k = 0 ..= M/2` of the windowed decimated signal (empty if the
    /// spectrum was not computed); arbitrary common scale.
    pub power: Vec<f64>,
    /// The bin of the dominant-frequency peak (0 if none).
    pub peak_bin: usize,
    /// Width of one bin in Hz.
    pub bin_hz: f64,
}

/// The 12 features, in f64, of the window that ends with the last of `codes` (the codes
/// pushed since configuration, oldest first).
pub fn features_f64(codes: &[i16], cfg: &FeatureConfig) -> Result<[f64; FEATURE_COUNT], FeatureError> {
    Ok(features_f64_detail(codes, cfg)?.values)
}

/// As [`features_f64`], with the spectrum.
pub fn features_f64_detail(codes: &[i16], cfg: &FeatureConfig) -> Result<ReferenceFeatures, FeatureError> {
    cfg.validate(MAX_WINDOW_SAMPLES)?;
    let scale = cfg.acc_mps2_per_lsb as f64;
    let window = cfg.window_samples as usize;
    let t = codes.len();
    let n = t.min(window);
    let win = &codes[t - n..];
    let mut values = [0.0f64; FEATURE_COUNT];

    // Blocks overlapping the window (complete ones) and the partial block.
    let complete = t / BLOCK_SAMPLES;
    let nd = complete.min(window / BLOCK_SAMPLES);
    let block_start = (complete - nd) * BLOCK_SAMPLES;

    if n >= 2 {
        let mean = win.iter().map(|&x| x as i64).sum::<i64>() as f64 / n as f64;
        let moment = |k: i32| win.iter().map(|&x| (x as f64 - mean).powi(k)).sum::<f64>() / n as f64;
        let (m2, m3, m4) = (moment(2), moment(3), moment(4));
        let rms = m2.sqrt();
        let mean_abs = mean_abs_tracked(codes, window);
        let peak = codes[block_start..].iter().map(|&x| (x as f64 - mean).abs()).fold(0.0, f64::max);
        let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { 0.0 };
        values[1] = mean_abs * scale;
        values[2] = m2 * scale * scale;
        values[3] = peak * scale;
        values[4] = rms * scale;
        values[5] = ratio(m4, m2 * m2);
        values[6] = ratio(m3, m2.powf(1.5));
        values[7] = ratio(peak, rms);
        values[8] = ratio(peak, mean_abs);
        values[9] = ratio(rms, mean_abs);
    }

    let m = cfg.fft_len();
    let bin_hz = cfg.sample_rate_hz as f64 / (BLOCK_SAMPLES * m) as f64;
    let mut power = Vec::new();
    let mut peak_bin = 0;
    if nd >= 2 {
        let y: Vec<f64> = codes[block_start..block_start + nd * BLOCK_SAMPLES]
            .chunks(BLOCK_SAMPLES)
            .map(|b| b.iter().map(|&x| x as f64).sum())
            .collect();
        let mean_y = y.iter().sum::<f64>() / nd as f64;
        let var_y = y.iter().map(|v| (v - mean_y).powi(2)).sum::<f64>() / nd as f64;
        values[11] = var_y / 256.0 * scale * scale;
        if nd >= 4 && var_y > 0.0 {
            let mut x = vec![Complex::new(0.0, 0.0); m];
            for (j, v) in y.iter().enumerate() {
                let w = 0.5 * (1.0 - (2.0 * PI * j as f64 / nd as f64).cos());
                x[j].re = (v - mean_y) * w;
            }
            // Forward (`e^{-i...}`), unnormalised: the power's scale is arbitrary anyway. The
            // scalar planner: an oracle needs no SIMD, and the SIMD one took 20 s to compile
            // in each test binary.
            FftPlannerScalar::new().plan_fft_forward(m).process(&mut x);
            power = x[..=m / 2].iter().map(|c| c.norm_sqr()).collect();
            let (f1, k) = dominant_bins(&power);
            peak_bin = k;
            values[0] = f1 * bin_hz;
            values[10] = centroid_bins(&power) * bin_hz;
        }
    }
    Ok(ReferenceFeatures { values, power, peak_bin, bin_hz })
}

/// Mean of `|x_i - d_i|` over the window, `d_i` the DC reference of sample i's block: the
/// window mean at the block's start, truncated toward zero to 1/256 LSB (the block's first
/// code for the first block).
fn mean_abs_tracked(codes: &[i16], window: usize) -> f64 {
    let t = codes.len();
    let n = t.min(window);
    let mut prefix = vec![0i64; t + 1];
    for (i, &x) in codes.iter().enumerate() {
        prefix[i + 1] = prefix[i] + x as i64;
    }
    let mut sum_abs = 0.0;
    let mut d = 0.0;
    for (i, &x) in codes.iter().enumerate() {
        if i % BLOCK_SAMPLES == 0 {
            let filled = i.min(window);
            let s1 = prefix[i] - prefix[i - filled];
            d = if filled == 0 { x as f64 } else { (256 * s1 / filled as i64) as f64 / 256.0 };
        }
        if i >= t - n {
            sum_abs += (x as f64 - d).abs();
        }
    }
    sum_abs / n as f64
}

/// Dominant frequency in bins: first largest `P_k`, `k = 1 ..= M/2`, refined by a parabola
/// through the log powers (floored at `2^-40` of the peak). Returns (bins, peak bin).
fn dominant_bins(power: &[f64]) -> (f64, usize) {
    let half = power.len() - 1;
    let mut k = 1;
    for i in 1..=half {
        if power[i] > power[k] {
            k = i;
        }
    }
    let b = power[k];
    let floor = b * 2f64.powi(-40);
    let a = power[k - 1].max(floor);
    let c = if k == half { power[half - 1] } else { power[k + 1] }.max(floor);
    let (la, lb, lc) = (a.ln(), b.max(floor).ln(), c.ln());
    let den = la - 2.0 * lb + lc;
    let delta = if den < 0.0 { 0.5 * (la - lc) / den } else { 0.0 };
    (k as f64 + delta.clamp(-0.5, 0.5), k)
}

/// Mean frequency in bins: blend of the centroid of `max(P_k - T, 0)` (`T` = factor times
/// the lower median of `P_1 ..= P_{M/2}`) and the plain centroid, by the fraction of the
/// power above `T`; one-sided weights.
fn centroid_bins(power: &[f64]) -> f64 {
    let half = power.len() - 1;
    let mut sorted: Vec<f64> = power[1..].to_vec();
    sorted.sort_by(f64::total_cmp);
    let floor = NOISE_FLOOR_FACTOR as f64 * sorted[(half - 1) / 2];
    let (mut num_e, mut den_e, mut num_p, mut den_p) = (0.0, 0.0, 0.0, 0.0);
    for (k, &p) in power.iter().enumerate().skip(1) {
        let w = if k == half { 1.0 } else { 2.0 };
        let e = (p - floor).max(0.0);
        num_e += w * k as f64 * e;
        den_e += w * e;
        num_p += w * k as f64 * p;
        den_p += w * p;
    }
    if den_p == 0.0 {
        return 0.0;
    }
    let distinct = if den_e > 0.0 { num_e / den_e } else { 0.0 };
    let alpha = (den_e / den_p * DISTINCT_POWER_GAIN as f64).min(1.0);
    alpha * distinct + (1.0 - alpha) * num_p / den_p
}
