//! What the accelerometer says the tool did at the command frequency, read at low priority
//! from the window's block sums: the error left between the command and the tool (as a
//! fraction of the stroke) and how much of the accelerometer's power the commanded motion
//! holds.
//!
//! The block sums are least-squares fitted with a mean, `sin` and `cos` of the command
//! phase at each block's centre (exact for any number of periods, not only whole ones; the
//! phase of the ticks before the request comes from its phase and step, as for the axis
//! twin's compensator: exact for a command at a steady frequency, as in a cut). A block of
//! 16 samples scales a sine of `w` rad per tick by `sin(8 w) / sin(w / 2)`; it is divided
//! out. The tool's position is the acceleration over `-(2 pi f)^2`. The command's
//! fundamental is fitted the same way on the command positions the rings keep with each
//! block (its last sample's, stored with the block sum), so no convention between the
//! command's phase and its position is assumed, and a slow drift or a changing stroke
//! within the window counts as it does for the accelerometer.
//!
//! The accelerometer's own gain and phase (its filters) are not known here: they bias the
//! error by a few per cent of the stroke, the same with and without compensation, which
//! is what the supervisor's stroke tolerance is for.
//!
//! What the fundamental leaves is split into what repeats from period to period and what
//! does not: the residual block sums, averaged in [`PHASE_BINS`] bins of the command phase,
//! give the power at the command's harmonics (a synchronous average: friction's,
//! hysteresis' and ripple's error repeats with the command), and their scatter within the
//! bins the noise, whose share of the bin means is taken out (it adds `bins - 3` times the
//! noise variance to their sum of squares). The gate counts the harmonics with the
//! command's motion; the shaking trip still weighs everything at other frequencies.

use serde::{Deserialize, Serialize};

use crate::features::{Capture, SpectralRings, BLOCK_SAMPLES};

/// The motion at the command frequency over one feature window.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MotionEstimate {
    /// Command frequency, Hz (negative for a command running backwards).
    pub freq_hz: f32,
    /// Amplitude of the command's fundamental over the window, nm.
    pub cmd_amp_nm: f32,
    /// Amplitude of the command minus the tool's motion at the command frequency, over
    /// `cmd_amp_nm`.
    pub error_ratio: f32,
    /// The noise in `error_ratio`: the standard error of the fitted motion at the command
    /// frequency (both its components), from the scatter of what does not repeat, over
    /// `cmd_amp_nm`. At low speed, where the accelerometer barely sees the motion, it is
    /// several per cent of the stroke.
    pub error_ratio_sd: f32,
    /// The power of the commanded motion's acceleration plus `harmonic_power_m2ps4`, over the
    /// former plus the accelerometer's power at other frequencies: near 1 where the
    /// accelerometer sees what repeats with the command, near 0 where it sees mostly noise
    /// (on which the twin's features are then measured).
    pub motion_share: f32,
    /// The accelerometer's power at the command frequency, (m/s^2)^2.
    pub motion_power_m2ps4: f32,
    /// The accelerometer's power at all other frequencies (its variance less the power at
    /// the command frequency), (m/s^2)^2: noise, harmonics, and the structure shaken by a
    /// correction.
    pub other_power_m2ps4: f32,
    /// The part of `other_power_m2ps4` at the command's harmonics that repeats from period
    /// to period (friction's, hysteresis' and ripple's motion), (m/s^2)^2: signal, not noise.
    pub harmonic_power_m2ps4: f32,
}

/// Fewest command periods the window must hold for an estimate.
const MIN_PERIODS: f32 = 1.0;
/// Highest command frequency, as a fraction of the block rate (blocks of 16 at 8 kHz: 500
/// Hz), so that the block sums resolve it.
const MAX_FREQ_OF_BLOCK_RATE: f32 = 0.4;
/// Smallest command amplitude judged, nm: below it there is no motion to compensate.
const MIN_CMD_AMP_NM: f32 = 10.0;
/// Bins of the command phase over which the harmonics are averaged (a power of two: the
/// top bits of the phase in turns pick the bin). 64 resolve the harmonics up to about the
/// twentieth, where friction's pulse after a reversal lies at low speed (with 32, a square
/// wave's harmonics showed 72% of their power, with 64, 80%: the 16-sample blocks smooth
/// the rest).
pub const PHASE_BINS: usize = 64;

