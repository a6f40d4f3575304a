//! The switchable physical effects, each off by default, parsed from `NAME[:k=v,...]`.
//!
//! Every effect has a fixed table of parameters with a default (a typical value), a unit and
//! an allowed range; `docs/emulator.md` gives the physics. [`EffectSpec::random`] draws
//! plausible hidden-effect parameters from a seeded generator for diagnosis tests.
//!
//! ```
//! use sts_emulator::EffectSpec;
//! let spec: EffectSpec = "coulomb-friction:coulomb_n=40".parse().unwrap();
//! assert_eq!(spec.get("coulomb_n"), 40.0);
//! assert_eq!(spec.get("static_n"), 2.5); // the default
//! assert!("coulomb-friction:force=3".parse::<EffectSpec>().is_err());
//! ```

use rand::{Rng, RngExt};
use std::fmt;
use std::str::FromStr;

use sts_model::{Effect, UnknownEffect};

/// One parameter of an effect.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParamDef {
    /// Key in `NAME:key=value`.
    pub key: &'static str,
    /// Value when not given (a typical value).
    pub default: f64,
    /// Smallest allowed value.
    pub min: f64,
    /// Largest allowed value.
    pub max: f64,
    /// Unit and meaning.
    pub doc: &'static str,
}

const fn p(key: &'static str, default: f64, min: f64, max: f64, doc: &'static str) -> ParamDef {
    ParamDef { key, default, min, max, doc }
}

const FRICTION: &[ParamDef] = &[
    p("coulomb_n", 1.5, 0.0, 200.0, "Coulomb (sliding) friction force, N"),
    p("static_n", 2.5, 0.0, 300.0, "static (breakaway) friction force at the Stribeck peak, N"),
    p("stribeck_mps", 1e-4, 1e-7, 0.1, "Stribeck velocity, m/s"),
    p("smooth_mps", 1e-5, 1e-7, 1e-3, "velocity below which the sign function is smoothed, m/s"),
];
const HYSTERESIS: &[ParamDef] = &[
    p("force_n", 1.5, 0.0, 200.0, "Dahl saturation force, N"),
    p("stiffness_n_per_um", 2.0, 0.01, 1000.0, "presliding (rest) stiffness, N/um"),
];
const MODE: &[ParamDef] = &[
    p("freq_hz", 180.0, 5.0, 1500.0, "natural frequency, Hz"),
    p("damping", 0.03, 0.001, 0.99, "damping ratio"),
    p("tcp_gain", 0.8, 0.0, 20.0, "modal displacement at the TCP per unit slide motion"),
    p("acc_shape", 1.0, -2.0, 2.0, "modal displacement at the accelerometer relative to the TCP"),
];
const DELAY: &[ParamDef] = &[p("delay_us", 250.0, 0.0, 600.0, "extra delay of the force command, us")];
const SETPOINT_DELAY: &[ParamDef] =
    &[p("delay_us", 250.0, 0.0, 5000.0, "extra delay of the position command ahead of the servo loop, us")];
const THERMAL: &[ParamDef] = &[
    p("rise_k", 0.8, -10.0, 10.0, "temperature rise of the heat source at equilibrium, K"),
    p("tau_s", 900.0, 1.0, 1e6, "thermal time constant, s"),
    p("um_per_k", 1.0, -50.0, 50.0, "TCP growth per kelvin, um/K"),
];
const RIPPLE: &[ParamDef] = &[
    p("amp_nm", 30.0, 0.0, 2000.0, "first-harmonic amplitude of the interpolation error, nm"),
    p("period_um", 4.0, 0.05, 1000.0, "signal period of the encoder, um"),
    p("harmonic2_nm", 0.0, 0.0, 2000.0, "second-harmonic amplitude, nm"),
    p("phase_deg", 0.0, -360.0, 360.0, "phase of the error at position zero, degrees"),
];
const COUPLING: &[ParamDef] = &[
    p("x_um_per_mps2", 0.8, -100.0, 100.0, "Z deflection at the TCP per X acceleration, um/(m/s^2)"),
    p("spindle_um", 0.0, 0.0, 100.0, "spindle axial error motion, once per revolution, um"),
    p("spindle_phase_deg", 0.0, -360.0, 360.0, "phase of the axial error motion, degrees"),
];
const GAIN: &[ParamDef] = &[
    p("acc_gain", 1.08, 0.1, 10.0, "accelerometer scale (1 = correct)"),
    p("probe_gain", 1.0, 0.1, 10.0, "capacitance probe scale (1 = correct)"),
];

