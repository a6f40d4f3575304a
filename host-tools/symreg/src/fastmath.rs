//! Branch-free `exp`, `ln`, `tanh`, `|a|^b` and `sin`/`cos` in pure Rust, written so that a
//! loop over a column auto-vectorises (no libm call, no data-dependent branch: special cases
//! are selects, integer work is 64-bit add/shift/mask, integer <-> float conversions use the
//! `1.5 * 2^52` shifter instead of `as`).
//!
//! The first four are the engine's operator semantics ([`crate::UnaryOp::apply`],
//! [`crate::BinaryOp::apply`]) and the evaluator's column kernels, so row-wise and column-wise
//! evaluation agree bit for bit, and results do not depend on the platform's libm.
//! [`sin_cos`] is the axis twin's identification's (`sts-fit`): its ripple takes two sines a
//! tick in each simulated candidate, where libm's scalar `sin` would take most of a
//! three-effect fit.
//!
//! Accuracy against the correctly rounded value (measured against `std`/libm by the tests of
//! this module over dense samples of the whole domain, see `docs/symreg.md`):
//!
//! | function | max relative error |
//! |---|---|
//! | [`exp`] (normal results) | 2.3e-16 |
//! | [`ln`] | 2.3e-16 |
//! | [`tanh`] | 5.5e-16 |
//! | [`pow_abs`] (normal results) | 2.3e-16 + 2.3e-16 * \|b ln\|a\|\| (at most 1.7e-13) |
//! | [`sin_cos`] (\|x\| <= 1e5, absolute) | 1.1e-16 |
//!
//! Special values follow IEEE/libm exactly: `exp` overflows to `inf` and underflows to `0`
//! where libm does (up to the last ulp at the thresholds), `ln(0) = -inf`, `ln(inf) = inf`,
//! `tanh(±inf) = ±1`, `pow_abs(a, 0) = 1`, `pow_abs(±1, b) = 1` (also for NaN), and NaN in,
//! NaN out otherwise.

/// `1.5 * 2^52`: adding it to a float of magnitude below `2^51` rounds that float to an
/// integer (to nearest, ties to even) held in the low mantissa bits.
const SHIFTER: f64 = 6_755_399_441_055_744.0;
const SHIFTER_BITS: i64 = 0x4338_0000_0000_0000;
const LOG2_E: f64 = std::f64::consts::LOG2_E;
/// `ln 2` split so that `k * LN2_HI` is exact for `|k| < 2^20`.
const LN2_HI: f64 = 0.693_147_180_369_123_8;
const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;

/// Rounds `x` (|x| < 2^51) to the nearest integer, as a float and as an integer.
#[inline(always)]
fn round_int(x: f64) -> (f64, i64) {
    let t = x + SHIFTER;
    (t - SHIFTER, (t.to_bits() as i64).wrapping_sub(SHIFTER_BITS))
}

/// `2^k` for `-1022 <= k <= 1023`.
#[inline(always)]
fn pow2(k: i64) -> f64 {
    f64::from_bits((k.wrapping_add(1023) as u64) << 52)
}

/// `e^r - 1` for `|r| <= ln(2)/2 + tiny`: the Taylor series to degree 14 (the first
/// omitted term is below 1.2e-17 relative), as `r + r^2 q(r)` so that small `r` keeps full
/// relative accuracy.
#[inline(always)]
fn expm1_reduced(r: f64) -> f64 {
    const C: [f64; 13] = [
        1.0 / 2.0,
        1.0 / 6.0,
        1.0 / 24.0,
        1.0 / 120.0,
        1.0 / 720.0,
        1.0 / 5_040.0,
        1.0 / 40_320.0,
        1.0 / 362_880.0,
        1.0 / 3_628_800.0,
        1.0 / 39_916_800.0,
        1.0 / 479_001_600.0,
        1.0 / 6_227_020_800.0,
        1.0 / 87_178_291_200.0,
    ];
    // Estrin's scheme: a short dependency chain, so that the CPU overlaps the work.
    let r2 = r * r;
    let r4 = r2 * r2;
    let r8 = r4 * r4;
    let e0 = C[0] + C[1] * r;
    let e1 = C[2] + C[3] * r;
    let e2 = C[4] + C[5] * r;
    let e3 = C[6] + C[7] * r;
    let e4 = C[8] + C[9] * r;
    let e5 = C[10] + C[11] * r;
    let f0 = e0 + e1 * r2;
    let f1 = e2 + e3 * r2;
    let f2 = e4 + e5 * r2;
    let g0 = f0 + f1 * r4;
    let g1 = f2 + C[12] * r4;
    let p = g0 + g1 * r8;
    r + r * r * p
}