/// Sums for a least-squares fit of samples `y` by a mean, `sin` and `cos` of the command
/// phase.
#[derive(Clone, Copy, Default)]
struct SineSums {
    n: f32,
    s: f32,
    c: f32,
    ss: f32,
    sc: f32,
    cc: f32,
    y: f32,
    ys: f32,
    yc: f32,
    yy: f32,
}

impl SineSums {
    fn add(&mut self, y: f32, s: f32, c: f32) {
        self.n += 1.0;
        self.yy += y * y;
        self.s += s;
        self.c += c;
        self.ss += s * s;
        self.sc += s * c;
        self.cc += c * c;
        self.y += y;
        self.ys += y * s;
        self.yc += y * c;
    }

    /// The variances of the `sin` and `cos` coefficients per unit variance of the samples'
    /// noise (the diagonal of the inverse normal matrix, the mean taken out).
    fn coefficient_variances(&self) -> (f32, f32) {
        let n = self.n;
        let (css, csc, ccc) =
            (self.ss - self.s * self.s / n, self.sc - self.s * self.c / n, self.cc - self.c * self.c / n);
        let det = css * ccc - csc * csc;
        (ccc / det, css / det)
    }

    /// The `sin` and `cos` coefficients, the mean taken out; `None` unless well posed (at
    /// least a period gives a determinant near `(n / 2)^2`).
    fn fit(&self) -> Option<(f32, f32)> {
        let n = self.n;
        let (css, csc, ccc) =
            (self.ss - self.s * self.s / n, self.sc - self.s * self.c / n, self.cc - self.c * self.c / n);
        let (cys, cyc) = (self.ys - self.y * self.s / n, self.yc - self.y * self.c / n);
        let det = css * ccc - csc * csc;
        if det.is_nan() || det <= 0.05 * n * n {
            return None;
        }
        Some(((cys * ccc - cyc * csc) / det, (cyc * css - cys * csc) / det))
    }
}

/// Sums per bin of the command phase: blocks, block sums, and the fundamental's `sin` and
/// `cos` at them (so that the fundamental's fit can be taken out of the bin means after it).
#[derive(Clone, Copy, Default)]
struct PhaseBin {
    n: f32,
    y: f32,
    s: f32,
    c: f32,
}

/// The block sums' residual power at the command's harmonics that repeats from period to
/// period, per block, from `bins` and the fit `y ~ mean + p sin + q cos` of `sums` (zero
/// where it cannot be told from the noise), and the variance of what does not repeat (the
/// noise), per block.
fn repeating_residual_power(bins: &[PhaseBin; PHASE_BINS], sums: &SineSums, p: f32, q: f32) -> (f32, f32) {
    let n = sums.n;
    let (s_mean, c_mean) = (sums.s / n, sums.c / n);
    let intercept = sums.y / n - p * s_mean - q * c_mean;
    // Residual sum of squares of the fit (the fitted part of the centred sum taken out).
    let centred_yy = sums.yy - sums.y * sums.y / n;
    let centred_ys = sums.ys - sums.y * s_mean;
    let centred_yc = sums.yc - sums.y * c_mean;
    let residual_ss = centred_yy - p * centred_ys - q * centred_yc;
    let (mut between_ss, mut filled) = (0.0f32, 0.0f32);
    for bin in bins.iter().filter(|b| b.n > 0.0) {
        let residual = bin.y - bin.n * intercept - p * bin.s - q * bin.c;
        between_ss += residual * residual / bin.n;
        filled += 1.0;
    }
    let within_dof = n - filled;
    if within_dof < 1.0 || residual_ss.is_nan() || residual_ss <= 0.0 {
        // Too few blocks to tell: all of it counts as noise.
        return (0.0, residual_ss.max(0.0) / (n - 3.0).max(1.0));
    }
    let noise_variance = (residual_ss - between_ss).max(0.0) / within_dof;
    let harmonic_ss = between_ss - (filled - 3.0).max(0.0) * noise_variance;
    if harmonic_ss.is_finite() {
        (harmonic_ss.max(0.0) / n, noise_variance)
    } else {
        (0.0, noise_variance)
    }
}

