//! Read-time assembly of the time-domain features from exact integer sums.

use super::{
    Capture, CREST_FACTOR, IMPULSE_FACTOR, KURTOSIS, MEAN_ABS_MPS2, PEAK_MPS2, RMS_MPS2, SHAPE_FACTOR, SKEWNESS,
    VARIANCE_M2PS4,
};

/// Correctly rounded square root of an f32, in integer arithmetic.
///
/// `core` has no `f32::sqrt` without `std`; this one matches IEEE 754 `sqrt` bit for bit
/// (tested against `std` over many values), so results are identical on every target.
/// Negative inputs and NaN give NaN, `+inf` gives `+inf`, `-0.0` gives `-0.0`.
pub fn sqrt_f32(x: f32) -> f32 {
    if x.is_nan() || x < 0.0 {
        return f32::NAN;
    }
    if x == 0.0 || x.is_infinite() {
        return x;
    }
    let bits = x.to_bits();
    let exp_field = ((bits >> 23) & 0xff) as i32;
    // x = m * 2^e with m an integer.
    let (mut m, mut e) = if exp_field == 0 {
        (bits as u64 & 0x7f_ffff, -149)
    } else {
        ((bits as u64 & 0x7f_ffff) | 0x80_0000, exp_field - 150)
    };
    // Normalise m to [2^23, 2^24) (subnormals), then make e even.
    while m < (1 << 23) {
        m <<= 1;
        e -= 1;
    }
    if e & 1 != 0 {
        m <<= 1;
        e -= 1;
    }
    // sqrt(m * 2^28) = sqrt(m) * 2^14 has 26 or 27 bits: two guard bits beyond f32's 24,
    // plus a sticky bit from the remainder, so one rounding to nearest is exact.
    let scaled = m << 28;
    let root = scaled.isqrt();
    let sticky = (root * root != scaled) as u64;
    let odd = (root << 1) | sticky;
    // result = odd * 2^(e/2 - 15); the power of two is within f32 range for all inputs.
    let pow = e / 2 - 15;
    let value = odd as f32; // correctly rounded, ties-to-even with the sticky bit
    value * pow2_f32(pow)
}

/// 2^p as an f32 for p in -126..=127 (exact).
fn pow2_f32(p: i32) -> f32 {
    // sqrt results lie within 2^-75 .. 2^64, so p stays within normal range here; split
    // large magnitudes to stay exact anyway.
    if p < -126 {
        return pow2_f32(p + 126) * f32::from_bits(1 << 23);
    }
    if p > 127 {
        return pow2_f32(p - 127) * f32::from_bits(254 << 23);
    }
    f32::from_bits(((p + 127) as u32) << 23)
}

/// Central-moment numerators from exact power sums over `n` samples:
/// `c2 = n^2 m2`, `c3 = n^3 m3`, `c4 = n^4 m4`.
///
/// All true values fit i128 for `n <= 65,536` (`n^4 m4 <= 2^64 * 2^64 / 12`), but some
/// intermediate products of the expansion do not, so the expansion is evaluated with
/// wrapping arithmetic: exact modulo 2^128, hence exact.
pub(crate) fn central_numerators(n: i128, s1: i128, s2: i128, s3: i128, s4: i128) -> (i128, i128, i128) {
    let s1_2 = s1.wrapping_mul(s1);
    let c2 = n * s2 - s1_2;
    let c3 = (n * n * s3) - 3 * n * s1 * s2 + 2 * s1_2 * s1;
    let c4 = n
        .wrapping_mul(n)
        .wrapping_mul(n)
        .wrapping_mul(s4)
        .wrapping_sub(4i128.wrapping_mul(n).wrapping_mul(n).wrapping_mul(s1).wrapping_mul(s3))
        .wrapping_add(6i128.wrapping_mul(n).wrapping_mul(s1_2).wrapping_mul(s2))
        .wrapping_sub(3i128.wrapping_mul(s1_2).wrapping_mul(s1_2));
    (c2, c3, c4)
}

/// Block extremes over the peak window, in codes.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Extremes {
    pub max: i16,
    pub min: i16,
}

/// Fills the time-domain features (f2..f10) of `out` from `cap` and the peak-window extremes.
pub(crate) fn time_domain(cap: &Capture, ext: Option<Extremes>, out: &mut [f32; super::FEATURE_COUNT]) {
    let n = cap.samples;
    if n < 2 {
        return;
    }
    let scale = cap.cfg.acc_mps2_per_lsb;
    let nf = n as f32; // exact: n <= 65,536
    let (c2, c3, c4) = central_numerators(n as i128, cap.s1 as i128, cap.s2 as i128, cap.s3 as i128, cap.s4);

    // Mean |x - d| in codes; n * 256 <= 2^24 is exact in f32.
    let mean_abs = cap.sum_abs_q8 as f32 / (n * 256) as f32;
    // Peak about the mean: n * peak = max(n max - S1, S1 - n min), exact in i64.
    let peak = match ext {
        Some(e) => {
            let s1 = cap.s1 as i64;
            let hi = n as i64 * e.max as i64 - s1;
            let lo = s1 - n as i64 * e.min as i64;
            hi.max(lo).max(0) as f32 / nf
        }
        None => 0.0,
    };
    let (variance, rms, skew, kurt) = if c2 > 0 {
        let c2f = c2 as f32;
        let root = sqrt_f32(c2f);
        let variance = c2f / ((n as u64 * n as u64) as f32);
        let rms = root / nf;
        let skew = (c3 as f32 / c2f) / root;
        let kurt = (c4 as f32 / c2f) / c2f;
        (variance, rms, skew, kurt)
    } else {
        (0.0, 0.0, 0.0, 0.0)
    };
    let ratio = |num: f32, den: f32| if den > 0.0 { num / den } else { 0.0 };

    out[MEAN_ABS_MPS2] = mean_abs * scale;
    out[VARIANCE_M2PS4] = variance * (scale * scale);
    out[PEAK_MPS2] = peak * scale;
    out[RMS_MPS2] = rms * scale;
    out[KURTOSIS] = kurt;
    out[SKEWNESS] = skew;
    out[CREST_FACTOR] = ratio(peak, rms);
    out[IMPULSE_FACTOR] = ratio(peak, mean_abs);
    out[SHAPE_FACTOR] = ratio(rms, mean_abs);
}