/// The emulator's parameters of `effect`, in the order `NAME:key=value` lists them.
pub fn effect_params(effect: Effect) -> &'static [ParamDef] {
    match effect {
        Effect::CoulombFriction => FRICTION,
        Effect::PreslidingHysteresis => HYSTERESIS,
        Effect::StructuralMode => MODE,
        Effect::LoopDelay => DELAY,
        Effect::SetpointDelay => SETPOINT_DELAY,
        Effect::ThermalDrift => THERMAL,
        Effect::ForceRipple => RIPPLE,
        Effect::AxisCoupling => COUPLING,
        Effect::SensorGain => GAIN,
    }
}

/// Why an effect specification was rejected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EffectError {
    /// Not an effect's name.
    #[error(transparent)]
    UnknownEffect(#[from] UnknownEffect),
    /// Not a parameter of that effect.
    #[error("effect `{effect}`: unknown parameter `{key}` (known: {known})")]
    UnknownKey {
        /// The effect.
        effect: String,
        /// The key given.
        key: String,
        /// The effect's keys.
        known: String,
    },
    /// `key=value` malformed, or the value not a number in range.
    #[error("effect `{effect}`: parameter `{key}`: {reason}")]
    BadValue {
        /// The effect.
        effect: String,
        /// The key.
        key: String,
        /// What is wrong.
        reason: String,
    },
    /// The same effect given twice.
    #[error("effect `{0}` given twice")]
    Duplicate(String),
}

/// An enabled effect and its parameter values.
#[derive(Debug, Clone, PartialEq)]
pub struct EffectSpec {
    kind: Effect,
    values: Vec<f64>,
}

impl EffectSpec {
    /// The effect with its default (typical) parameters.
    pub fn new(kind: Effect) -> Self {
        Self { kind, values: effect_params(kind).iter().map(|d| d.default).collect() }
    }

    /// The effect.
    pub fn kind(&self) -> Effect {
        self.kind
    }

    /// The canonical name.
    pub fn name(&self) -> &'static str {
        self.kind.name()
    }

    /// A parameter's value (0 for a key the effect does not have).
    pub fn get(&self, key: &str) -> f64 {
        effect_params(self.kind).iter().position(|d| d.key == key).map_or(0.0, |i| self.values[i])
    }

    /// Sets a parameter, checking the key and the range.
    pub fn set(&mut self, key: &str, value: f64) -> Result<(), EffectError> {
        let defs = effect_params(self.kind);
        let Some(i) = defs.iter().position(|d| d.key == key) else {
            return Err(EffectError::UnknownKey {
                effect: self.name().into(),
                key: key.into(),
                known: defs.iter().map(|d| d.key).collect::<Vec<_>>().join(", "),
            });
        };
        let def = defs[i];
        if !(value.is_finite() && value >= def.min && value <= def.max) {
            return Err(EffectError::BadValue {
                effect: self.name().into(),
                key: key.into(),
                reason: format!("{value} out of range [{}, {}] ({})", def.min, def.max, def.doc),
            });
        }
        self.values[i] = value;
        Ok(())
    }

    /// Parameter keys and values, in table order.
    pub fn values(&self) -> impl Iterator<Item = (&'static str, f64)> + '_ {
        effect_params(self.kind).iter().zip(&self.values).map(|(d, v)| (d.key, *v))
    }

    /// Draws a structural mode inside the band `lo_hz..hi_hz` of the measurement test: a
    /// resonance of the error against frequency, with a small modal gain (a large one would
    /// make the machine useless at that frequency).
    pub fn random_in_band_mode<R: Rng + ?Sized>(lo_hz: f64, hi_hz: f64, rng: &mut R) -> Result<Self, EffectError> {
        let mut spec = Self::new(Effect::StructuralMode);
        let mut u = |lo: f64, hi: f64| lo + (hi - lo) * rng.random::<f64>();
        let draws = [
            ("freq_hz", u(lo_hz, hi_hz)),
            ("damping", u(0.03, 0.1)),
            ("tcp_gain", u(0.004, 0.012)),
            ("acc_shape", u(0.6, 1.2)),
        ];
        for (key, value) in draws {
            spec.set(key, value)?;
        }
        Ok(spec)
    }

    /// Draws plausible hidden-effect parameters for `kind`: strong enough to leave a signature
    /// in the measurement test, within what real machines show.
    pub fn random<R: Rng + ?Sized>(kind: Effect, rng: &mut R) -> Result<Self, EffectError> {
        let mut spec = Self::new(kind);
        let mut u = |lo: f64, hi: f64| lo + (hi - lo) * rng.random::<f64>();
        let draws: Vec<(&str, f64)> = match kind {
            Effect::CoulombFriction => {
                let coulomb = u(0.8, 4.0);
                vec![("coulomb_n", coulomb), ("static_n", coulomb * u(1.2, 1.8)), ("stribeck_mps", u(5e-5, 5e-4))]
            }
            Effect::PreslidingHysteresis => {
                vec![("force_n", u(0.8, 4.0)), ("stiffness_n_per_um", u(1.0, 5.0))]
            }
            Effect::StructuralMode => vec![
                ("freq_hz", u(120.0, 320.0)),
                ("damping", u(0.015, 0.06)),
                ("tcp_gain", u(0.5, 1.5)),
                ("acc_shape", u(0.6, 1.2)),
            ],
            Effect::LoopDelay => vec![("delay_us", u(150.0, 450.0))],
            Effect::SetpointDelay => vec![("delay_us", u(100.0, 500.0))],
            Effect::ThermalDrift => {
                let sign = if u(0.0, 1.0) < 0.5 { -1.0 } else { 1.0 };
                vec![("rise_k", u(0.5, 1.5)), ("tau_s", u(300.0, 1800.0)), ("um_per_k", sign * u(0.6, 1.5))]
            }
            Effect::ForceRipple => vec![
                ("amp_nm", u(25.0, 80.0)),
                ("period_um", u(2.0, 8.0)),
                ("harmonic2_nm", u(0.0, 15.0)),
                ("phase_deg", u(-180.0, 180.0)),
            ],
            Effect::AxisCoupling => vec![
                ("x_um_per_mps2", u(0.5, 2.0) * if u(0.0, 1.0) < 0.5 { -1.0 } else { 1.0 }),
                ("spindle_um", u(0.0, 0.1)),
                ("spindle_phase_deg", u(-180.0, 180.0)),
            ],
            Effect::SensorGain => {
                let gain = 1.0 + u(0.04, 0.12) * if u(0.0, 1.0) < 0.5 { -1.0 } else { 1.0 };
                if u(0.0, 1.0) < 0.5 {
                    vec![("acc_gain", gain), ("probe_gain", 1.0)]
                } else {
                    vec![("acc_gain", 1.0), ("probe_gain", gain)]
                }
            }
        };
        for (key, value) in draws {
            spec.set(key, value)?;
        }
        Ok(spec)
    }
}