/// `e^x` (see the module docs for accuracy and special values).
///
/// ```
/// assert_eq!(sts_symreg::fastmath::exp(0.0), 1.0);
/// assert!((sts_symreg::fastmath::exp(1.0) - std::f64::consts::E).abs() < 1e-15);
/// ```
#[inline(always)]
pub fn exp(x: f64) -> f64 {
    // Comparisons (not min/max) so that NaN passes through.
    let x = if x > 1000.0 { 1000.0 } else { x };
    let x = if x < -1000.0 { -1000.0 } else { x };
    let (kf, k) = round_int(x * LOG2_E);
    let r = (x - kf * LN2_HI) - kf * LN2_LO;
    let y = 1.0 + expm1_reduced(r);
    // 2^k in two factors, each a normal number, so that overflow and gradual underflow
    // happen in the last product with one rounding.
    let (_, k1) = round_int(kf * 0.5);
    let k2 = k.wrapping_sub(k1);
    y * pow2(k1) * pow2(k2)
}

/// `tanh(x)` (see the module docs for accuracy and special values).
///
/// ```
/// assert_eq!(sts_symreg::fastmath::tanh(0.0), 0.0);
/// assert_eq!(sts_symreg::fastmath::tanh(-50.0), -1.0);
/// ```
#[inline(always)]
pub fn tanh(x: f64) -> f64 {
    // tanh|x| = t / (t + 2) with t = e^(2|x|) - 1; beyond |x| = 20, t + 2 rounds to t and
    // the quotient is exactly 1, as is the correctly rounded tanh.
    let a = x.abs();
    let a = if a > 20.0 { 20.0 } else { a };
    let y = a + a;
    let (kf, k) = round_int(y * LOG2_E);
    let r = (y - kf * LN2_HI) - kf * LN2_LO;
    let p = expm1_reduced(r);
    // e^y - 1 = 2^k (p + 1) - 1 = 2^k p + (2^k - 1); k >= 0 here, so no cancellation.
    let s = pow2(k);
    let t = s * p + (s - 1.0);
    let q = t / (t + 2.0);
    q.copysign(x)
}

/// `ln|x|` (see the module docs for accuracy and special values).
///
/// ```
/// assert_eq!(sts_symreg::fastmath::ln(1.0), 0.0);
/// assert_eq!(sts_symreg::fastmath::ln(-1.0), 0.0);
/// assert_eq!(sts_symreg::fastmath::ln(0.0), f64::NEG_INFINITY);
/// ```
#[inline(always)]
pub fn ln(x: f64) -> f64 {
    // musl/fdlibm log (same constants, shortest round-trip decimals): x = 2^k (1 + f) with 1 + f in [sqrt(2)/2, sqrt(2)),
    // ln(1 + f) = f - f^2/2 + s (f^2/2 + R(s^2)), s = f / (2 + f).
    const LG1: f64 = 0.666_666_666_666_673_5;
    const LG2: f64 = 0.399_999_999_994_094_2;
    const LG3: f64 = 0.285_714_287_436_623_9;
    const LG4: f64 = 0.222_221_984_321_497_84;
    const LG5: f64 = 0.181_835_721_616_180_5;
    const LG6: f64 = 0.153_138_376_992_093_73;
    const LG7: f64 = 0.147_981_986_051_165_86;
    let a = x.abs();
    // Subnormals: scale into the normal range first.
    let sub = a < f64::MIN_POSITIVE;
    let a_n = if sub { a * 18_014_398_509_481_984.0 } else { a }; // 2^54
    let k_sub: i64 = if sub { -54 } else { 0 };
    let bits = a_n.to_bits() as i64;
    // Shift so that mantissas from sqrt(2)/2 (0x3fe6a09e...) land in exponent 0x3ff.
    let bits = bits.wrapping_add((0x3ff0_0000_i64 - 0x3fe6_a09e) << 32);
    let k = ((bits as u64) >> 52) as i64 - 0x3ff + k_sub;
    let m_bits = (bits & 0x000f_ffff_ffff_ffff).wrapping_add(0x3fe6_a09e_i64 << 32);
    let m = f64::from_bits(m_bits as u64);
    let f = m - 1.0;
    let hfsq = 0.5 * f * f;
    let s = f / (2.0 + f);
    let z = s * s;
    let w = z * z;
    let t1 = w * (LG2 + w * (LG4 + w * LG6));
    let t2 = z * (LG1 + w * (LG3 + w * (LG5 + w * LG7)));
    let big_r = t2 + t1;
    let dk = f64::from_bits(k.wrapping_add(SHIFTER_BITS) as u64) - SHIFTER;
    let v = s * (hfsq + big_r) + dk * LN2_LO - hfsq + f + dk * LN2_HI;
    let v = if a == 0.0 { f64::NEG_INFINITY } else { v };
    let v = if a == f64::INFINITY { f64::INFINITY } else { v };
    if a.is_nan() {
        a
    } else {
        v
    }
}

