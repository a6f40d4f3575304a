//! Feedforward (the paper's Eq. 5): the predicted error to a DAC code.
//!
//! The correction is the displacement that cancels the predicted error, `u = -DE`. The
//! voltage is `V = g * u / K_dv - offset` where `g` ramps between 0 (disabled, degraded)
//! and 1 (enabled); the motion controller reads `V` plus its interface offset and turns it
//! into motion pulses `P = reading * K_vc`. With `offset` calibrated to the interface offset
//! the controller reads exactly `u / K_dv` and `P = (DE_pre / K_dv - offset) * K_vc` as in the
//! paper, and switching compensation on at rest moves the axis by nothing.
//!
//! The DAC code never steps: every change of target (a new prediction, enabling, disabling,
//! a new offset, a fault) is followed at most [`FeedforwardParams::slew_v_per_tick`] per
//! tick. A target beyond the DAC's range is clamped and counted.
//!
//! Internal formats: codes in Q16 (`i64`, 65536 per DAC code), the scale from picometres to
//! codes in Q32. Bad parameters are rejected by [`FeedforwardParams::validate`] and never
//! reach the arithmetic, which then cannot overflow.

use serde::{Deserialize, Serialize};

use crate::analogue_path::{AnaloguePath, PathError};

/// Parameters of the feedforward, as set over the control channel and stored in the config.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FeedforwardParams {
    /// Displacement per volt of the analogue input, micrometres per volt (`K_dv`).
    pub k_dv_um_per_v: f32,
    /// Motion pulses per volt of the controller (`K_vc`), for reporting in pulses.
    pub k_vc_pulses_per_v: f32,
    /// Offset voltage subtracted from the output (calibrated to the interface's offset), volts.
    pub offset_v: f32,
    /// Largest change of the output per servo tick, volts.
    pub slew_v_per_tick: f32,
    /// Full-scale voltage of the DAC (code 32767), volts.
    pub dac_full_scale_v: f32,
    /// Ticks over which enabling or disabling ramps the gain between 0 and 1.
    pub enable_ramp_ticks: u32,
    /// The analogue path's phase response, subtracted from each model update's phase (see
    /// [`crate::analogue_path`]); empty by default.
    pub analogue_path: AnaloguePath,
}

impl Default for FeedforwardParams {
    fn default() -> Self {
        Self {
            k_dv_um_per_v: 1.0,
            k_vc_pulses_per_v: 1000.0,
            offset_v: 0.0,
            slew_v_per_tick: 0.5,
            dac_full_scale_v: 10.0,
            enable_ramp_ticks: 4000,
            analogue_path: AnaloguePath::NONE,
        }
    }
}

/// Why feedforward parameters were rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ParamError {
    /// `K_dv` is zero, not finite, outside 1e-4..1e4 um/V in magnitude, or so small that a
    /// DAC code is less than 2 pm of correction.
    KDv,
    /// `K_vc` is not finite or not in (0, 1e9] pulses/V.
    KVc,
    /// The offset is not finite or larger than half the DAC's full scale.
    Offset,
    /// The slew limit is not finite, not positive, or above the DAC's full scale per tick.
    Slew,
    /// The DAC full scale is not finite or not in (0, 100] V.
    DacFullScale,
    /// The enable ramp is longer than 10 minutes at 8 kHz.
    EnableRamp,
    /// The analogue-path table is malformed.
    AnaloguePath(PathError),
}

impl core::fmt::Display for ParamError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::KDv => {
                "k_dv_um_per_v must be finite, within 1e-4..1e4 in magnitude, and give at least 2 pm per DAC code"
            }
            Self::KVc => "k_vc_pulses_per_v must be finite and in (0, 1e9]",
            Self::Offset => "offset_v must be finite and within half the DAC full scale",
            Self::Slew => "slew_v_per_tick must be finite, positive and at most the DAC full scale",
            Self::DacFullScale => "dac_full_scale_v must be finite and in (0, 100]",
            Self::EnableRamp => "enable_ramp_ticks must be at most 4,800,000",
            Self::AnaloguePath(err) => return write!(f, "analogue_path: {err}"),
        })
    }
}

// The analogue-path error is part of the message, so it is not also given as the source.
impl core::error::Error for ParamError {}

