//! The core's arithmetic primitives, in one place: the table sine of a phase in turns (Q31,
//! and as a fraction), the table `exp(-x)` and the smoothed sign of the axis twin's friction
//! law, the high-word multiply, the integer square root and a division by 10^6 without
//! 64-bit division, and the conversions of model outputs (micrometres, degrees) to
//! picometres and turns.
//!
//! Hand-written rather than taken from a crate: the core is `no_std`, it must compute the
//! same bits on the firmware and on the host (a library's `sin` or `exp` is not guaranteed
//! to agree to the last bit across implementations and targets, and `micromath`'s
//! approximations are too coarse near zero for a friction law), and most of this runs in the
//! hot loop of the 8 kHz servo tick, where a 64-bit division or a float series is a library
//! call of about a hundred instructions on a Cortex-M4F. The tables are built at compile time
//! (`const fn`: f64 in const fn is exact IEEE arithmetic, the same on every host); the
//! single-precision functions use `+ - * /` only, correctly rounded in IEEE arithmetic.
//!
//! Phases are in turns where a full turn is 2^32 (`u32`, so phase arithmetic wraps exactly).
//! The sine comes from a 1024-entry table with linear interpolation (worst error 4.8e-6 of
//! full scale, i.e. 48 pm at a 10 um amplitude).

/// Table size (entries per turn).
const SINE_TABLE_BITS: u32 = 10;
const SINE_TABLE_LEN: usize = 1 << SINE_TABLE_BITS;

/// sin(2 pi i / 1024) in Q31, one extra entry so interpolation needs no wrap.
#[cfg(test)]
const SINE_Q31: [i32; SINE_TABLE_LEN + 1] = sine_table();

/// Each table entry with twice the step to the next: `[sin_i, 2 (sin_(i+1) - sin_i)]`, so that
/// the interpolation is one load pair and one high-word multiply (`smmla` on a Cortex-M4).
/// The doubled step (at most 2^24.7) and the fraction in Q31 keep the product exact.
static SINE_SLOPE_Q31: [[i32; 2]; SINE_TABLE_LEN] = sine_slope_table();

/// Builds the table at compile time (f64 in const fn is exact IEEE arithmetic).
const fn sine_table() -> [i32; SINE_TABLE_LEN + 1] {
    let mut table = [0i32; SINE_TABLE_LEN + 1];
    let mut i = 0;
    while i <= SINE_TABLE_LEN {
        // Reduce to [-pi, pi] for the Taylor series.
        let mut x = 2.0 * core::f64::consts::PI * (i as f64) / (SINE_TABLE_LEN as f64);
        if x > core::f64::consts::PI {
            x -= 2.0 * core::f64::consts::PI;
        }
        let mut term = x;
        let mut sum = x;
        let mut n = 1;
        while n < 30 {
            term = -term * x * x / (((2 * n) * (2 * n + 1)) as f64);
            sum += term;
            n += 1;
        }
        let scaled = sum * 2147483647.0;
        table[i] = if scaled >= 0.0 { (scaled + 0.5) as i32 } else { (scaled - 0.5) as i32 };
        i += 1;
    }
    table
}

const fn sine_slope_table() -> [[i32; 2]; SINE_TABLE_LEN] {
    let sine = sine_table();
    let mut table = [[0i32; 2]; SINE_TABLE_LEN];
    let mut i = 0;
    while i < SINE_TABLE_LEN {
        table[i] = [sine[i], 2 * (sine[i + 1] - sine[i])];
        i += 1;
    }
    table
}

/// `(a * b) >> 32`: one `smmul` on a Cortex-M4.
#[inline(always)]
pub(crate) fn mul_hi(a: i32, b: i32) -> i32 {
    ((a as i64 * b as i64) >> 32) as i32
}

/// sin of a phase in turns (2^32 = one turn), in Q31: the table entry of the top 10 bits,
/// linearly interpolated by the next 16, `a + ((b - a) * frac16) >> 16` (floor).
#[inline]
pub fn sin_q31(phase_turns: u32) -> i32 {
    let [a, slope2] = SINE_SLOPE_Q31[(phase_turns >> (32 - SINE_TABLE_BITS)) as usize];
    // The 16 interpolation bits in Q31: frac16 << 15.
    let frac_q31 = ((phase_turns << SINE_TABLE_BITS) >> 1) & 0x7fff_8000;
    // (2 (b - a) * frac16 2^15) >> 32 = ((b - a) * frac16) >> 16, exactly.
    a + mul_hi(slope2, frac_q31 as i32)
}

/// 2^-31: a Q31 sine to a fraction.
const Q31: f32 = 1.0 / 2_147_483_648.0;

/// `sin` of a phase in u32 turns, as a fraction (the synthesiser's table sine).
#[inline(always)]
pub fn sin_turns(turns: u32) -> f32 {
    sin_q31(turns) as f32 * Q31
}

/// `amp_pm * sin(phase)`, in picometres (any amplitude).
#[inline]
pub(crate) fn harmonic_pm(amp_pm: i32, phase_turns: u32) -> i32 {
    ((amp_pm as i64 * sin_q31(phase_turns) as i64) >> 31) as i32
}

/// Micrometres (f32) to picometres, saturating at +-1 mm (NaN gives 0).
pub fn um_to_pm(value_um: f32) -> i32 {
    const LIMIT_UM: f32 = 1000.0;
    // `clamp` keeps NaN, and `as` maps NaN to 0.
    (value_um.clamp(-LIMIT_UM, LIMIT_UM) * 1.0e6) as i32
}

