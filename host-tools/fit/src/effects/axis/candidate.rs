//! A candidate axis of the identification: its parameters in slots, each with the range the
//! firmware accepts and the scale the fit moves it on, and the firmware's parameters from it.

use std::f64::consts::PI;

use sts_twin_core::axis::{AxisParams, Friction, Hysteresis, Ripple, StructuralMode};

use super::AxisEffects;

/// Parameter slots of the fit. Positive quantities are fitted on a log scale, signed ones
/// additively on a typical scale.
#[derive(Clone, Copy)]
pub(super) enum Slot {
    Kp,
    Ki,
    Kd,
    Vff,
    Aff,
    Viscous,
    Tau,
    ModeHz,
    Zeta,
    Gain,
    Coulomb,
    Static,
    Stribeck,
    Smooth,
    DahlForce,
    DahlStiffness,
    RippleAmp,
    RipplePhase,
    Ripple2,
    RipplePitch,
    Mode2Hz,
    Zeta2,
    Gain2,
}
pub(super) const SLOTS: usize = 23;

impl Slot {
    /// The range the firmware accepts (`AxisParams::check`), kept inside by the fit.
    pub(super) fn bounds(self) -> (f64, f64) {
        match self {
            Slot::Kp => (1.0, 1e9),
            Slot::Ki => (1e-6, 1e12),
            Slot::Kd => (1e-6, 1e6),
            Slot::Vff => (-1e6, 1e6),
            Slot::Aff => (-10.0, 10.0),
            Slot::Viscous => (1e-6, 1e6),
            Slot::Tau => (1e-6, 0.1),
            Slot::ModeHz | Slot::Mode2Hz => (1.0, 3000.0),
            Slot::Zeta | Slot::Zeta2 => (0.001, 10.0),
            Slot::Gain | Slot::Gain2 => (-100.0, 100.0),
            Slot::Coulomb | Slot::Static | Slot::DahlForce => (1e-6, 1e3),
            Slot::Stribeck => (1e-7, 1.0),
            Slot::Smooth => (1e-8, 1.0),
            Slot::DahlStiffness => (1.0, 1e10),
            Slot::RippleAmp | Slot::Ripple2 => (-1e4, 1e4),
            Slot::RipplePhase => (-1e3, 1e3),
            Slot::RipplePitch => (0.01, 1e6),
        }
    }

    /// `Some(scale)` for an additive parameter, `None` for a log-scale one.
    pub(super) fn additive(self) -> Option<f64> {
        match self {
            Slot::Vff => Some(10.0),
            Slot::Aff => Some(0.3),
            Slot::Gain | Slot::Gain2 => Some(1.0),
            Slot::RippleAmp | Slot::Ripple2 => Some(20.0),
            Slot::RipplePhase => Some(1.0),
            _ => None,
        }
    }
}

/// A candidate axis: the parameter vector and the command delay.
#[derive(Clone, Copy, Debug)]
pub(super) struct Candidate {
    pub(super) v: [f64; SLOTS],
    pub(super) delay: usize,
    pub(super) effects: AxisEffects,
}

impl Candidate {
    pub(super) fn get(&self, s: Slot) -> f64 {
        self.v[s as usize]
    }

    /// Sets `s` to `x`, kept within its bounds.
    pub(super) fn set_within(&mut self, s: Slot, x: f64) {
        let (lo, hi) = s.bounds();
        self.v[s as usize] = x.clamp(lo, hi);
    }

