//! The physical effects a twin can carry, the emulator can switch on and diagnose can name:
//! one type for the whole tool. Its name is what every command, file and report writes.
//!
//! ```
//! use sts_model::Effect;
//! let effect: Effect = "force-ripple".parse().unwrap();
//! assert_eq!(effect, Effect::ForceRipple);
//! assert_eq!(effect.to_string(), "force-ripple");
//! assert!(effect.carried_by_the_axis_twin());
//! assert!("friction".parse::<Effect>().is_err());
//! ```

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// One of the physical effects, in the library's order ([`Effect::ALL`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Effect {
    /// `coulomb-friction`: Coulomb friction with a Stribeck peak on the Z slide.
    CoulombFriction,
    /// `presliding-hysteresis`: presliding friction, a hysteretic spring at reversals.
    PreslidingHysteresis,
    /// `structural-mode`: a structural mode between the slide and the tool.
    StructuralMode,
    /// `loop-delay`: extra delay in the servo loop's force output.
    LoopDelay,
    /// `setpoint-delay`: the position command reaches the servo loop late.
    SetpointDelay,
    /// `thermal-drift`: thermal growth of the tool side, drifting with machine time.
    ThermalDrift,
    /// `force-ripple`: a position-periodic error (encoder interpolation error).
    ForceRipple,
    /// `axis-coupling`: X-axis acceleration and spindle axial error motion into Z at the tool.
    AxisCoupling,
    /// `sensor-gain`: a scale error of the accelerometer or of the capacitance probe.
    SensorGain,
}

impl Effect {
    /// Every effect, in the library's order. A new variant is added here by hand: the
    /// matches on [`Effect`] are checked by the compiler, this list is not.
    pub const ALL: [Effect; 9] = [
        Effect::CoulombFriction,
        Effect::PreslidingHysteresis,
        Effect::StructuralMode,
        Effect::LoopDelay,
        Effect::SetpointDelay,
        Effect::ThermalDrift,
        Effect::ForceRipple,
        Effect::AxisCoupling,
        Effect::SensorGain,
    ];

    /// The name every command, file and report uses (`--effect NAME`).
    pub const fn name(self) -> &'static str {
        match self {
            Effect::CoulombFriction => "coulomb-friction",
            Effect::PreslidingHysteresis => "presliding-hysteresis",
            Effect::StructuralMode => "structural-mode",
            Effect::LoopDelay => "loop-delay",
            Effect::SetpointDelay => "setpoint-delay",
            Effect::ThermalDrift => "thermal-drift",
            Effect::ForceRipple => "force-ripple",
            Effect::AxisCoupling => "axis-coupling",
            Effect::SensorGain => "sensor-gain",
        }
    }

    /// The effect of this name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|e| e.name() == name)
    }

    /// Every name, comma-separated, for messages.
    pub fn names() -> String {
        Self::ALL.map(Effect::name).join(", ")
    }

    /// Whether the twin carries it in the servo-axis twin (a simulation of the axis from the
    /// command, with the effect's force in it), not in terms of its own.
    pub const fn carried_by_the_axis_twin(self) -> bool {
        matches!(self, Effect::CoulombFriction | Effect::PreslidingHysteresis | Effect::ForceRipple)
    }

    /// Whether `name` names an effect the servo-axis twin carries (a model file's record
    /// names it so; the axis twin itself, [`SERVO_AXIS`], is not such an effect).
    pub fn name_carried_by_the_axis_twin(name: &str) -> bool {
        Self::from_name(name).is_some_and(Self::carried_by_the_axis_twin)
    }

    /// Whether its signature reaches beyond the command frequency (harmonics, steps, trends,
    /// other lines), so that the twin needs terms for it: the formulas at the command's
    /// frequency cannot carry it. A mode, a delay (in the loop or ahead of it) and a sensor's
    /// gain change each group's fundamental only.
    pub const fn beyond_the_fundamental(self) -> bool {
        matches!(
            self,
            Effect::CoulombFriction
                | Effect::PreslidingHysteresis
                | Effect::ThermalDrift
                | Effect::ForceRipple
                | Effect::AxisCoupling
        )
    }
}

impl fmt::Display for Effect {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A name that is not an effect's.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("unknown effect {name:?} (known: {known})", known = Effect::names())]
pub struct UnknownEffect {
    /// The name given.
    pub name: String,
}

impl FromStr for Effect {
    type Err = UnknownEffect;

    fn from_str(name: &str) -> Result<Self, UnknownEffect> {
        Self::from_name(name).ok_or_else(|| UnknownEffect { name: name.into() })
    }
}

/// Not an effect but the servo-axis twin alone (controller, slide and structural mode,
/// simulated from the command, no nonlinear effect): the twin for a machine's whole speed
/// range, whose correction the firmware learns from the command rather than from the
/// accelerometer's view of the compensated motion. `fit --effect servo-axis`.
pub const SERVO_AXIS: &str = "servo-axis";

/// What `fit --effect NAME` adds to a twin: a physical effect, or the servo-axis twin alone
/// ([`SERVO_AXIS`], the twin for a machine's whole speed range). Its name is the effect's, or
/// `servo-axis`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum FitEffect {
    /// A physical effect.
    Effect(Effect),
    /// The servo-axis twin alone.
    ServoAxis,
}

impl FitEffect {
    /// The name `fit --effect` takes and the model file's records carry.
    pub const fn name(self) -> &'static str {
        match self {
            FitEffect::Effect(effect) => effect.name(),
            FitEffect::ServoAxis => SERVO_AXIS,
        }
    }

    /// Whether the servo-axis twin carries it (it, or an effect the axis twin carries).
    pub const fn needs_the_axis_twin(self) -> bool {
        match self {
            FitEffect::Effect(effect) => effect.carried_by_the_axis_twin(),
            FitEffect::ServoAxis => true,
        }
    }
}

impl From<Effect> for FitEffect {
    fn from(effect: Effect) -> Self {
        FitEffect::Effect(effect)
    }
}

impl fmt::Display for FitEffect {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for FitEffect {
    type Err = UnknownEffect;

    fn from_str(name: &str) -> Result<Self, UnknownEffect> {
        if name == SERVO_AXIS {
            return Ok(FitEffect::ServoAxis);
        }
        name.parse().map(FitEffect::Effect)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_effect_is_known_by_its_name_in_text_and_in_json() {
        for effect in Effect::ALL {
            assert_eq!(effect.name().parse::<Effect>(), Ok(effect));
            assert_eq!(serde_json::to_string(&effect).unwrap(), format!("\"{}\"", effect.name()));
            assert_eq!(serde_json::from_str::<Effect>(&format!("\"{effect}\"")).unwrap(), effect);
        }
        let error = "servo-axis".parse::<Effect>().unwrap_err();
        assert!(error.to_string().contains("coulomb-friction, presliding-hysteresis"), "{error}");
        assert_eq!("servo-axis".parse::<FitEffect>(), Ok(FitEffect::ServoAxis));
        for effect in Effect::ALL {
            assert_eq!(effect.name().parse::<FitEffect>(), Ok(FitEffect::Effect(effect)));
            assert_eq!(FitEffect::from(effect).to_string(), effect.name());
        }
    }
}