/// `|a|^b`, the engine's `pow` (see the module docs for accuracy and special values). Exact
/// for `b = 0, 1, 2`.
///
/// ```
/// use sts_symreg::fastmath::pow_abs;
/// assert_eq!(pow_abs(-3.0, 2.0), 9.0);
/// assert_eq!(pow_abs(0.0, -1.5), f64::INFINITY);
/// assert!((pow_abs(-4.0, 0.5) - 2.0).abs() < 1e-15);
/// ```
#[inline(always)]
pub fn pow_abs(a: f64, b: f64) -> f64 {
    let x = a.abs();
    let v = exp(b * ln(x));
    let v = if b == 2.0 { x * x } else { v };
    let v = if b == 1.0 { x } else { v };
    if b == 0.0 || x == 1.0 {
        1.0
    } else {
        v
    }
}

/// `pi / 2` in three parts, each of the first two with 33 significant bits, so that
/// `k * part` is exact for `|k| < 2^20` (fdlibm's `pio2_1`, `pio2_2`, `pio2_2t`).
const PIO2_1: f64 = 1.570_796_326_734_125_6;
const PIO2_2: f64 = 6.077_100_506_303_966e-11;
const PIO2_3: f64 = 2.022_266_248_795_950_6e-21;
/// Where [`sin_cos`]'s reduction stays exact: `2^20 * pi / 2`.
const SIN_COS_LIMIT: f64 = 1_647_099.0;

/// `(sin x, cos x)` for `|x| <= 1.6e6` (NaN beyond, and for NaN or infinite `x`), within a few
/// 1e-16 absolute (see the module docs). Reduced by `pi / 2` in three exact parts, then
/// fdlibm's minimax polynomials on `[-pi/4, pi/4]` and the quadrant by selects.
///
/// ```
/// let (s, c) = sts_symreg::fastmath::sin_cos(1.0);
/// assert!((s - 1f64.sin()).abs() < 1e-15 && (c - 1f64.cos()).abs() < 1e-15);
/// ```
#[inline(always)]
pub fn sin_cos(x: f64) -> (f64, f64) {
    const S: [f64; 6] = [
        -1.666_666_666_666_663_2e-1,
        8.333_333_333_322_49e-3,
        -1.984_126_982_985_795e-4,
        2.755_731_370_707_006_8e-6,
        -2.505_076_025_340_686_3e-8,
        1.589_690_995_211_55e-10,
    ];
    const C: [f64; 6] = [
        4.166_666_666_666_66e-2,
        -1.388_888_888_887_411e-3,
        2.480_158_728_947_673e-5,
        -2.755_731_435_139_066_3e-7,
        2.087_572_321_298_175e-9,
        -1.135_964_755_778_819_5e-11,
    ];
    let inside = x.abs() <= SIN_COS_LIMIT;
    let xr = if inside { x } else { 0.0 };
    let (kf, k) = round_int(xr * std::f64::consts::FRAC_2_PI);
    let r = ((xr - kf * PIO2_1) - kf * PIO2_2) - kf * PIO2_3;
    let z = r * r;
    let w = z * z;
    let sin_r = r + r * z * (S[0] + z * (S[1] + z * S[2]) + z * w * (S[3] + z * (S[4] + z * S[5])));
    let tail = z * z * (C[0] + z * (C[1] + z * C[2]) + z * w * (C[3] + z * (C[4] + z * C[5])));
    let hz = 0.5 * z;
    let one_minus_hz = 1.0 - hz;
    let cos_r = one_minus_hz + (((1.0 - one_minus_hz) - hz) + tail);
    // Quadrant k: sin x = sin r, cos r, -sin r, -cos r; cos x a quadrant ahead.
    let swap = k & 1 != 0;
    let (s, c) = if swap { (cos_r, sin_r) } else { (sin_r, cos_r) };
    let sin_sign = ((k as u64) & 2) << 62;
    let cos_sign = ((k.wrapping_add(1) as u64) & 2) << 62;
    let s = f64::from_bits(s.to_bits() ^ sin_sign);
    let c = f64::from_bits(c.to_bits() ^ cos_sign);
    if inside {
        (s, c)
    } else {
        (f64::NAN, f64::NAN)
    }
}

