//! Read-time spectral features: integer block-floating-point FFT, Hann window, dominant
//! frequency and noise-floor-subtracted spectral centroid.
//!
//! The FFT is written here rather than taken from a crate because the features must come out
//! bit for bit the same on the firmware and on the host, in `no_std` fixed point, and no
//! maintained `no_std` fixed-point FFT with bit-exact, documented scaling exists (`microfft`
//! is f32 only and its results depend on the compiler's float code generation; CMSIS-DSP's
//! q31 FFT is C and halves at every stage, losing 11 bits). It is a textbook radix-2
//! decimation-in-time FFT with per-stage block scaling, plus the standard split step for a
//! real input. The tests check the features against an f64 reference whose spectrum comes
//! from `rustfft` (`tests/support/reference.rs`), so the oracle shares no code with this one.

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
/// generated in order: the sine is linearly interpolated in the table at a phase that
/// advances by `2048 / len` table steps (Q40) per sample (one division per window, error
/// of the weights below 6e-7).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Hann {
    /// Table position of the next weight, Q40 steps of the 4096-step circle.
    phase: u64,
    /// Position step per sample.
    step: u64,
}

impl Hann {
    pub(crate) fn new(len: usize) -> Self {
        Self { phase: 0, step: (1u64 << 51) / len.max(1) as u64 }
    }
}

impl Iterator for Hann {
    type Item = i32;

    /// The next weight (Q30, at most 2^30); the sequence does not end.
    #[inline]
    fn next(&mut self) -> Option<i32> {
        // Angle pi j / len is within [0, pi): table index 0 ..= 2048, sin >= 0.
        let idx = (self.phase >> 40) as usize;
        let frac = ((self.phase >> 20) & 0xf_ffff) as i64;
        self.phase += self.step;
        let s0 = half_sin(idx);
        let s1 = half_sin(idx + 1);
        let s = s0 as i64 + (((s1 - s0) as i64 * frac) >> 20);
        Some(((s * s) >> 30) as i32)
    }
}

