//! Linear responses at one frequency, as phasors: what a linear filter of the command does
//! to a group's steady sine, in closed form, so that a grid of filter shapes is scored per
//! group from two numbers instead of a pass over the samples (diagnose's mode and delay
//! candidates, `fit --effect`'s in-band mode).
//!
//! A signal's phasor `P` at command phase `theta` means `x ~ Re(P e^(j theta))`, that is
//! `x = Re(P) cos theta - Im(P) sin theta`. Complex numbers are `(re, im)` pairs.

use std::f64::consts::PI;

use sts_numerics::lsq::least_squares;
use sts_twin_core::SERVO_RATE_HZ;

/// A complex number, `(re, im)`.
pub type Complex = (f64, f64);

/// `a b`.
pub fn mul(a: Complex, b: Complex) -> Complex {
    (a.0 * b.0 - a.1 * b.1, a.0 * b.1 + a.1 * b.0)
}

/// `a / b`.
pub fn div(a: Complex, b: Complex) -> Complex {
    let d = b.0 * b.0 + b.1 * b.1;
    ((a.0 * b.0 + a.1 * b.1) / d, (a.1 * b.0 - a.0 * b.1) / d)
}

/// `e^(-j phi)`: a delay of `phi` radians.
pub fn delay(phi: f64) -> Complex {
    (phi.cos(), -phi.sin())
}

/// A signal's component at the command frequency over a window as a phasor (its mean
/// fitted too); zero where the window cannot tell sine from cosine.
pub fn phasor(theta: &[f64], x: &[f64]) -> Complex {
    let (sin, cos): (Vec<f64>, Vec<f64>) = theta.iter().map(|t| t.sin_cos()).unzip();
    phasor_of(&sin, &cos, x)
}

/// [`phasor`] with the sine and cosine of the phase given (computed once for many signals).
pub fn phasor_of(sin_theta: &[f64], cos_theta: &[f64], x: &[f64]) -> Complex {
    let rows: Vec<[f64; 3]> = sin_theta.iter().zip(cos_theta).map(|(&s, &c)| [s, c, 1.0]).collect();
    least_squares(&rows, x).map_or((0.0, 0.0), |f| (f.coefficients[1], -f.coefficients[0]))
}

/// The weights on `[sin theta, cos theta]` of the signal `Re(q e^(j theta))` and of its
/// quadrature `Re(j q e^(j theta))`.
pub fn sine_weights(q: Complex) -> [Vec<f64>; 2] {
    [vec![-q.1, q.0], vec![-q.0, -q.1]]
}

/// A structural mode's high-pass `r^2 / (1 - r^2 + 2 j zeta r)`, `r = freq / mode`: the
/// tool's motion against the slide per unit of slide motion, up to the modal gain.
pub fn mode_high_pass(freq_hz: f64, mode_hz: f64, zeta: f64) -> Complex {
    let r = freq_hz / mode_hz;
    div((r * r, 0.0), (1.0 - r * r, 2.0 * zeta * r))
}

/// Damping ratios of the structural-mode grid.
pub const MODE_DAMPINGS: [f64; 6] = [0.02, 0.04, 0.07, 0.12, 0.2, 0.35];

/// The structural-mode grid of a test whose highest frequency is `top_hz`: `(mode frequency,
/// damping)` pairs, frequencies inside the band from 3 Hz in 4% steps up to 0.9 of its top
/// (so that groups above a resonance show it; at the very top a mode and the peaking of a
/// loop with less phase margin look alike on the probe), and 2-30 times the top above it.
/// `diagnose` names a mode and `fit --effect` carries one from the same grid.
pub fn mode_grid(top_hz: f64) -> Vec<(f64, f64)> {
    let mut freqs: Vec<f64> = (0..).map(|i| 3.0 * 1.04f64.powi(i)).take_while(|f| *f < 0.9 * top_hz).collect();
    freqs.extend([2.0, 3.0, 5.0, 10.0, 30.0].iter().map(|k| k * top_hz));
    freqs.iter().flat_map(|f| MODE_DAMPINGS.iter().map(move |z| (*f, *z))).collect()
}

/// The stage responses of a Laguerre bank (pole `pole`, `N` stages, as
/// [`crate::bases::laguerre`]) at `freq_hz` on the command velocity over 4 servo ticks
/// divided by `smooth_nm` (the firmware's velocity input, linear below the smoothing), for a
/// command of phasor `x_um`: `L0 = sqrt(1 - a^2) / (1 - a z^-1)`, each next stage times the
/// all-pass `(z^-1 - a) / (1 - a z^-1)`, on `u = (1 - z^-4) x / smoothing`.
pub fn velocity_bank<const N: usize>(freq_hz: f64, x_um: Complex, smooth_nm: f64, pole: f64) -> [Complex; N] {
    let phi = 2.0 * PI * freq_hz / f64::from(SERVO_RATE_HZ);
    let z1 = delay(phi);
    let z4 = delay(4.0 * phi);
    let u = mul((1.0 - z4.0, -z4.1), (x_um.0 * 1e3 / smooth_nm, x_um.1 * 1e3 / smooth_nm));
    let den = (1.0 - pole * z1.0, -pole * z1.1);
    let all_pass = div((z1.0 - pole, z1.1), den);
    let mut stage = div(((1.0 - pole * pole).sqrt(), 0.0), den);
    let mut out = [(0.0, 0.0); N];
    for o in out.iter_mut() {
        *o = mul(stage, u);
        stage = mul(stage, all_pass);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bases::laguerre;

    #[test]
    fn the_bank_in_closed_form_is_the_bank_on_samples() {
        let (f, amp, smooth, pole) = (12.0, 5.0, 900.0, 0.93);
        let n = 16000;
        let theta: Vec<f64> = (0..n).map(|k| 2.0 * PI * f * k as f64 / f64::from(SERVO_RATE_HZ)).collect();
        let x: Vec<f64> = theta.iter().map(|t| amp * t.sin()).collect();
        let u: Vec<f64> = (0..n).map(|k| (x[k] - x[k.saturating_sub(4)]) * 1e3 / smooth).collect();
        let stages = laguerre(&u, n / 2, pole, 4);
        let want: [Complex; 4] = velocity_bank(f, phasor(&theta[n / 2..], &x[n / 2..]), smooth, pole);
        for (s, w) in stages.iter().zip(want) {
            let got = phasor(&theta[n / 2..], s);
            assert!((got.0 - w.0).hypot(got.1 - w.1) < 1e-6 * w.0.hypot(w.1).max(1e-3), "{got:?} vs {w:?}");
        }
        let x_phasor = phasor(&theta, &x);
        assert!((x_phasor.0).abs() < 1e-9 && (x_phasor.1 + amp).abs() < 1e-9, "{x_phasor:?}");
    }
}