// Column kernels. `#[inline(always)]` so that they are compiled inside the evaluator's
// AVX2 variant too (see `eval.rs`): the same operations, so the same bits, on more lanes.

/// `x <- e^x` on a column.
#[inline(always)]
pub fn exp_in_place(v: &mut [f64]) {
    for x in v.iter_mut() {
        *x = exp(*x);
    }
}

/// `x <- ln|x|` on a column.
#[inline(always)]
pub fn ln_in_place(v: &mut [f64]) {
    for x in v.iter_mut() {
        *x = ln(*x);
    }
}

/// `x <- tanh(x)` on a column.
#[inline(always)]
pub fn tanh_in_place(v: &mut [f64]) {
    for x in v.iter_mut() {
        *x = tanh(*x);
    }
}

/// `x <- |x|^b` on a column, for one exponent `b`.
#[inline(always)]
pub fn pow_abs_const_in_place(v: &mut [f64], b: f64) {
    if b == 2.0 {
        for x in v.iter_mut() {
            *x *= *x;
        }
    } else {
        for x in v.iter_mut() {
            *x = pow_abs(*x, b);
        }
    }
}

/// `a <- |a|^b` on columns, elementwise.
#[inline(always)]
pub fn pow_abs_in_place(a: &mut [f64], b: &[f64]) {
    for (x, y) in a.iter_mut().zip(b.iter()) {
        *x = pow_abs(*x, *y);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Relative error in units of 2^-53 against a reference (which is itself within half an
    /// ulp, so the true error is at most this plus 0.5).
    fn rel_err(got: f64, want: f64) -> f64 {
        if got == want {
            return 0.0;
        }
        ((got - want) / want).abs()
    }

    /// A deterministic sweep: evenly spaced plus pseudo-random points (xorshift) in [lo, hi].
    fn sweep(lo: f64, hi: f64, n: usize) -> impl Iterator<Item = f64> {
        let mut s = 0x9E37_79B9_7F4A_7C15u64;
        (0..n).map(move |i| {
            if i % 2 == 0 {
                lo + (hi - lo) * (i as f64 / n as f64)
            } else {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                lo + (hi - lo) * ((s >> 11) as f64 / (1u64 << 53) as f64)
            }
        })
    }

    /// Log-uniform positive magnitudes over [2^lo_e, 2^hi_e].
    fn log_sweep(lo_e: f64, hi_e: f64, n: usize) -> impl Iterator<Item = f64> {
        sweep(lo_e, hi_e, n).map(|e| e.exp2())
    }

    fn max_err(f: impl Fn(f64) -> f64, g: impl Fn(f64) -> f64, xs: impl Iterator<Item = f64>) -> (f64, f64) {
        let mut worst = (0.0, 0.0);
        for x in xs {
            let want = g(x);
            if want == 0.0 || !want.is_normal() {
                continue;
            }
            let e = rel_err(f(x), want);
            if e > worst.0 {
                worst = (e, x);
            }
        }
        eprintln!("max relative error {:.3e} at {}", worst.0, worst.1);
        worst
    }

    #[test]
    fn exp_accuracy() {
        let (e, x) = max_err(exp, f64::exp, sweep(-708.0, 709.78, 400_000));
        assert!(e <= 2.3e-16, "exp: {e:e} at {x}");
        let (e, x) = max_err(exp, f64::exp, sweep(-2.0, 2.0, 200_000));
        assert!(e <= 2.3e-16, "exp: {e:e} at {x}");
        let (e, x) = max_err(exp, f64::exp, log_sweep(-60.0, 0.0, 100_000).map(|v| -v));
        assert!(e <= 2.3e-16, "exp: {e:e} at {x}");
    }

    #[test]
    fn ln_accuracy() {
        let (e, x) = max_err(ln, f64::ln, log_sweep(-1074.0, 1023.9, 400_000));
        assert!(e <= 2.3e-16, "ln: {e:e} at {x}");
        let (e, x) = max_err(ln, f64::ln, sweep(0.5, 2.0, 400_000));
        assert!(e <= 2.3e-16, "ln: {e:e} at {x}");
        // Near 1, where ln is small and cancellation would show.
        let (e, x) = max_err(ln, f64::ln, log_sweep(-50.0, -1.0, 100_000).map(|d| 1.0 + d));
        assert!(e <= 2.3e-16, "ln: {e:e} at {x}");
        let (e, x) = max_err(ln, f64::ln, log_sweep(-50.0, -1.0, 100_000).map(|d| 1.0 - d));
        assert!(e <= 2.3e-16, "ln: {e:e} at {x}");
    }

    #[test]
    fn tanh_accuracy() {
        let (e, x) = max_err(tanh, f64::tanh, sweep(-25.0, 25.0, 400_000));
        assert!(e <= 5.5e-16, "tanh: {e:e} at {x}");
        let (e, x) = max_err(tanh, f64::tanh, log_sweep(-1070.0, 2.0, 200_000));
        assert!(e <= 5.5e-16, "tanh: {e:e} at {x}");
        let (e, x) = max_err(tanh, f64::tanh, log_sweep(-1070.0, 2.0, 200_000).map(|v| -v));
        assert!(e <= 5.5e-16, "tanh: {e:e} at {x}");
    }

    #[test]
    fn pow_accuracy() {
        let mut worst = 0.0f64;
        let mut at = (0.0, 0.0);
        let mut worst_scaled = 0.0f64;
        for a in log_sweep(-60.0, 60.0, 1_500).chain(sweep(0.01, 20.0, 1_500)) {
            for b in sweep(-6.0, 6.0, 400) {
                let want = a.powf(b);
                if !want.is_normal() {
                    continue;
                }
                let e = rel_err(pow_abs(a, b), want);
                let y = (b * a.ln()).abs();
                worst_scaled = worst_scaled.max(e - 2.3e-16 * y);
                if e > worst {
                    worst = e;
                    at = (a, b);
                }
            }
        }
        eprintln!("pow: max relative error {worst:.3e} at {at:?}, {worst_scaled:.3e} beyond 2.3e-16 |b ln a|");
        assert!(worst_scaled <= 2.3e-16, "pow: {worst_scaled:e} beyond the bound");
        assert!(worst <= 1e-13, "pow: {worst:e} at {at:?}");
        // Large |b ln a|, up to the overflow threshold.
        let mut worst = 0.0f64;
        for a in log_sweep(-1000.0, 1000.0, 2_000) {
            for b in sweep(-1.0, 1.0, 300) {
                let want = a.powf(b);
                if want.is_normal() {
                    worst = worst.max(rel_err(pow_abs(a, b), want));
                }
            }
        }
        eprintln!("pow, |b ln a| up to 709: max relative error {worst:.3e}");
        assert!(worst <= 1.7e-13, "pow, large exponents: {worst:e}");
    }

    /// Same finite / non-finite classification and the same special values as std.
    #[test]
    fn edge_cases_match_std() {
        let nan = f64::NAN;
        let inf = f64::INFINITY;
        let xs = [
            0.0,
            -0.0,
            1.0,
            -1.0,
            5e-324,
            -5e-324,
            2.2e-308,
            1e-300,
            0.5,
            1e-20,
            19.0,
            19.1,
            20.0,
            21.0,
            300.0,
            354.9,
            700.0,
            709.78,
            709.783,
            710.0,
            1e5,
            1e300,
            f64::MAX,
            -708.4,
            -745.1,
            -745.2,
            -746.0,
            -1e5,
            -1e300,
            -f64::MAX,
            inf,
            -inf,
            nan,
        ];
        let same_class = |got: f64, want: f64, what: &str, x: f64| {
            assert_eq!(got.is_nan(), want.is_nan(), "{what}({x}): {got} vs {want}");
            assert_eq!(got.is_finite(), want.is_finite(), "{what}({x}): {got} vs {want}");
            if want.is_infinite() || want == 0.0 {
                assert_eq!(got, want, "{what}({x})");
            }
        };
        for &x in &xs {
            same_class(exp(x), x.exp(), "exp", x);
            same_class(ln(x), x.abs().ln(), "ln", x);
            same_class(tanh(x), x.tanh(), "tanh", x);
            if x.tanh().abs() == 1.0 {
                assert_eq!(tanh(x), x.tanh(), "tanh({x})");
            }
            assert_eq!(tanh(x).is_sign_negative(), x.tanh().is_sign_negative(), "tanh sign at {x}");
            for &b in &xs {
                let want = x.abs().powf(b);
                let got = pow_abs(x, b);
                same_class(got, want, "pow", x);
                if want == 1.0 {
                    assert_eq!(got, 1.0, "pow({x}, {b})");
                }
            }
        }
        assert_eq!(exp(-0.0), 1.0);
        assert_eq!(ln(-0.0), f64::NEG_INFINITY);
        assert_eq!(pow_abs(nan, 0.0), 1.0);
        assert_eq!(pow_abs(-1.0, nan), 1.0);
        assert_eq!(pow_abs(-3.0, 1.0), 3.0);
        assert_eq!(pow_abs(0.0, 0.78), 0.0);
        assert_eq!(pow_abs(0.0, -0.78), inf);
        assert_eq!(pow_abs(0.5, inf), 0.0);
        assert_eq!(pow_abs(0.5, -inf), inf);
        assert_eq!(pow_abs(2.0, inf), inf);
        assert_eq!(pow_abs(inf, -2.5), 0.0);
        assert!(pow_abs(nan, 2.5).is_nan());
    }

    #[test]
    fn sin_cos_accuracy() {
        let mut worst: f64 = 0.0;
        let xs = sweep(-1e5, 1e5, 400_000).chain(sweep(-4.0, 4.0, 100_000)).chain(log_sweep(-40.0, 16.0, 50_000));
        for x in xs {
            let (s, c) = sin_cos(x);
            worst = worst.max((s - x.sin()).abs()).max((c - x.cos()).abs());
        }
        eprintln!("max absolute error {worst:.3e}");
        assert!(worst < 4e-16, "{worst:e}");
        // Small arguments keep their relative accuracy.
        for x in log_sweep(-60.0, -2.0, 10_000) {
            assert!(rel_err(sin_cos(x).0, x.sin()) < 3e-16, "{x}");
            assert!(rel_err(sin_cos(-x).0, (-x).sin()) < 3e-16, "{x}");
        }
        assert_eq!(sin_cos(0.0), (0.0, 1.0));
        for x in [f64::NAN, f64::INFINITY, -f64::INFINITY, 2e6, -1e300] {
            let (s, c) = sin_cos(x);
            assert!(s.is_nan() && c.is_nan(), "{x}");
        }
    }

    #[test]
    fn exp_overflow_threshold_matches_std() {
        // The largest x with finite e^x and the first one above it.
        let last = 709.782_712_893_383_9_f64;
        for x in [last, f64::from_bits(last.to_bits() + 1)] {
            assert_eq!(exp(x).is_finite(), x.exp().is_finite(), "{x}");
        }
    }

    #[test]
    fn column_kernels_equal_scalar() {
        let v: Vec<f64> = sweep(-30.0, 30.0, 1003).collect();
        let b: Vec<f64> = sweep(-3.0, 3.0, 1003).collect();
        let mut w = v.clone();
        exp_in_place(&mut w);
        assert!(w.iter().zip(&v).all(|(w, x)| w.to_bits() == exp(*x).to_bits()));
        let mut w = v.clone();
        ln_in_place(&mut w);
        assert!(w.iter().zip(&v).all(|(w, x)| w.to_bits() == ln(*x).to_bits()));
        let mut w = v.clone();
        tanh_in_place(&mut w);
        assert!(w.iter().zip(&v).all(|(w, x)| w.to_bits() == tanh(*x).to_bits()));
        let mut w = v.clone();
        pow_abs_in_place(&mut w, &b);
        assert!(w.iter().zip(v.iter().zip(&b)).all(|(w, (x, y))| w.to_bits() == pow_abs(*x, *y).to_bits()));
        for c in [2.0, 0.78, -1.3] {
            let mut w = v.clone();
            pow_abs_const_in_place(&mut w, c);
            assert!(w.iter().zip(&v).all(|(w, x)| w.to_bits() == pow_abs(*x, c).to_bits()));
        }
    }
}