/// The estimate for the window of `capture`, whose request came at command phase
/// `cmd_phase_turns` with step `cmd_step_turns` (the phase and position handed in with a
/// tick's input are those of the tick after it, whose output they drive).
/// `variance_m2ps4` is the window's accelerometer variance (feature f3). `None` when the
/// window holds less than a period, the frequency is beyond what the blocks resolve, the
/// command does not move, or the ring was overwritten while read.
pub fn estimate<const RING_BLOCKS: usize>(
    rings: &SpectralRings<RING_BLOCKS>,
    capture: &Capture,
    variance_m2ps4: f32,
    cmd_step_turns: i32,
    cmd_phase_turns: u32,
) -> Option<MotionEstimate> {
    const TURN: f32 = 4_294_967_296.0;
    let rate_hz = capture.cfg.sample_rate_hz;
    let w_rad_per_tick = cmd_step_turns as f32 * (core::f32::consts::TAU / TURN);
    let freq_hz = cmd_step_turns as f32 * (rate_hz / TURN);
    let nd = (capture.blocks as usize).min(capture.cfg.window_blocks());
    let periods = nd as f32 * BLOCK_SAMPLES as f32 * cmd_step_turns.unsigned_abs() as f32 / TURN;
    let block_rate_hz = rate_hz / BLOCK_SAMPLES as f32;
    // (Written so that a NaN is refused too.)
    if periods < MIN_PERIODS
        || freq_hz.abs() > MAX_FREQ_OF_BLOCK_RATE * block_rate_hz
        || variance_m2ps4.is_nan()
        || variance_m2ps4 <= 0.0
        || nd == 0
    {
        return None;
    }
    // The phase at the centre of the window's first block: the request's, less the ticks
    // back to its last sample, less 7.5 to its centre, less the tick the phase runs ahead.
    let step = cmd_step_turns as u32;
    let half_step = step.wrapping_add(u32::from(cmd_step_turns < 0)) as i32 >> 1;
    let back_ticks = 8 + capture.partial_len + (BLOCK_SAMPLES * (nd - 1)) as u32;
    let to_rad = |turns: u32| turns as i32 as f32 * (core::f32::consts::TAU / TURN);
    let first_phase = cmd_phase_turns.wrapping_sub(step.wrapping_mul(back_ticks)).wrapping_sub(half_step as u32);
    // Then a rotation by a block's advance per block (three sines per window, not two per
    // block: this runs at low priority within the model latency). The command sample kept
    // with a block (its last input's, for the tick after) is 8.5 ticks after its centre.
    let (mut s, mut c) = libm::sincosf(to_rad(first_phase));
    let (ds, dc) = libm::sincosf(to_rad(step.wrapping_mul(BLOCK_SAMPLES as u32)));
    let (cmd_s, cmd_c) = libm::sincosf(to_rad((step.wrapping_mul(8)).wrapping_add(half_step as u32)));
    let (mut acc, mut cmd) = (SineSums::default(), SineSums::default());
    // Relative to the first block, so that f32 keeps the cross terms exact enough.
    let mut first: Option<(i32, i32)> = None;
    let mut bins = [PhaseBin::default(); PHASE_BINS];
    let (mut block_phase, block_step) = (first_phase, step.wrapping_mul(BLOCK_SAMPLES as u32));
    let read = rings.visit_window(capture, |_, block_sum, _, cmd_nm| {
        let (sum0, cmd0) = *first.get_or_insert((block_sum, cmd_nm));
        let y = (block_sum - sum0) as f32;
        acc.add(y, s, c);
        cmd.add(cmd_nm.wrapping_sub(cmd0) as f32, s * cmd_c + c * cmd_s, c * cmd_c - s * cmd_s);
        let bin = &mut bins[(block_phase >> (32 - PHASE_BINS.trailing_zeros())) as usize];
        (bin.n, bin.y, bin.s, bin.c) = (bin.n + 1.0, bin.y + y, bin.s + s, bin.c + c);
        (s, c) = (s * dc + c * ds, c * dc - s * ds);
        block_phase = block_phase.wrapping_add(block_step);
    });
    if read.ok()? != nd {
        return None;
    }
    let (p_codes, q_codes) = acc.fit()?;
    let (cmd_sin_nm, cmd_cos_nm) = cmd.fit()?;
    let cmd_amp_nm = libm::sqrtf(cmd_sin_nm * cmd_sin_nm + cmd_cos_nm * cmd_cos_nm);
    if cmd_amp_nm.is_nan() || cmd_amp_nm < MIN_CMD_AMP_NM {
        return None;
    }
    // Block sum of a unit sine of w rad per tick.
    let block_gain = libm::sinf(8.0 * w_rad_per_tick) / libm::sinf(0.5 * w_rad_per_tick);
    let acc_mps2 = capture.cfg.acc_mps2_per_lsb / block_gain;
    let w_rad_per_s = w_rad_per_tick * rate_hz;
    // Tool position = -acceleration / w^2, in nm.
    let to_nm = acc_mps2 / (w_rad_per_s * w_rad_per_s) * 1e9;
    let error_sin_nm = cmd_sin_nm + p_codes * to_nm;
    let error_cos_nm = cmd_cos_nm + q_codes * to_nm;
    let error_ratio = libm::sqrtf(error_sin_nm * error_sin_nm + error_cos_nm * error_cos_nm) / cmd_amp_nm;
    let motion_power_m2ps4 = 0.5 * (p_codes * p_codes + q_codes * q_codes) * (acc_mps2 * acc_mps2);
    let other_power_m2ps4 = (variance_m2ps4 - motion_power_m2ps4).max(0.0);
    // A block sum is 16 samples' sum: at the harmonics that matter (well below the block
    // rate) 16 times their mean.
    let sample_mps2 = capture.cfg.acc_mps2_per_lsb / BLOCK_SAMPLES as f32;
    let (harmonic_power_codes, noise_variance_codes) = repeating_residual_power(&bins, &acc, p_codes, q_codes);
    let harmonic_power_m2ps4 = (harmonic_power_codes * (sample_mps2 * sample_mps2)).min(other_power_m2ps4);
    let (var_p, var_q) = acc.coefficient_variances();
    let error_ratio_sd = libm::sqrtf(noise_variance_codes * (var_p + var_q)) * libm::fabsf(to_nm) / cmd_amp_nm;
    // The share is the commanded motion's, not the motion seen: compensation moves the
    // tool towards the command, and above the axis's resonance (the tool then moving
    // against its command) the motion seen passes through zero while it ramps in. What
    // repeats with the command at its harmonics is motion too.
    let command_acc_mps2 = w_rad_per_s * w_rad_per_s * cmd_amp_nm * 1e-9;
    let command_power_m2ps4 = 0.5 * command_acc_mps2 * command_acc_mps2;
    let motion_share = (command_power_m2ps4 + harmonic_power_m2ps4) / (command_power_m2ps4 + other_power_m2ps4);
    (error_ratio.is_finite() && motion_share.is_finite() && error_ratio_sd.is_finite()).then_some(MotionEstimate {
        freq_hz,
        cmd_amp_nm,
        error_ratio,
        error_ratio_sd,
        motion_share,
        motion_power_m2ps4,
        other_power_m2ps4,
        harmonic_power_m2ps4,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::{FeatureConfig, FeatureState};

    /// A tool that follows a 40 Hz, 3 um command with `gain` and `lag_deg`, seen by the
    /// accelerometer (1e-4 m/s^2 per LSB); the estimate's error ratio is
    /// `|1 - gain e^(-i lag)|`.
    fn ratio_for(freq_hz: f64, gain: f64, lag_deg: f64) -> MotionEstimate {
        let cfg = FeatureConfig { window_samples: 800, ..FeatureConfig::DEFAULT };
        let mut state = std::boxed::Box::new(FeatureState::<50>::new(cfg).unwrap());
        let rings = std::boxed::Box::new(SpectralRings::<306>::new());
        let step = (freq_hz / 8000.0 * 4_294_967_296.0).round() as i64 as i32;
        let w = std::f64::consts::TAU * freq_hz;
        let ticks = 1000u32;
        for k in 0..ticks {
            let theta = w * f64::from(k) / 8000.0;
            let acc = -w * w * 3e-6 * gain * (theta - lag_deg.to_radians()).sin();
            // The command handed in with a tick's input is the next tick's, as the phase.
            let cmd = (3000.0 * (theta + w / 8000.0).sin()).round() as i32;
            state.push_with_command(&*rings, (acc / 1e-4).round() as i16, cmd);
        }
        // The phase handed in with the last tick's input: that of the tick after it.
        let phase = (step as u32).wrapping_mul(ticks);
        let capture = state.capture(&*rings);
        let variance = 0.5 * (w * w * 3e-6 * gain).powi(2);
        estimate(&*rings, &capture, variance as f32, step, phase).expect("an estimate")
    }

    #[test]
    fn the_error_ratio_is_what_the_tool_left_of_the_command() {
        for (freq_hz, gain, lag_deg) in [(40.0, 1.0, 0.0), (40.0, 0.5, 0.0), (40.0, 1.0, 30.0), (80.0, 1.5, -20.0)] {
            let est = ratio_for(freq_hz, gain, lag_deg);
            let lag = f64::to_radians(lag_deg);
            let expected = ((1.0 - gain * lag.cos()).powi(2) + (gain * lag.sin()).powi(2)).sqrt();
            assert!(
                (f64::from(est.error_ratio) - expected).abs() < 0.01,
                "{freq_hz} Hz gain {gain} lag {lag_deg}: {} vs {expected}",
                est.error_ratio
            );
            assert!((est.freq_hz - freq_hz as f32).abs() < 1e-3);
            assert!((est.motion_share - 1.0).abs() < 0.01, "{est:?}");
        }
    }

    /// A 10 Hz, 3 um command followed exactly, plus `harmonic_mps2` of a square wave at the
    /// command's phase (friction's force reversing with the velocity) and white noise of
    /// `noise_mps2` RMS, over a window of `window_samples`.
    fn with_harmonics(harmonic_mps2: f64, noise_mps2: f64, window_samples: u32) -> MotionEstimate {
        let cfg = FeatureConfig { window_samples, ..FeatureConfig::DEFAULT };
        let mut state = std::boxed::Box::new(FeatureState::<200>::new(cfg).unwrap());
        let rings = std::boxed::Box::new(SpectralRings::<512>::new());
        let freq_hz = 10.0;
        let step = (freq_hz / 8000.0 * 4_294_967_296.0f64).round() as i64 as i32;
        let w = std::f64::consts::TAU * freq_hz;
        let ticks = window_samples + 160;
        // A deterministic noise: a linear congruential generator's uniform draws.
        let mut lcg = 12345u64;
        let mut uniform = move || {
            lcg = lcg.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (lcg >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let (mut sum, mut sum2) = (0.0, 0.0);
        for k in 0..ticks {
            let theta = w * f64::from(k) / 8000.0;
            let square = if theta.cos() >= 0.0 { 1.0 } else { -1.0 };
            let acc = -w * w * 3e-6 * theta.sin() + harmonic_mps2 * square + noise_mps2 * 12f64.sqrt() * uniform();
            let cmd = (3000.0 * (theta + w / 8000.0).sin()).round() as i32;
            let code = (acc / 1e-4).round() as i16;
            state.push_with_command(&*rings, code, cmd);
            if k >= ticks - window_samples {
                (sum, sum2) = (sum + f64::from(code) * 1e-4, sum2 + (f64::from(code) * 1e-4).powi(2));
            }
        }
        let n = f64::from(window_samples);
        let variance = sum2 / n - (sum / n).powi(2);
        let phase = (step as u32).wrapping_mul(ticks);
        let capture = state.capture(&*rings);
        estimate(&*rings, &capture, variance as f32, step, phase).expect("an estimate")
    }

    #[test]
    fn what_repeats_with_the_command_is_not_noise() {
        // The command's acceleration: 0.0118 m/s^2 at 10 Hz (power 7e-5 (m/s^2)^2).
        let noise_only = with_harmonics(0.0, 0.02, 3200);
        assert!(noise_only.motion_share < 0.3, "{noise_only:?}");
        assert!(
            noise_only.harmonic_power_m2ps4 < 0.1 * noise_only.other_power_m2ps4,
            "noise is not repeating: {noise_only:?}"
        );
        // A square wave of 0.02 m/s^2 (power 4e-4, of which the fundamental's 81%) with
        // little noise: its harmonics repeat.
        let friction = with_harmonics(0.02, 0.001, 3200);
        assert!(friction.motion_share > 0.8, "{friction:?}");
        let harmonics_m2ps4 = 4e-4 * (1.0 - 8.0 / std::f64::consts::PI.powi(2));
        assert!(
            (f64::from(friction.harmonic_power_m2ps4) / harmonics_m2ps4 - 1.0).abs() < 0.2,
            "{friction:?} against {harmonics_m2ps4}"
        );
        // Both: the noise still counts as noise.
        let both = with_harmonics(0.02, 0.02, 3200);
        assert!(both.motion_share < 0.3, "{both:?}");
        // The error ratio's noise: the white noise's through the fit of 200 blocks, 16
        // samples each (per component 0.02 / sqrt(16 x 100) m/s^2 over the motion's 0.0118),
        // whatever repeats beside it.
        let expected_sd = 2f64.sqrt() * 0.02 / (16.0f64 * 100.0).sqrt() / 0.0118;
        for est in [noise_only, both] {
            assert!((f64::from(est.error_ratio_sd) / expected_sd - 1.0).abs() < 0.25, "{est:?} against {expected_sd}");
        }
        assert!(friction.error_ratio_sd < 0.1 * noise_only.error_ratio_sd, "{friction:?}");
    }

    #[test]
    fn no_estimate_without_a_period_or_motion() {
        let cfg = FeatureConfig { window_samples: 800, ..FeatureConfig::DEFAULT };
        let mut state = std::boxed::Box::new(FeatureState::<50>::new(cfg).unwrap());
        let rings = std::boxed::Box::new(SpectralRings::<306>::new());
        let moving = |k: i32| (3000.0 * libm::sin(f64::from(k) * 0.0314)) as i32;
        for k in 0..900 {
            state.push_with_command(&*rings, (k % 7) as i16, moving(k));
        }
        let capture = state.capture(&*rings);
        // 5 Hz: a 0.1 s window holds half a period.
        let step_5hz = (5.0 / 8000.0 * 4_294_967_296.0f64) as i32;
        assert_eq!(estimate(&*rings, &capture, 1.0, step_5hz, 0), None);
        let step_40hz = step_5hz * 8;
        assert_eq!(estimate(&*rings, &capture, 0.0, step_40hz, 0), None, "no variance");
        assert!(estimate(&*rings, &capture, 1.0, step_40hz, 0).is_some());
        // A command standing still.
        let mut still = std::boxed::Box::new(FeatureState::<50>::new(cfg).unwrap());
        let still_rings = std::boxed::Box::new(SpectralRings::<306>::new());
        for k in 0..900 {
            still.push_with_command(&*still_rings, (k % 7) as i16, 1234);
        }
        let capture = still.capture(&*still_rings);
        assert_eq!(estimate(&*still_rings, &capture, 1.0, step_40hz, 0), None, "no motion");
    }
}