impl FeedforwardParams {
    /// Checks the parameters; only valid parameters are ever used.
    pub fn validate(&self) -> Result<(), ParamError> {
        let k_dv = self.k_dv_um_per_v;
        if !(k_dv.is_finite() && (1e-4..=1e4).contains(&k_dv.abs())) {
            return Err(ParamError::KDv);
        }
        if !(self.k_vc_pulses_per_v.is_finite() && self.k_vc_pulses_per_v > 0.0 && self.k_vc_pulses_per_v <= 1e9) {
            return Err(ParamError::KVc);
        }
        let fs = self.dac_full_scale_v;
        if !(fs.is_finite() && fs > 0.0 && fs <= 100.0) {
            return Err(ParamError::DacFullScale);
        }
        // At least 2 pm of correction per DAC code keeps the scale below 2^31 in Q32, so the
        // per-tick product fits in i64 (a 64-bit multiply, not a 128-bit library call).
        if f64::from(k_dv.abs()) * 1e6 * f64::from(fs) / 32767.0 < 2.0 {
            return Err(ParamError::KDv);
        }
        if !(self.offset_v.is_finite() && self.offset_v.abs() <= fs / 2.0) {
            return Err(ParamError::Offset);
        }
        if !(self.slew_v_per_tick.is_finite() && self.slew_v_per_tick > 0.0 && self.slew_v_per_tick <= fs) {
            return Err(ParamError::Slew);
        }
        if self.enable_ramp_ticks > 4_800_000 {
            return Err(ParamError::EnableRamp);
        }
        self.analogue_path.validate().map_err(ParamError::AnaloguePath)
    }

    /// Volts per DAC code.
    pub fn volts_per_code(&self) -> f32 {
        self.dac_full_scale_v / 32767.0
    }
}

/// Scaled integer form of validated parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Scaled {
    /// DAC codes per picometre of correction, Q32 (signed: `K_dv` may be negative).
    codes_per_pm_q32: i64,
    offset_q16: i64,
    slew_q16: i64,
    /// 1 ..= 2^16.
    gain_step_q16: i32,
}

const ONE_Q16: i64 = 1 << 16;
const CODE_MAX_Q16: i64 = (i16::MAX as i64) << 16;
const CODE_MIN_Q16: i64 = (i16::MIN as i64) << 16;

impl Scaled {
    fn from(params: &FeedforwardParams) -> Self {
        let v_per_code = f64::from(params.volts_per_code());
        let pm_per_code = f64::from(params.k_dv_um_per_v) * 1e6 * v_per_code;
        let ramp = params.enable_ramp_ticks.max(1) as i64;
        Self {
            // |K_dv| >= 1e-4 and full scale > 0 bound this well inside i64.
            codes_per_pm_q32: (4_294_967_296.0 / pm_per_code) as i64,
            offset_q16: (f64::from(params.offset_v) / v_per_code * 65536.0) as i64,
            slew_q16: ((f64::from(params.slew_v_per_tick) / v_per_code * 65536.0) as i64).max(1),
            gain_step_q16: (ONE_Q16 / ramp).max(1) as i32,
        }
    }
}

/// What one feedforward tick did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FeedforwardTick {
    /// The DAC code to write.
    pub dac_code: i16,
    /// The target was beyond the DAC range and clamped.
    pub saturated: bool,
    /// The output moved by the slew limit rather than to its target.
    pub slewing: bool,
}

/// The feedforward stage. See the [module docs](self).
#[derive(Clone, Debug, PartialEq)]
pub struct Feedforward {
    params: FeedforwardParams,
    scaled: Scaled,
    /// Current output, Q16 codes; always within the DAC's range (it only ever moves towards
    /// a target clamped to the range), so 32 bits hold it.
    output_q16: i32,
    /// Current gain, Q16 (0 ..= 65536).
    gain_q16: i32,
    /// Whether compensation is wanted (the gain ramps towards 1 when also trusted).
    enabled: bool,
}

impl Feedforward {
    /// A disabled stage with `params`, which must be valid; invalid ones are replaced by the
    /// defaults (and the error is returned alongside) so that the stage is always usable.
    pub fn new(params: FeedforwardParams) -> (Self, Result<(), ParamError>) {
        let check = params.validate();
        let params = if check.is_ok() { params } else { FeedforwardParams::default() };
        let stage = Self { params, scaled: Scaled::from(&params), output_q16: 0, gain_q16: 0, enabled: false };
        (stage, check)
    }

