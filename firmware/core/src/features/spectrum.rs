//! Read-time spectral features: integer block-floating-point FFT, Hann window, dominant
//! frequency and noise-floor-subtracted spectral centroid.
//!
//! The FFT is written here rather than taken from a crate because no maintained `no_std`
//! fixed-point FFT with bit-exact, documented scaling exists (`microfft` is f32 only and its
//! results depend on the compiler's float code generation; CMSIS-DSP's q31 FFT is C and
//! halves at every stage, losing 11 bits). It is a textbook radix-2 decimation-in-time FFT
//! with per-stage block scaling, plus the standard split step for a real input.

#[cfg(test)]
use fixed::types::I2F30;
use fixed::types::I40F24;

/// log2 of the number of table steps per full circle.
const CIRCLE_LOG2: u32 = 12;
/// Table steps per full circle (angle resolution 2 pi / 4096).
const CIRCLE: usize = 1 << CIRCLE_LOG2;
/// Table steps per quarter circle.
const QUARTER: usize = CIRCLE / 4;
/// Largest real FFT length the table supports exactly.
pub(crate) const MAX_FFT_LEN: usize = CIRCLE;

/// round(pi / 2 * 2^60).
const HALF_PI_Q60: i128 = 1_811_004_864_519_280_711;

/// sin(pi/2 * k / 1024) in Q30 for k = 0..=1024, rounded to nearest, computed at compile
/// time from the Taylor series in Q60 integer arithmetic (error < 1e-17 before rounding).
static SIN_Q30: [i32; QUARTER + 1] = sin_table();

const fn sin_table() -> [i32; QUARTER + 1] {
    let mut table = [0i32; QUARTER + 1];
    let mut k = 0;
    while k <= QUARTER {
        let x = HALF_PI_Q60 * k as i128 / QUARTER as i128;
        let x2 = (x * x) >> 60;
        let mut term = x;
        let mut sum = x;
        let mut i = 1;
        while i < 16 {
            term = -((term * x2) >> 60) / ((2 * i) * (2 * i + 1));
            sum += term;
            i += 1;
        }
        table[k] = ((sum + (1 << 29)) >> 30) as i32;
        k += 1;
    }
    table
}

/// sin(2 pi a / 4096) in Q30.
#[inline]
fn sin_idx(a: usize) -> i32 {
    let a = a % CIRCLE;
    let r = a % QUARTER;
    match a / QUARTER {
        0 => SIN_Q30[r],
        1 => SIN_Q30[QUARTER - r],
        2 => -SIN_Q30[r],
        _ => -SIN_Q30[QUARTER - r],
    }
}

/// cos(2 pi a / 4096) in Q30.
#[inline]
fn cos_idx(a: usize) -> i32 {
    sin_idx(a + QUARTER)
}

/// Twiddle-table value as a `fixed` number (for tests of the Q format).
#[cfg(test)]
pub(crate) fn sin_q30(a: usize) -> I2F30 {
    I2F30::from_bits(sin_idx(a))
}

/// Periodic Hann weight `0.5 (1 - cos(2 pi j / len)) = sin^2(pi j / len)` in Q30, with the
/// sine linearly interpolated in the table (error < 3e-7).
pub(crate) fn hann_q30(j: usize, len: usize) -> i64 {
    if len == 0 {
        return 0;
    }
    // Position on the 4096-step circle of the angle pi j / len, with 20 fraction bits.
    let pos = ((j as u64) << (CIRCLE_LOG2 - 1 + 20)) / len as u64;
    let idx = (pos >> 20) as usize;
    let frac = (pos & 0xf_ffff) as i64;
    let s0 = sin_idx(idx) as i64;
    let s1 = sin_idx(idx + 1) as i64;
    let s = s0 + (((s1 - s0) * frac) >> 20);
    (s * s) >> 30
}

/// Shift right by `sh` with rounding half up (`sh` may be 0).
#[inline]
fn round_shr(v: i64, sh: u32) -> i64 {
    if sh == 0 {
        v
    } else {
        (v + (1i64 << (sh - 1))) >> sh
    }
}