    /// The firmware's parameters.
    pub(super) fn params(&self) -> AxisParams {
        let g = |s| self.get(s) as f32;
        let mut p = AxisParams {
            cmd_delay_ticks: self.delay as u8,
            kp_per_s2: g(Slot::Kp),
            ki_per_s3: g(Slot::Ki),
            kd_per_s: g(Slot::Kd),
            vff_per_s: g(Slot::Vff),
            aff: g(Slot::Aff),
            viscous_per_s: g(Slot::Viscous),
            current_tau_s: g(Slot::Tau),
            mode_freq_hz: g(Slot::ModeHz),
            mode_damping: g(Slot::Zeta),
            mode_tcp_gain: g(Slot::Gain),
            friction: None,
            hysteresis: None,
            ripple: None,
            second_mode: None,
        };
        if self.effects.second_mode {
            p.second_mode =
                Some(StructuralMode { freq_hz: g(Slot::Mode2Hz), damping: g(Slot::Zeta2), tcp_gain: g(Slot::Gain2) });
        }
        if self.effects.friction {
            p.friction = Some(Friction {
                coulomb_mps2: g(Slot::Coulomb),
                static_mps2: g(Slot::Static),
                stribeck_mps: g(Slot::Stribeck),
                smooth_mps: g(Slot::Smooth),
            });
        }
        if self.effects.hysteresis {
            p.hysteresis =
                Some(Hysteresis { force_mps2: g(Slot::DahlForce), stiffness_per_s2: g(Slot::DahlStiffness) });
        }
        if self.effects.ripple_pitch_um.is_some() {
            // Negative amplitude: the same sine half a turn on.
            let (mut amp, mut phase) = (self.get(Slot::RippleAmp), self.get(Slot::RipplePhase));
            if amp < 0.0 {
                amp = -amp;
                phase += PI;
            }
            p.ripple = Some(Ripple {
                amp_nm: amp as f32,
                harmonic2_nm: g(Slot::Ripple2),
                turns_per_nm: (4_294_967_296.0 / (self.get(Slot::RipplePitch) * 1000.0)).round() as u32,
                phase_turns: ((phase / (2.0 * PI)).rem_euclid(1.0) * 4_294_967_296.0) as u64 as u32,
            });
        }
        p
    }

    /// The slots of the effects that show in the encoder reading (friction and hysteresis
    /// move the slide against the loop) and those fitted on the probe (the loop follows
    /// the encoder's error, so at low speed it moves the slide, not the reading; the start
    /// search adds the ripple's shape on the encoder too, where fast groups show it).
    pub(super) fn effect_slots(&self) -> (Vec<Slot>, Vec<Slot>) {
        let mut encoder = Vec::new();
        if self.effects.friction {
            encoder.extend([Slot::Coulomb, Slot::Static, Slot::Stribeck, Slot::Smooth]);
        }
        if self.effects.hysteresis {
            encoder.extend([Slot::DahlForce, Slot::DahlStiffness]);
        }
        let probe = if self.effects.ripple_pitch_um.is_some() {
            vec![Slot::RippleAmp, Slot::RipplePhase, Slot::Ripple2, Slot::RipplePitch]
        } else {
            Vec::new()
        };
        (encoder, probe)
    }
}

pub(super) const SERVO: [Slot; 7] = [Slot::Kp, Slot::Ki, Slot::Kd, Slot::Vff, Slot::Aff, Slot::Viscous, Slot::Tau];
pub(super) const MODE: [Slot; 3] = [Slot::ModeHz, Slot::Zeta, Slot::Gain];
pub(super) const MODE2: [Slot; 3] = [Slot::Mode2Hz, Slot::Zeta2, Slot::Gain2];
/// The ripple's amplitudes and phase (its pitch comes from a search, refined last).
pub(super) const RIPPLE_SHAPE: [Slot; 3] = [Slot::RippleAmp, Slot::RipplePhase, Slot::Ripple2];

/// `c` with `slot` moved by `step` in its scale (additive, or a factor `exp(step)` of at most
/// `exp(0.7)`), kept within its bounds.
pub(super) fn moved(c: &Candidate, slot: Slot, step: f64) -> Candidate {
    let mut out = *c;
    let x = &mut out.v[slot as usize];
    match slot.additive() {
        Some(scale) => *x += step * scale,
        None => *x *= step.clamp(-0.7, 0.7).exp(),
    }
    let (lo, hi) = match (slot, c.effects.ripple_pitch_um) {
        // Near the pitch measured from the data: at twice it, the second harmonic alone
        // fits the same ripple.
        (Slot::RipplePitch, Some(pitch_um)) => (pitch_um / 1.05, pitch_um * 1.05),
        _ => slot.bounds(),
    };
    *x = x.clamp(lo, hi);
    out
}