impl FromStr for EffectSpec {
    type Err = EffectError;

    /// Parses `NAME` or `NAME:key=value,key=value`.
    fn from_str(text: &str) -> Result<Self, EffectError> {
        let (name, rest) = match text.split_once(':') {
            Some((name, rest)) => (name.trim(), Some(rest)),
            None => (text.trim(), None),
        };
        let kind: Effect = name.parse()?;
        let mut spec = EffectSpec::new(kind);
        let mut seen: Vec<&str> = Vec::new();
        for pair in rest.into_iter().flat_map(|r| r.split(',')).filter(|s| !s.trim().is_empty()) {
            let Some((key, value)) = pair.split_once('=') else {
                return Err(EffectError::BadValue {
                    effect: name.into(),
                    key: pair.trim().into(),
                    reason: "expected key=value".into(),
                });
            };
            let key = key.trim();
            if seen.contains(&key) {
                return Err(EffectError::BadValue {
                    effect: name.into(),
                    key: key.into(),
                    reason: "given twice".into(),
                });
            }
            seen.push(key);
            let value: f64 = value.trim().parse().map_err(|_| EffectError::BadValue {
                effect: name.into(),
                key: key.into(),
                reason: format!("{:?} is not a number", value.trim()),
            })?;
            spec.set(key, value)?;
        }
        Ok(spec)
    }
}

impl fmt::Display for EffectSpec {
    /// `NAME:key=value,...` with every parameter; parses back to the same spec.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.name())?;
        for (i, (key, value)) in self.values().enumerate() {
            write!(f, "{}{key}={value}", if i == 0 { ':' } else { ',' })?;
        }
        Ok(())
    }
}

/// Checks a list of effects: each at most once.
pub fn check_unique(effects: &[EffectSpec]) -> Result<(), EffectError> {
    for (i, e) in effects.iter().enumerate() {
        if effects[..i].iter().any(|o| o.kind == e.kind) {
            return Err(EffectError::Duplicate(e.name().into()));
        }
    }
    Ok(())
}