/// sin(2 pi a / 4096) in Q30 for a in 0 ..= 2048 (the upper half circle), 0 beyond.
#[inline]
fn half_sin(a: usize) -> i32 {
    let r = if a <= QUARTER { a } else { (2 * QUARTER).saturating_sub(a) };
    SIN_Q30[r]
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

/// In-place forward complex FFT (`e^{-i...}`) of `z` (`[re, im]` pairs; length a power of
/// two, at most `MAX_FFT_LEN / 2`). Block floating point: before each stage whose inputs
/// reach 2^29 in magnitude, all values are halved (or quartered from 2^30) with rounding,
/// so that the butterfly outputs stay below 2^29 (1 + sqrt 2) < 2^31 and fit i32. Returns
/// the total right shift. Deterministic integer arithmetic.
pub(crate) fn fft_bfp(z: &mut [[i32; 2]]) -> u32 {
    let n = z.len();
    if n < 2 || !n.is_power_of_two() {
        return 0;
    }
    let log2n = n.trailing_zeros();
    // Bit-reversal permutation.
    for i in 0..n {
        let j = i.reverse_bits() >> (usize::BITS - log2n);
        if j > i {
            z.swap(i, j);
        }
    }
    let mut total_shift = 0;
    // OR of all magnitudes (as v ^ (v >> 31), |v| - 1 for negative v: one instruction); its
    // top bit is that of the largest magnitude, except that -2^29 passes as below 2^29,
    // which the bound below allows for.
    let mag = |v: i32| (v ^ (v >> 31)) as u32;
    let mut magnitude_bits = z.iter().fold(0u32, |acc, [r, i]| acc | mag(*r) | mag(*i));
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
            let round = 1 << (shift - 1);
            for v in z.iter_mut() {
                *v = [(v[0] + round) >> shift, (v[1] + round) >> shift];
            }
            total_shift += shift;
        }
        // Inputs are now at most 2^29 in magnitude: |t| <= 2^29 sqrt 2 + 1 and the sums
        // stay below 2^30.3.
        let span = half * 2;
        let step = CIRCLE / span;
        let mut bits = 0u32;
        for k in 0..half {
            let c = cos_idx(k * step) as i64;
            let s = sin_idx(k * step) as i64;
            let mut a = k;
            while a + half < n {
                let b = a + half;
                let (br, bi) = (z[b][0] as i64, z[b][1] as i64);
                // (br + i bi)(c - i s), rounded from Q30.
                let tr = ((br * c + bi * s + (1 << 29)) >> 30) as i32;
                let ti = ((bi * c - br * s + (1 << 29)) >> 30) as i32;
                let [ar, ai] = z[a];
                let (xr, xi, yr, yi) = (ar + tr, ai + ti, ar - tr, ai - ti);
                z[a] = [xr, xi];
                z[b] = [yr, yi];
                bits |= mag(xr) | mag(xi) | mag(yr) | mag(yi);
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

/// Powers of the real-FFT bins 1 ..= h of a length-2h real signal, from the length-h
/// complex FFT `z` of its even/odd packing, into `out[0 .. h]`; returns the power of bin 0.
/// All are `|X_k|^2 / 4` in the units of `z` (so that they fit u64). Bins k and h - k are computed together:
/// with `E = (Z_k + conj Z_{h-k}) / 2`, `O = (Z_k - conj Z_{h-k}) / 2i` and `W = e^{-i pi k/h}`,
/// `X_k = E + W O` and `X_{h-k} = conj(E - W O)`.
pub(crate) fn real_spectrum_powers(z: &[[i32; 2]], out: &mut [u64]) -> u64 {
    let h = z.len().min(out.len());
    if h < 2 {
        return 0;
    }
    let step = CIRCLE / (2 * h); // table steps per bin
    let mut p0 = 0;
    for k in 0..=h / 2 {
        let mk = (h - k) % h;
        let (zr, zi) = (z[k][0] as i64, z[k][1] as i64);
        let (wr, wi) = (z[mk][0] as i64, z[mk][1] as i64);
        // 2E and 2O.
        let (er, ei) = (zr + wr, zi - wi);
        let (or, oi) = (zi + wi, wr - zr);
        let (c, s) = (cos_idx(k * step) as i64, sin_idx(k * step) as i64);
        // 2 W O = (c - i s)(or + i oi), rounded from Q30.
        let tr = round_shr(or * c + oi * s, 30);
        let ti = round_shr(oi * c - or * s, 30);
        // |Z| < 2^30.8, so |2X| < 2^32.8; shift 2 keeps |2X / 4|^2 < 2^61.6.
        let power = |r: i64, i: i64| {
            let (r, i) = (round_shr(r, 2), round_shr(i, 2));
            (r * r) as u64 + (i * i) as u64
        };
        let plus = power(er + tr, ei + ti);
        let minus = power(er - tr, ei - ti);
        if k == 0 {
            p0 = plus;
            out[h - 1] = minus;
        } else {
            out[k - 1] = plus;
            if mk != k {
                out[mk - 1] = minus;
            }
        }
    }
    p0
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

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec::Vec;

    fn rng(seed: &mut u64) -> u64 {
        *seed ^= *seed << 13;
        *seed ^= *seed >> 7;
        *seed ^= *seed << 17;
        *seed
    }

    #[test]
    fn sine_table_is_correctly_rounded_q30() {
        for a in 0..CIRCLE {
            let exact = (2.0 * core::f64::consts::PI * a as f64 / CIRCLE as f64).sin() * (1u64 << 30) as f64;
            let err = (sin_idx(a) as f64 - exact).abs();
            assert!(err <= 0.5 + 1e-6, "a {a}: {} vs {exact}", sin_idx(a));
            assert_eq!(cos_idx(a), sin_idx(a + QUARTER));
        }
        assert_eq!(sin_q30(QUARTER), I2F30::ONE);
        assert_eq!(sin_idx(0), 0);
    }

    #[test]
    fn hann_weights_match_the_formula() {
        for len in [4usize, 7, 64, 1000, 2500, 4096] {
            let mut hann = Hann::new(len);
            for j in 0..len {
                let w = hann.next().unwrap() as f64 / (1u64 << 30) as f64;
                let exact = 0.5 * (1.0 - (2.0 * core::f64::consts::PI * j as f64 / len as f64).cos());
                assert!((w - exact).abs() < 6e-7, "len {len} j {j}: {w} vs {exact}");
            }
        }
    }

    /// Naive DFT in f64.
    fn dft(re: &[f64], im: &[f64]) -> Vec<(f64, f64)> {
        let n = re.len();
        (0..n)
            .map(|k| {
                let (mut sr, mut si) = (0.0, 0.0);
                for j in 0..n {
                    let a = -2.0 * core::f64::consts::PI * (j * k % n) as f64 / n as f64;
                    sr += re[j] * a.cos() - im[j] * a.sin();
                    si += re[j] * a.sin() + im[j] * a.cos();
                }
                (sr, si)
            })
            .collect()
    }

    #[test]
    fn block_floating_point_fft_matches_dft() {
        let mut seed = 0x1234_5678_9abc_def1u64;
        for n in [2usize, 4, 16, 128, 512] {
            for amplitude_bits in [29u32, 20, 3] {
                let mut z: Vec<[i32; 2]> = (0..n)
                    .map(|_| {
                        let m = (1i64 << amplitude_bits) - 1;
                        let r = (rng(&mut seed) % (2 * m as u64 + 1)) as i64 - m;
                        let i = (rng(&mut seed) % (2 * m as u64 + 1)) as i64 - m;
                        [r as i32, i as i32]
                    })
                    .collect();
                let re: Vec<f64> = z.iter().map(|v| v[0] as f64).collect();
                let im: Vec<f64> = z.iter().map(|v| v[1] as f64).collect();
                let expect = dft(&re, &im);
                let shift = fft_bfp(&mut z);
                let scale = (1u64 << shift) as f64;
                let peak = expect.iter().map(|(r, i)| r.hypot(*i)).fold(0.0, f64::max);
                for (k, ((r, i), got)) in expect.iter().zip(&z).enumerate() {
                    let err = (got[0] as f64 * scale - r).hypot(got[1] as f64 * scale - i);
                    // A few rounding steps per stage, each at most half a unit of the scale.
                    let bound = (n.trailing_zeros() as f64 + 1.0) * 2.0 * scale + 1e-9 * peak;
                    assert!(err <= bound, "n {n} bits {amplitude_bits} k {k}: error {err} > {bound}");
                }
            }
        }
    }

    #[test]
    fn real_split_matches_dft_of_real_signal() {
        let mut seed = 77u64;
        let h = 64;
        let x: Vec<f64> =
            (0..2 * h).map(|_| ((rng(&mut seed) % 2_000_001) as i64 - 1_000_000) as f64 * 256.0).collect();
        let mut z: Vec<[i32; 2]> = (0..h).map(|m| [x[2 * m] as i32, x[2 * m + 1] as i32]).collect();
        let shift = fft_bfp(&mut z);
        let mut out = [0u64; 64];
        let p0 = real_spectrum_powers(&z, &mut out);
        let expect = dft(&x, &vec![0.0; 2 * h]);
        // Powers are |X|^2 / 4 in units of 2^(2 shift).
        let unit = (1u64 << (2 * shift)) as f64 * 4.0;
        let peak = expect.iter().map(|(r, i)| r * r + i * i).fold(0.0, f64::max);
        for k in 0..=h {
            let got = if k == 0 { p0 } else { out[k - 1] } as f64 * unit;
            let (r, i) = expect[k];
            let want = r * r + i * i;
            assert!((got - want).abs() <= 1e-7 * peak + 1e-6 * want, "k {k}: {got:e} vs {want:e}");
        }
    }

    #[test]
    fn log2_is_accurate() {
        let mut seed = 5u64;
        for _ in 0..20_000 {
            let p = rng(&mut seed) >> (rng(&mut seed) % 64);
            let got = log2_q24(p).to_num::<f64>();
            let want = (p.max(1) as f64).log2();
            assert!((got - want).abs() < 2.0 / (1 << 24) as f64, "{p}: {got} vs {want}");
        }
        assert_eq!(log2_q24(1).to_bits(), 0);
        assert_eq!(log2_q24(1 << 40).to_bits(), 40 << 24);
    }

    #[test]
    fn peak_refinement_is_exact_for_a_log_parabola() {
        // log2 P = 40 - 3 (x - 10.3)^2 at x = 9, 10, 11.
        let p = |x: f64| 2f64.powf(40.0 - 3.0 * (x - 10.3) * (x - 10.3)) as u64;
        let k = refine_peak(10, p(9.0), p(10.0), p(11.0));
        assert!((k - 10.3).abs() < 1e-4, "{k}");
        assert_eq!(refine_peak(10, 5, 7, 5), 10.0);
        assert_eq!(refine_peak(10, 0, 0, 0), 10.0);
    }

    #[test]
    fn lower_median_matches_sorting() {
        let mut seed = 99u64;
        let mut cases: Vec<Vec<u64>> = Vec::new();
        for len in [1usize, 2, 3, 4, 5, 16, 17, 1000, 2048] {
            cases.push((0..len).map(|_| rng(&mut seed) % 1000).collect());
            cases.push((0..len as u64).collect());
            cases.push((0..len as u64).rev().collect());
            cases.push(std::vec![42; len]);
            // Organ pipe and alternating: bad orders for simple pivots.
            cases.push((0..len as u64).map(|i| i.min(len as u64 - i)).collect());
            cases.push((0..len as u64).map(|i| if i % 2 == 0 { i } else { u64::MAX - i }).collect());
        }
        for mut v in cases {
            let mut sorted = v.clone();
            sorted.sort_unstable();
            let want = sorted[(v.len() - 1) / 2];
            assert_eq!(lower_median(&mut v), want);
        }
        assert_eq!(lower_median(&mut []), 0);
    }
}
