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

/// Periodic Hann window `w_j = 0.5 (1 - cos(2 pi j / len)) = sin^2(pi j / len)` in Q30,
/// the sine linearly interpolated in the table (error < 3e-7). One division per window,
/// none per weight.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Hann {
    /// Table position step per sample, `2^31 / len` with 20 extra fraction bits.
    step: u64,
}

impl Hann {
    pub(crate) fn new(len: usize) -> Self {
        Self { step: (1u64 << 51) / len.max(1) as u64 }
    }

    /// The weight of sample `j < len`.
    #[inline]
    pub(crate) fn weight_q30(&self, j: usize) -> i64 {
        // Position of the angle pi j / len on the 4096-step circle, 20 fraction bits.
        let pos = (j as u64 * self.step) >> 20;
        let idx = (pos >> 20) as usize;
        let frac = (pos & 0xf_ffff) as i64;
        let s0 = sin_idx(idx) as i64;
        let s1 = sin_idx(idx + 1) as i64;
        let s = s0 + (((s1 - s0) * frac) >> 20);
        (s * s) >> 30
    }
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

/// In-place forward complex FFT (`e^{-i...}`) of `re`/`im` (same length, a power of two,
/// at most `MAX_FFT_LEN / 2`). Block floating point: before each stage whose inputs reach
/// 2^29 in magnitude, all values are halved (or quartered from 2^30) with rounding, so that
/// the butterfly outputs stay below 2^29 (1 + sqrt 2) < 2^31 and fit i32. Returns the total
/// right shift. Deterministic integer arithmetic.
pub(crate) fn fft_bfp(re: &mut [i32], im: &mut [i32]) -> u32 {
    let n = re.len().min(im.len());
    let (re, im) = (&mut re[..n], &mut im[..n]);
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
    // OR of all magnitudes: its top bit is the top bit of the largest one.
    let mut magnitude_bits = re.iter().chain(im.iter()).fold(0u32, |acc, v| acc | v.unsigned_abs());
    let mut half = 1;
    while half < n {
        let shift = if magnitude_bits >= 1 << 30 {
            2
        } else if magnitude_bits >= 1 << 29 {
            1
        } else {
            0
        };
        if shift > 0 {
            for v in re.iter_mut().chain(im.iter_mut()) {
                *v = (*v + (1 << (shift - 1))) >> shift;
            }
            total_shift += shift;
        }
        let span = half * 2;
        let step = CIRCLE / span;
        let mut bits = 0u32;
        for k in 0..half {
            let c = cos_idx(k * step) as i64;
            let s = sin_idx(k * step) as i64;
            let mut a = k;
            while a + half < n {
                let b = a + half;
                let (br, bi) = (re[b] as i64, im[b] as i64);
                // (br + i bi)(c - i s): |t| < 2^29 sqrt 2, so the sums below fit i32.
                let tr = ((br * c + bi * s + (1 << 29)) >> 30) as i32;
                let ti = ((bi * c - br * s + (1 << 29)) >> 30) as i32;
                let (ar, ai) = (re[a], im[a]);
                let (xr, xi, yr, yi) = (ar + tr, ai + ti, ar - tr, ai - ti);
                re[a] = xr;
                im[a] = xi;
                re[b] = yr;
                im[b] = yi;
                bits |= xr.unsigned_abs() | xi.unsigned_abs() | yr.unsigned_abs() | yi.unsigned_abs();
                a += span;
            }
        }
        magnitude_bits = bits;
        half = span;
    }
    total_shift
}

/// The lower median (`(len - 1) / 2`-th smallest) of `values`, reordering them. Quickselect
/// with a median-of-three pivot; after 2 log2(len) rounds (adversarial orders only) it
/// hands over to `core`'s worst-case linear selection. The value does not depend on the
/// algorithm, so results stay deterministic.
pub(crate) fn lower_median(values: &mut [u64]) -> u64 {
    if values.is_empty() {
        return 0;
    }
    let rank = (values.len() - 1) / 2;
    let (mut lo, mut hi) = (0, values.len() - 1); // inclusive range holding `rank`
    let mut rounds = 2 * (usize::BITS - values.len().leading_zeros());
    while lo < hi {
        if rounds == 0 {
            let (_, m, _) = values[lo..=hi].select_nth_unstable(rank - lo);
            return *m;
        }
        rounds -= 1;
        let mid = lo + (hi - lo) / 2;
        // Median of three as pivot, moved to `hi`.
        let (x, y, z) = (values[lo], values[mid], values[hi]);
        let p = if (x <= y) == (y <= z) {
            mid
        } else if (y <= x) == (x <= z) {
            lo
        } else {
            hi
        };
        values.swap(p, hi);
        let pivot = values[hi];
        // Lomuto partition: [lo, store) < pivot <= [store, hi).
        let mut store = lo;
        for i in lo..hi {
            if values[i] < pivot {
                values.swap(i, store);
                store += 1;
            }
        }
        values.swap(store, hi);
        if rank == store {
            return pivot;
        }
        if rank < store {
            hi = store - 1;
        } else {
            lo = store + 1;
        }
    }
    values[rank]
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