    /// Replaces the parameters if valid; otherwise keeps the old ones. The output follows a
    /// new offset at the slew limit, never in a step.
    pub fn set_params(&mut self, params: FeedforwardParams) -> Result<(), ParamError> {
        params.validate()?;
        self.params = params;
        self.scaled = Scaled::from(&params);
        Ok(())
    }

    /// The parameters in force.
    pub fn params(&self) -> &FeedforwardParams {
        &self.params
    }

    /// Asks for compensation on or off; the gain ramps over `enable_ramp_ticks`.
    pub fn set_enabled(&mut self, enabled: bool) {
        self.enabled = enabled;
    }

    /// Whether compensation is asked for.
    pub fn enabled(&self) -> bool {
        self.enabled
    }

    /// The gain in force, 0 to 1.
    pub fn gain(&self) -> f32 {
        self.gain_q16 as f32 / ONE_Q16 as f32
    }

    /// Whether the gain is zero (compensation fully ramped out).
    pub fn gain_is_zero(&self) -> bool {
        self.gain_q16 == 0
    }

    /// One tick: `de_pred_pm` is the predicted dynamic error; `trusted` false ramps the
    /// compensation out (degraded inputs) whatever `enabled` says.
    #[inline]
    pub fn tick(&mut self, de_pred_pm: i32, trusted: bool) -> FeedforwardTick {
        let s = &self.scaled;
        let gain_target = if self.enabled && trusted { ONE_Q16 as i32 } else { 0 };
        // Gain and step are at most 2^16: 32 bits suffice.
        self.gain_q16 = if self.gain_q16 < gain_target {
            (self.gain_q16 + s.gain_step_q16).min(gain_target)
        } else {
            (self.gain_q16 - s.gain_step_q16).max(gain_target)
        };
        // u = -DE; codes = u * codes_per_pm. Validation keeps |codes_per_pm_q32| < 2^31, so
        // with |DE| <= 2^31 the product fits in i64; it is clamped far outside the DAC range
        // before the gain.
        const LIMIT_Q16: i64 = 1 << 40;
        let product_q48 = (de_pred_pm as i64).wrapping_neg().wrapping_mul(s.codes_per_pm_q32);
        let correction_q16 = (product_q48 >> 16).clamp(-LIMIT_Q16, LIMIT_Q16);
        let target = ((correction_q16 * self.gain_q16 as i64) >> 16) - s.offset_q16;
        let saturated = !(CODE_MIN_Q16..=CODE_MAX_Q16).contains(&target);
        let target = target.clamp(CODE_MIN_Q16, CODE_MAX_Q16);
        let delta = target - self.output_q16 as i64;
        let slewing = delta.abs() > s.slew_q16;
        // Moved by at most |delta| towards a target in the range: still in it. (`max`/`min`
        // rather than `clamp`: the same for a slew limit of at least 1, without its check.)
        self.output_q16 += delta.max(-s.slew_q16).min(s.slew_q16) as i32;
        // In the range [-2^31, 2^31 - 2^16], (output + 2^15) >> 16 is always an i16: no clamp.
        let code = ((self.output_q16 + (1 << 15)) >> 16) as i16;
        FeedforwardTick { dac_code: code, saturated, slewing }
    }