/// In-place forward complex FFT (`e^{-i...}`) of `re`/`im` (length a power of two, at most
/// `MAX_FFT_LEN / 2`), inputs below 2^29 in magnitude. Each stage scales by 1, 1/2 or 1/4
/// so that no component reaches 2^31 (butterfly growth is at most 1 + sqrt 2); returns the
/// total right shift. Deterministic integer arithmetic with rounding shifts.
pub(crate) fn fft_bfp(re: &mut [i32], im: &mut [i32]) -> u32 {
    let n = re.len().min(im.len());
    if n < 2 {
        return 0;
    }
    let log2n = n.trailing_zeros();
    // Bit-reversal permutation.
    for i in 0..n {
        let j = i.reverse_bits() >> (usize::BITS - log2n);
        if j > i {
            re.swap(i, j);
            im.swap(i, j);
        }
    }
    let mut total_shift = 0;
    let mut max_abs = max_abs2(re, im);
    let mut half = 1;
    while half < n {
        let span = half * 2;
        let shift = if max_abs >= 1 << 30 {
            2
        } else if max_abs >= 1 << 29 {
            1
        } else {
            0
        };
        total_shift += shift;
        let step = CIRCLE / span;
        let mut new_max = 0u32;
        let mut start = 0;
        while start < n {
            for k in 0..half {
                let c = cos_idx(k * step) as i64;
                let s = sin_idx(k * step) as i64;
                let a = start + k;
                let b = a + half;
                let (br, bi) = (re[b] as i64, im[b] as i64);
                // (br + i bi)(c - i s)
                let tr = round_shr(br * c + bi * s, 30);
                let ti = round_shr(bi * c - br * s, 30);
                let (ar, ai) = (re[a] as i64, im[a] as i64);
                let (xr, xi) = (round_shr(ar + tr, shift), round_shr(ai + ti, shift));
                let (yr, yi) = (round_shr(ar - tr, shift), round_shr(ai - ti, shift));
                re[a] = xr as i32;
                im[a] = xi as i32;
                re[b] = yr as i32;
                im[b] = yi as i32;
                new_max = new_max
                    .max(xr.unsigned_abs() as u32)
                    .max(xi.unsigned_abs() as u32)
                    .max(yr.unsigned_abs() as u32)
                    .max(yi.unsigned_abs() as u32);
            }
            start += span;
        }
        max_abs = new_max;
        half = span;
    }
    total_shift
}

fn max_abs2(re: &[i32], im: &[i32]) -> u32 {
    re.iter().chain(im.iter()).map(|v| v.unsigned_abs()).max().unwrap_or(0)
}

/// Power of real-FFT bin `k` (0 ..= h) of a length-2h real signal from the length-h complex
/// FFT `z` of its even/odd packing, scaled by 1/64 (so that it fits u64).
#[inline]
pub(crate) fn real_bin_power(re: &[i32], im: &[i32], k: usize) -> u64 {
    let h = re.len();
    let kk = k % h;
    let mk = (h - kk) % h;
    let (zr, zi) = (re[kk] as i64, im[kk] as i64);
    let (wr, wi) = (re[mk] as i64, im[mk] as i64);
    // 2 E = Z_k + conj(Z_{h-k}), 2 O = (Z_k - conj(Z_{h-k})) / i, X_k = E + W^k O.
    let (ar, ai) = (zr + wr, zi - wi);
    let (br, bi) = (zi + wi, wr - zr);
    // W^k = e^{-i 2 pi k / 2h}: the table angle index is k * 4096 / 2h.
    let a = k * (CIRCLE / (2 * h));
    let (c, s) = (cos_idx(a) as i64, sin_idx(a) as i64);
    // |Z| < 2^30.8, so |2X| < 2^32.8; shift 2 keeps |2X / 4|^2 < 2^61.6.
    let xr = round_shr(ar + round_shr(br * c + bi * s, 30), 2);
    let xi = round_shr(ai + round_shr(bi * c - br * s, 30), 2);
    (xr * xr) as u64 + (xi * xi) as u64
}

/// log2(p) in Q40.24 for p > 0 (p = 0 is treated as 1), by bit-wise squaring of the
/// normalised mantissa: exact to within 2^-23.
pub(crate) fn log2_q24(p: u64) -> I40F24 {
    let p = p.max(1);
    let lz = p.leading_zeros();
    let int = 63 - lz as i64;
    // Mantissa in Q62: [1, 2) -> [2^62, 2^63).
    let mut m = (p << lz) >> 1;
    let mut frac = 0i64;
    for _ in 0..24 {
        let sq = ((m as u128 * m as u128) >> 62) as u64; // [1, 4) in Q62
        frac <<= 1;
        if sq >= 1 << 63 {
            frac |= 1;
            m = sq >> 1;
        } else {
            m = sq;
        }
    }
    I40F24::from_bits((int << 24) | frac)
}

/// Dominant frequency in bins from the powers around the peak bin `k`:
/// `k + 0.5 (a - c) / (a - 2b + c)` on log2 power, clamped to +-0.5 bin.
pub(crate) fn refine_peak(k: usize, a: u64, b: u64, c: u64) -> f32 {
    let floor = (b >> 40).max(1);
    let la = log2_q24(a.max(floor)).to_bits();
    let lb = log2_q24(b.max(floor)).to_bits();
    let lc = log2_q24(c.max(floor)).to_bits();
    let den = la - 2 * lb + lc;
    let delta = if den < 0 { (la - lc) as f32 / (2 * den) as f32 } else { 0.0 };
    k as f32 + delta.clamp(-0.5, 0.5)
}
