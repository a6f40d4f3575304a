//! Single-precision `exp(-x)` and `tanh` from `+ - * /` only, so that the host and every
//! target compute them bit for bit alike (`libm`'s and the FPU-less targets' routines are
//! not guaranteed to agree to the last bit, and `micromath`'s approximations are too coarse
//! near zero for a friction law).

/// `log2(e)`.
const LOG2_E: f32 = core::f32::consts::LOG2_E;
/// `ln(2)` in two parts (Cody and Waite): the first has 9 significant bits, so `n` times it
/// is exact and `x - n ln2` loses nothing for the exponents `exp_neg` meets.
const LN_2_HI: f32 = 355.0 / 512.0;
const LN_2_LO: f32 = -2.121_944_4e-4;

/// `exp(-x)` for `x >= 0` (0 above 87, 1 for negative or NaN input), relative error below
/// 2e-6.
#[inline]
pub fn exp_neg(x: f32) -> f32 {
    // NaN and negative input: the value at zero (callers pass squares and magnitudes).
    if x.is_nan() || x <= 0.0 {
        return 1.0;
    }
    if x > 87.0 {
        return 0.0;
    }
    // exp(-x) = 2^-n exp(-u), u = x - n ln2 in [0, ln2).
    let n = (x * LOG2_E) as i32;
    let mut u = (x - n as f32 * LN_2_HI) - n as f32 * LN_2_LO;
    // The product above can round u just below 0 or to ln2; both stay accurate.
    if u < 0.0 {
        u = 0.0;
    }
    // Taylor series of exp(-u) to the 7th power (error below u^8/8! < 1.3e-6).
    let mut p = 1.0 / 5040.0 - u * (1.0 / 40320.0);
    p = 1.0 / 720.0 - u * p;
    p = 1.0 / 120.0 - u * p;
    p = 1.0 / 24.0 - u * p;
    p = 1.0 / 6.0 - u * p;
    p = 0.5 - u * p;
    p = 1.0 - u * p;
    p = 1.0 - u * p;
    // 2^-n as an f32 bit pattern (n <= 125 here, so the exponent stays normal).
    p * f32::from_bits(((127 - n) as u32) << 23)
}

/// `tanh(y)` (0 for NaN), absolute error below 4e-6.
#[inline]
pub fn tanh(y: f32) -> f32 {
    let t = exp_neg(2.0 * y.abs());
    let m = (1.0 - t) / (1.0 + t);
    if y < 0.0 {
        -m
    } else if y > 0.0 {
        m
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_neg_matches_f64_over_its_range() {
        let mut worst = 0.0f64;
        let mut x = 0.0f32;
        while x < 80.0 {
            let got = exp_neg(x) as f64;
            let want = (-(x as f64)).exp();
            worst = worst.max(((got - want) / want).abs());
            x += 0.000_731;
        }
        assert!(worst < 2e-6, "worst relative error {worst:e}");
        assert_eq!(exp_neg(0.0), 1.0);
        assert_eq!(exp_neg(-3.0), 1.0);
        assert_eq!(exp_neg(f32::NAN), 1.0);
        assert_eq!(exp_neg(100.0), 0.0);
        assert_eq!(exp_neg(f32::INFINITY), 0.0);
    }

    #[test]
    fn tanh_matches_f64_and_is_odd() {
        let mut worst = 0.0f64;
        let mut y = -20.0f32;
        while y < 20.0 {
            let got = tanh(y) as f64;
            worst = worst.max((got - (y as f64).tanh()).abs());
            assert_eq!(tanh(-y), -tanh(y));
            y += 0.000_377;
        }
        assert!(worst < 4e-6, "worst absolute error {worst:e}");
        assert_eq!(tanh(0.0), 0.0);
        assert_eq!(tanh(f32::NAN), 0.0);
        assert_eq!(tanh(f32::INFINITY), 1.0);
        assert_eq!(tanh(f32::NEG_INFINITY), -1.0);
    }
}