    /// The largest change of DAC code one tick may make under the current slew limit.
    pub fn max_step_codes(&self) -> i32 {
        ((self.scaled.slew_q16 + ONE_Q16 - 1) >> 16) as i32 + 1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stage(params: FeedforwardParams) -> Feedforward {
        let (stage, check) = Feedforward::new(params);
        assert_eq!(check, Ok(()));
        stage
    }

    #[test]
    fn absurd_parameters_are_rejected_and_the_old_kept() {
        let mut ff = stage(FeedforwardParams::default());
        for (bad, err) in [
            (FeedforwardParams { k_dv_um_per_v: 0.0, ..Default::default() }, ParamError::KDv),
            (FeedforwardParams { k_dv_um_per_v: f32::NAN, ..Default::default() }, ParamError::KDv),
            (FeedforwardParams { k_dv_um_per_v: 1e9, ..Default::default() }, ParamError::KDv),
            (FeedforwardParams { k_vc_pulses_per_v: -1.0, ..Default::default() }, ParamError::KVc),
            (FeedforwardParams { offset_v: 7.0, ..Default::default() }, ParamError::Offset),
            (FeedforwardParams { slew_v_per_tick: 0.0, ..Default::default() }, ParamError::Slew),
            (FeedforwardParams { dac_full_scale_v: f32::INFINITY, ..Default::default() }, ParamError::DacFullScale),
            (FeedforwardParams { enable_ramp_ticks: u32::MAX, ..Default::default() }, ParamError::EnableRamp),
        ] {
            assert_eq!(ff.set_params(bad), Err(err));
            assert_eq!(ff.params(), &FeedforwardParams::default());
        }
        let (fallback, check) = Feedforward::new(FeedforwardParams { k_dv_um_per_v: 0.0, ..Default::default() });
        assert_eq!(check, Err(ParamError::KDv));
        assert_eq!(fallback.params(), &FeedforwardParams::default());
    }

    #[test]
    fn settled_output_is_equation_5() {
        let params = FeedforwardParams {
            k_dv_um_per_v: 2.0,
            offset_v: 0.01,
            enable_ramp_ticks: 1,
            slew_v_per_tick: 10.0,
            ..Default::default()
        };
        let mut ff = stage(params);
        ff.set_enabled(true);
        let mut tick = ff.tick(0, true);
        for _ in 0..3 {
            tick = ff.tick(1_000_000, true);
        }
        // DE = 1 um -> u = -1 um -> -0.5 V - 0.01 V = -0.51 V = -1671.0 codes at 10 V / 32767.
        let expected = (-0.51f64 / (10.0 / 32767.0)).round() as i16;
        assert!((tick.dac_code - expected).abs() <= 1, "{} vs {expected}", tick.dac_code);
    }

    #[test]
    fn enabling_disabling_and_offset_changes_never_step_beyond_the_slew_limit() {
        let params = FeedforwardParams { slew_v_per_tick: 0.01, enable_ramp_ticks: 10, ..Default::default() };
        let mut ff = stage(params);
        let limit = ff.max_step_codes();
        let mut last = ff.tick(0, true).dac_code;
        let mut check = |ff: &mut Feedforward, de: i32, trusted: bool| {
            let code = ff.tick(de, trusted).dac_code;
            assert!((code as i32 - last as i32).abs() <= limit, "step {last} -> {code} beyond {limit}");
            last = code;
        };
        for k in 0..2000 {
            if k == 100 {
                ff.set_enabled(true);
            }
            if k == 600 {
                ff.set_params(FeedforwardParams { offset_v: 4.0, ..params }).unwrap();
            }
            if k == 1200 {
                ff.set_enabled(false);
            }
            check(&mut ff, if k % 2 == 0 { 9_000_000 } else { -9_000_000 }, k < 1500);
        }
    }

    #[test]
    fn saturation_clamps_and_is_reported() {
        let mut ff = stage(FeedforwardParams { slew_v_per_tick: 10.0, enable_ramp_ticks: 1, ..Default::default() });
        ff.set_enabled(true);
        ff.tick(0, true);
        let tick = ff.tick(i32::MIN, true);
        assert!(tick.saturated);
        assert_eq!(tick.dac_code, i16::MAX);
        // Full scale to the opposite full scale takes three ticks at a full-scale slew limit.
        assert_eq!(ff.tick(i32::MAX, true).dac_code, 0);
        ff.tick(i32::MAX, true);
        let tick = ff.tick(i32::MAX, true);
        assert!(tick.saturated);
        assert_eq!(tick.dac_code, i16::MIN);
    }

    /// The tick as first written, all in 64 bits: the narrower arithmetic must give the same
    /// codes and flags, bit for bit.
    fn wide_tick(
        s: &Scaled,
        output_q16: &mut i64,
        gain_q16: &mut i64,
        enabled: bool,
        de_pred_pm: i32,
        trusted: bool,
    ) -> FeedforwardTick {
        let gain_target = if enabled && trusted { ONE_Q16 } else { 0 };
        let step = s.gain_step_q16 as i64;
        *gain_q16 = if *gain_q16 < gain_target {
            (*gain_q16 + step).min(gain_target)
        } else {
            (*gain_q16 - step).max(gain_target)
        };
        const LIMIT_Q16: i64 = 1 << 40;
        let product_q48 = (de_pred_pm as i64).wrapping_neg().wrapping_mul(s.codes_per_pm_q32);
        let correction_q16 = (product_q48 >> 16).clamp(-LIMIT_Q16, LIMIT_Q16);
        let mut target = ((correction_q16 * *gain_q16) >> 16) - s.offset_q16;
        let saturated = !(CODE_MIN_Q16..=CODE_MAX_Q16).contains(&target);
        target = target.clamp(CODE_MIN_Q16, CODE_MAX_Q16);
        let delta = target - *output_q16;
        let slewing = delta.abs() > s.slew_q16;
        *output_q16 += delta.clamp(-s.slew_q16, s.slew_q16);
        let code = ((*output_q16 + (1 << 15)) >> 16).clamp(i16::MIN as i64, i16::MAX as i64) as i16;
        FeedforwardTick { dac_code: code, saturated, slewing }
    }

    #[test]
    fn the_tick_is_the_64_bit_one_bit_for_bit() {
        let mut seed = 0x9e37_79b9u64;
        let mut rng = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        let mut checked = 0;
        for round in 0..400 {
            let fs = [1e-3f32, 0.5, 10.0, 100.0][round % 4];
            let unit = |r: u64| (r % 1_000_001) as f32 * 1e-6;
            let params = FeedforwardParams {
                k_dv_um_per_v: [1e-4f32, -1e-4, 0.0656, -0.0656, 1.0, -3.7, 1e4, -1e4][(rng() % 8) as usize]
                    * (0.5 + unit(rng())),
                dac_full_scale_v: fs,
                offset_v: fs / 2.0 * (2.0 * unit(rng()) - 1.0),
                slew_v_per_tick: fs * unit(rng()).max(1e-6),
                enable_ramp_ticks: [0, 1, 3, 100, 4_800_000][(rng() % 5) as usize],
                ..FeedforwardParams::default()
            };
            if params.validate().is_err() {
                continue;
            }
            let mut ff = stage(params);
            let (mut output, mut gain) = (0i64, 0i64);
            for k in 0..3000 {
                if k % 500 == 0 {
                    ff.set_enabled(rng() % 4 != 0);
                }
                let de = match rng() % 6 {
                    0 => i32::MIN,
                    1 => i32::MAX,
                    2 => (rng() as i32) >> (rng() % 32),
                    _ => (rng() % 20_000_001) as i32 - 10_000_000,
                };
                let trusted = rng() % 50 != 0;
                let expected = wide_tick(&ff.scaled, &mut output, &mut gain, ff.enabled, de, trusted);
                assert_eq!(ff.tick(de, trusted), expected, "{params:?} tick {k}");
                assert_eq!(i64::from(ff.output_q16), output);
                assert_eq!(i64::from(ff.gain_q16), gain);
            }
            checked += 1;
        }
        assert!(checked > 150, "{checked}");
    }

    #[test]
    fn extreme_inputs_never_overflow() {
        let mut accepted = 0;
        for k_dv in [1e-4f32, -1e-4, 0.0656, -0.0656, 1e4, -1e4] {
            for fs in [1e-3f32, 1.0, 100.0] {
                let params = FeedforwardParams {
                    k_dv_um_per_v: k_dv,
                    dac_full_scale_v: fs,
                    slew_v_per_tick: fs,
                    offset_v: fs / 2.0,
                    ..Default::default()
                };
                if params.validate().is_err() {
                    continue;
                }
                accepted += 1;
                let mut ff = stage(params);
                ff.set_enabled(true);
                for de in [i32::MIN, i32::MAX, 0, -1, 1] {
                    for _ in 0..3 {
                        ff.tick(de, true);
                    }
                }
            }
        }
        // The smallest accepted scales (2 pm per code) are among those exercised.
        assert!(accepted >= 6, "{accepted}");
        let tiny = FeedforwardParams { k_dv_um_per_v: 1e-4, dac_full_scale_v: 1.0, ..Default::default() };
        assert_eq!(tiny.validate(), Err(ParamError::KDv));
    }
}
