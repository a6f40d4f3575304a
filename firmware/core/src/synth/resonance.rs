//! A structural mode's motion of the tool against the slide, from the command position
//! ([`TickTerm::Resonance`](crate::program::TickTerm::Resonance)): the second-order high-pass
//! `H(s) = s^2 / (s^2 + 2 zeta w s + w^2)` of the command, times a gain. It is a mode between
//! slide and tool driven by the slide's acceleration (`q'' + 2 zeta w q' + w^2 q = g x''`),
//! computed without differentiating the command (whose second difference at 8 kHz is below
//! its nanometre): `q = x - p` with `p = (2 zeta w s + w^2) / (s^2 + 2 zeta w s + w^2) x`, a
//! strictly proper filter of the position, discretised exactly for a position held over each
//! tick (zero-order hold), against the command half a tick late (the hold's lag).
//!
//! f32 like the axis twin: the poles lie within 1e-5 of the unit circle for a mode of a few
//! hertz at 8 kHz, which Q30 coefficients would resolve no better, and the M4F has an FPU;
//! the same code on host and target gives the same bits. The coefficients come from f64
//! closed forms (libm, once when the term starts).

use crate::program::{resonance_params_ok, TickTerm};

use crate::TICK_S;

/// A resonance's coefficients and state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Resonance {
    /// `z' = phi z + gamma x`, row-major.
    phi: [f32; 4],
    gamma: [f32; 2],
    /// `p = c0 z0 + c1 z1`.
    c: [f32; 2],
    /// Output picometres per nanometre of `q`.
    gain_pm_per_nm: f32,
    /// Filter state.
    z: [f32; 2],
    /// The last tick's command, nm.
    x_prev: f32,
    /// Whether the state has been set on the first command (at rest there: no step).
    primed: bool,
}

impl Resonance {
    /// The term's coefficients, at rest; `None` for a term that is not a resonance or whose
    /// parameters the validator refuses.
    pub fn new(term: &TickTerm) -> Option<Self> {
        let TickTerm::Resonance { freq_hz, damping, gain } = *term else { return None };
        if !resonance_params_ok(freq_hz, damping, gain) {
            return None;
        }
        let w = 2.0 * core::f64::consts::PI * f64::from(freq_hz);
        let zeta = f64::from(damping);
        let sigma = zeta * w;
        let wd = w * libm::sqrt(1.0 - zeta * zeta);
        let decay = libm::exp(-sigma * TICK_S);
        let (s, co) = (libm::sin(wd * TICK_S), libm::cos(wd * TICK_S));
        // e^(A T) for A = [[0, 1], [-w^2, -2 zeta w]].
        let phi =
            [decay * (co + sigma / wd * s), decay * s / wd, -decay * w * w / wd * s, decay * (co - sigma / wd * s)];
        // A^-1 (e^(A T) - I) [0, 1]^T.
        let gamma = [(1.0 - phi[3] - 2.0 * zeta * w * phi[1]) / (w * w), phi[1]];
        Some(Self {
            phi: phi.map(|v| v as f32),
            gamma: gamma.map(|v| v as f32),
            c: [(w * w) as f32, (2.0 * zeta * w) as f32],
            gain_pm_per_nm: gain * 1000.0,
            z: [0.0; 2],
            x_prev: 0.0,
            primed: false,
        })
    }

    /// The same coefficients, at rest (a new motion).
    pub fn rested(self) -> Self {
        Self { z: [0.0; 2], primed: false, ..self }
    }

    /// One tick on command position `pos_nm`: the tool's extra motion, picometres.
    #[inline(always)]
    pub fn step(&mut self, pos_nm: i32) -> i64 {
        let x = pos_nm as f32;
        if !self.primed {
            // At rest at the first command: p = x, no output step.
            self.z = [x / self.c[0], 0.0];
            self.x_prev = x;
            self.primed = true;
        }
        let [z0, z1] = self.z;
        // The held input lags half a tick: so does the command taken against it (else
        // `x - p` gains `j w T / 2`, more than the mode's `r^2` far below the mode).
        let q = 0.5 * (x + self.x_prev) - (self.c[0] * z0 + self.c[1] * z1);
        self.x_prev = x;
        self.z = [
            self.phi[0] * z0 + self.phi[1] * z1 + self.gamma[0] * x,
            self.phi[2] * z0 + self.phi[3] * z1 + self.gamma[1] * x,
        ];
        // Through i32 (one saturating conversion on the FPU; to i64 is a library call): at
        // most 2.1 mm, and a state that ran away (it cannot, for validated parameters) stays
        // bounded.
        i64::from((self.gain_pm_per_nm * q) as i32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn term(freq_hz: f32, damping: f32, gain: f32) -> TickTerm {
        TickTerm::Resonance { freq_hz, damping, gain }
    }

    /// Amplitude of the steady output on a command sine, relative to the command's.
    fn gain_at(freq_hz: f32, damping: f32, f: f64) -> f64 {
        let mut r = Resonance::new(&term(freq_hz, damping, 1.0)).unwrap();
        let amp_nm = 10_000.0;
        let n = 8000 * 8;
        let (mut s, mut c) = (0.0, 0.0);
        for k in 0..n {
            let phase = 2.0 * core::f64::consts::PI * f * k as f64 / 8000.0;
            let out_pm = r.step((amp_nm * libm::sin(phase)) as i32) as f64;
            if k >= n / 2 {
                s += out_pm * libm::sin(phase);
                c += out_pm * libm::cos(phase);
            }
        }
        let half = (n / 2) as f64;
        2.0 * libm::sqrt((s / half) * (s / half) + (c / half) * (c / half)) / (amp_nm * 1000.0)
    }

    #[test]
    fn the_response_is_the_second_order_high_pass() {
        // |H| = r^2 / sqrt((1 - r^2)^2 + (2 zeta r)^2).
        for (fm, zeta, f) in [(18.0f32, 0.05f32, 5.0), (18.0, 0.05, 18.0), (18.0, 0.05, 40.0), (300.0, 0.03, 40.0)] {
            let r = f / f64::from(fm);
            let want = r * r / libm::sqrt((1.0 - r * r).powi(2) + (2.0 * f64::from(zeta) * r).powi(2));
            let got = gain_at(fm, zeta, f);
            assert!((got / want - 1.0).abs() < 0.01, "{fm} Hz mode at {f} Hz: {got} vs {want}");
        }
    }

    #[test]
    fn it_starts_at_rest_wherever_the_command_is_and_refuses_bad_parameters() {
        let mut r = Resonance::new(&term(18.0, 0.05, 1.0)).unwrap();
        assert_eq!(r.step(123_456), 0);
        assert!(r.step(123_456).abs() <= 1);
        for (f, z, g) in
            [(0.1, 0.05, 1.0), (2000.0, 0.05, 1.0), (18.0, 0.0, 1.0), (18.0, 1.0, 1.0), (18.0, 0.05, f32::NAN)]
        {
            assert!(Resonance::new(&term(f, z, g)).is_none(), "{f} {z} {g}");
        }
        assert!(Resonance::new(&TickTerm::Drift { offset_pm: 0, decay_pm: 0, tau_ticks: 256 }).is_none());
    }
}