/// Degrees (f32) to turns (2^32 per turn), wrapping; NaN gives 0.
///
/// The fraction of a turn is `turns - trunc(turns)` (truncation toward zero), times 2^32,
/// truncated and wrapped. For `|turns| < 2^31`, the usual case, the truncations go through
/// `i32` (single instructions on a Cortex-M4F; `i64` conversions are library calls of ~50
/// instructions each) with the same results as through `i64`.
pub fn deg_to_turns(value_deg: f32) -> u32 {
    const TWO_POW_31: f32 = 2_147_483_648.0;
    if !value_deg.is_finite() {
        return 0;
    }
    let turns = value_deg / 360.0;
    if !(-TWO_POW_31 < turns && turns < TWO_POW_31) {
        return deg_to_turns_wide(turns);
    }
    // Exact: an integer below 2^24 in magnitude, or `turns` itself (already integral).
    let whole = turns as i32 as f32;
    let scaled = (turns - whole) * 4_294_967_296.0; // in (-2^32, 2^32), exact
    if -TWO_POW_31 < scaled && scaled < TWO_POW_31 {
        scaled as i32 as u32
    } else {
        // |scaled| >= 2^31 is a multiple of 2^8: halve exactly, convert, double (wrapping).
        ((scaled * 0.5) as i32 as u32) << 1
    }
}

/// [`deg_to_turns`] for `|turns| >= 2^31` (64-bit truncations, as defined).
#[cold]
fn deg_to_turns_wide(turns: f32) -> u32 {
    let whole = turns as i64 as f32;
    let frac = turns - whole;
    (frac * 4_294_967_296.0) as i64 as u32
}

/// Integer square root (floor) of `v < 2^62`: its one use is `1 - a^2` of a Laguerre pole
/// in Q60, at most 2^60 (beyond 2^62 the squares it checks would overflow).
pub(crate) fn isqrt_u64(v: u64) -> u64 {
    if v < 2 {
        return v;
    }
    let mut x = (libm::sqrt(v as f64)) as u64;
    while x * x > v {
        x -= 1;
    }
    while (x + 1) * (x + 1) <= v {
        x += 1;
    }
    x
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
    fn the_sine_table_is_accurate() {
        let mut worst = 0.0f64;
        for k in 0..100_000u64 {
            let phase = (k * 42_949_673 + 12345) as u32;
            let exact = (2.0 * core::f64::consts::PI * phase as f64 / 4_294_967_296.0).sin();
            let got = sin_q31(phase) as f64 / 2147483648.0;
            worst = worst.max((exact - got).abs());
        }
        assert!(worst < 5e-6, "worst sine error {worst}");
    }

    fn rng(seed: &mut u64) -> u64 {
        *seed ^= *seed << 13;
        *seed ^= *seed >> 7;
        *seed ^= *seed << 17;
        *seed
    }

    #[test]
    fn the_sine_interpolation_is_the_plain_one_bit_for_bit() {
        let plain = |phase: u32| {
            let index = (phase >> 22) as usize;
            let frac = ((phase >> 6) & 0xffff) as i64;
            let a = SINE_Q31[index] as i64;
            let b = SINE_Q31[index + 1] as i64;
            (a + (((b - a) * frac) >> 16)) as i32
        };
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        for k in 0..200_000u64 {
            let phase = if k < 4096 { (k as u32) << 20 | (k as u32 & 0x3f) } else { rng(&mut seed) as u32 };
            assert_eq!(sin_q31(phase), plain(phase), "phase {phase:#x}");
        }
        for phase in [0u32, u32::MAX, 0x7fff_ffff, 0x8000_0000, 0x003f_ffc0, 0xffc0_0000] {
            assert_eq!(sin_q31(phase), plain(phase));
        }
    }

    #[test]
    fn degrees_convert_as_through_64_bits() {
        let wide = |value_deg: f32| if value_deg.is_finite() { deg_to_turns_wide(value_deg / 360.0) } else { 0 };
        let mut seed = 11u64;
        let mut values = std::vec![
            0.0f32,
            -0.0,
            1e-30,
            -1e-30,
            359.99997,
            -359.99997,
            180.0,
            -180.0,
            7.7e11,
            -7.7e11,
            3e12,
            f32::MAX,
            f32::MIN
        ];
        for k in 0..300_000 {
            let bits = rng(&mut seed) as u32;
            values.push(match k % 3 {
                0 => f32::from_bits(bits),
                1 => (bits as i32 as f32) * 1e-3,
                _ => (bits as i32 as f32) * 400.0,
            });
        }
        for v in values {
            assert_eq!(deg_to_turns(v), wide(v), "{v:e}");
        }
    }

    #[test]
    fn degrees_convert_to_wrapping_turns() {
        assert_eq!(deg_to_turns(90.0), 1 << 30);
        assert_eq!(deg_to_turns(-90.0), 3 << 30);
        assert_eq!(deg_to_turns(450.0), 1 << 30);
        assert_eq!(deg_to_turns(f32::NAN), 0);
        assert_eq!(um_to_pm(1.5), 1_500_000);
        assert_eq!(um_to_pm(f32::INFINITY), 1_000_000_000);
        assert_eq!(um_to_pm(f32::NAN), 0);
    }

    #[test]
    fn the_integer_square_root_is_the_floor() {
        for v in [0u64, 1, 2, 3, 4, 15, 16, 17, (1 << 60) - 1, 1 << 60, (1 << 62) - 1] {
            let r = isqrt_u64(v);
            assert!(r * r <= v && (r + 1) * (r + 1) > v, "{v}: {r}");
        }
    }

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
