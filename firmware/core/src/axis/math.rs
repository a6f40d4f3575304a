//! Single-precision `exp(-x)` and a smoothed sign from `+ - * /` only (correctly rounded
//! in IEEE arithmetic), so that the host and every target compute
//! them bit for bit alike (`libm`'s exponential is not guaranteed to agree to the last bit
//! with another implementation, and `micromath`'s approximations are too coarse near zero
//! for a friction law), and the synthesiser's table sine as a fraction.

/// 2^-31: a Q31 sine to a fraction.
const Q31: f32 = 1.0 / 2_147_483_648.0;

/// `sin` of a phase in u32 turns, as a fraction (the synthesiser's table sine).
#[inline(always)]
pub fn sin_turns(turns: u32) -> f32 {
    crate::synth::sin_q31(turns) as f32 * Q31
}

/// Entries of the `exp(-x)` table per unit of `x`, and its extent.
const EXP_STEPS_PER_UNIT: f32 = 32.0;
const EXP_TABLE_LEN: usize = 512;

/// `[exp(-x_i), exp(-x_(i+1)) - exp(-x_i)]` at `x_i = i / 32`, so that a lookup is one load
/// pair and one multiply-add.
static EXP_NEG_TABLE: [[f32; 2]; EXP_TABLE_LEN] = exp_neg_table();

/// `exp(-x)` in f64 at compile time: `(exp(-x / 16))^16`, the inner one by its Taylor series
/// (f64 in const fn is exact IEEE arithmetic, the same on every host).
const fn exp_neg_f64(x: f64) -> f64 {
    let y = x / 16.0;
    let (mut term, mut sum, mut n) = (1.0, 1.0, 1);
    while n < 25 {
        term = -term * y / (n as f64);
        sum += term;
        n += 1;
    }
    let mut k = 0;
    while k < 4 {
        sum *= sum;
        k += 1;
    }
    sum
}

const fn exp_neg_table() -> [[f32; 2]; EXP_TABLE_LEN] {
    let mut table = [[0.0f32; 2]; EXP_TABLE_LEN];
    let mut i = 0;
    while i < EXP_TABLE_LEN {
        let a = exp_neg_f64(i as f64 / EXP_STEPS_PER_UNIT as f64);
        let b = exp_neg_f64((i + 1) as f64 / EXP_STEPS_PER_UNIT as f64);
        table[i] = [a as f32, (b - a) as f32];
        i += 1;
    }
    table
}

/// `exp(-x)` for `x >= 0` by linear interpolation in a table (relative error below 1.3e-4;
/// 0 from `x = 16` on, where it is below 1.2e-7; 1 for negative or NaN input). A friction
/// law needs no more, and a lookup is a few instructions where a series is thirty.
#[inline]
pub fn exp_neg(x: f32) -> f32 {
    // NaN and negative input: the value at zero (callers pass squares).
    let scaled = if x > 0.0 { x * EXP_STEPS_PER_UNIT } else { 0.0 };
    let index = scaled as usize;
    match EXP_NEG_TABLE.get(index) {
        Some(&[value, step]) => value + (scaled - index as f32) * step,
        None => 0.0,
    }
}

/// A smoothed sign close to `tanh(y)` (within 0.025): the Pade form
/// `y (27 + y^2) / (27 + 9 y^2)` up to `|y| = 3`, where it reaches +-1 with zero slope, and
/// the sign beyond; with its slope `((9 - y^2) / (9 + 3 y^2))^2`. One division, where
/// `tanh` needs an exponential. NaN gives NaN.
#[inline]
pub fn smooth_sign(y: f32) -> (f32, f32) {
    if y.abs() >= 3.0 {
        return (if y > 0.0 { 1.0 } else { -1.0 }, 0.0);
    }
    let y2 = y * y;
    let inv_den = 1.0 / (27.0 + 9.0 * y2);
    let ratio = (27.0 - 3.0 * y2) * inv_den;
    (y * (27.0 + y2) * inv_den, ratio * ratio)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_neg_matches_f64_over_its_range() {
        let (mut worst, mut worst_abs) = (0.0f64, 0.0f64);
        let mut x = 0.0f32;
        while x < 40.0 {
            let got = exp_neg(x) as f64;
            let want = (-(x as f64)).exp();
            if x < 16.0 {
                worst = worst.max(((got - want) / want).abs());
            }
            worst_abs = worst_abs.max((got - want).abs());
            x += 0.000_731;
        }
        assert!(worst < 1.3e-4, "worst relative error {worst:e}");
        assert!(worst_abs < 1.3e-4, "worst absolute error {worst_abs:e}");
        assert!((exp_neg(16.0) as f64) < 1.2e-7 && exp_neg(15.99) > 0.0);
        assert_eq!(exp_neg(0.0), 1.0);
        assert_eq!(exp_neg(-3.0), 1.0);
        assert_eq!(exp_neg(f32::NAN), 1.0);
        assert_eq!(exp_neg(100.0), 0.0);
        assert_eq!(exp_neg(f32::INFINITY), 0.0);
    }

    #[test]
    fn smooth_sign_follows_its_formula_and_tanh() {
        let (mut worst, mut from_tanh) = (0.0f64, 0.0f64);
        let mut y = -20.0f32;
        while y < 20.0 {
            let (s, slope) = smooth_sign(y);
            let yf = y as f64;
            let (want, want_slope) = if yf.abs() >= 3.0 {
                (yf.signum(), 0.0)
            } else {
                (yf * (27.0 + yf * yf) / (27.0 + 9.0 * yf * yf), ((9.0 - yf * yf) / (9.0 + 3.0 * yf * yf)).powi(2))
            };
            worst = worst.max((s as f64 - want).abs()).max((slope as f64 - want_slope).abs());
            from_tanh = from_tanh.max((s as f64 - yf.tanh()).abs());
            assert_eq!(smooth_sign(-y).0, -s);
            y += 0.000_377;
        }
        assert!(worst < 5e-7, "worst absolute error {worst:e}");
        assert!(from_tanh < 0.025, "{from_tanh}");
        assert_eq!(smooth_sign(0.0), (0.0, 1.0));
        assert_eq!(smooth_sign(f32::INFINITY), (1.0, 0.0));
        assert!(smooth_sign(f32::NAN).0.is_nan());
    }
}
