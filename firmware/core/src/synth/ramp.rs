//! A value moving linearly to a target over a number of ticks: how the synthesiser's
//! amplitudes and phase offsets follow model updates without stepping the output.

#[cfg(doc)]
use super::Synth;
#[cfg(doc)]
use crate::math::{harmonic_pm, um_to_pm};
use crate::math::{mul_hi, sin_q31};

/// Largest amplitude a [`Ramp`] holds, picometres: [`um_to_pm`] saturates at 1 mm.
const RAMP_AMP_LIMIT_PM: i32 = 1_000_000_000;

/// [`harmonic_pm`] for `|amp_pm| < 2^30` (every [`Ramp`]): `(2 amp * sin) >> 32`, the same
/// value with one high-word multiply.
#[inline(always)]
pub(super) fn ramp_harmonic_pm(amp_pm: i32, phase_turns: u32) -> i32 {
    debug_assert!(amp_pm.unsigned_abs() <= RAMP_AMP_LIMIT_PM as u32);
    mul_hi(amp_pm << 1, sin_q31(phase_turns))
}

/// A value moving linearly to a target over a number of ticks. The per-tick steps are
/// computed once, at the retarget, with 32-bit division (a single instruction on a
/// Cortex-M4; 64-bit division is a library call of a hundred), so a tick only adds. All
/// ramps of a synthesiser are retargeted together, so one tick counter
/// ([`Synth`]`::ramp_left`) serves them all and a settled tick skips them.
///
/// Amplitudes stay within +-[`RAMP_AMP_LIMIT_PM`]: targets come from [`um_to_pm`] and the
/// steps never overshoot (`|k step| < |target - start|` for `k` below the ramp length).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct Ramp {
    pub(super) amp_pm: i32,
    pub(super) phase_turns: u32,
    pub(super) amp_target_pm: i32,
    pub(super) phase_target_turns: u32,
    pub(super) amp_step_pm: i32,
    pub(super) phase_step_turns: i32,
}

impl Ramp {
    pub(super) const IDLE: Self = Self {
        amp_pm: 0,
        phase_turns: 0,
        amp_target_pm: 0,
        phase_target_turns: 0,
        amp_step_pm: 0,
        phase_step_turns: 0,
    };

    /// Sets the target, reached after `ramp_ticks` steps (at once for 0).
    pub(super) fn retarget(&mut self, amp_pm: i32, phase_turns: u32, ramp_ticks: u32) {
        self.amp_target_pm = amp_pm;
        self.phase_target_turns = phase_turns;
        if ramp_ticks == 0 {
            self.amp_pm = amp_pm;
            self.phase_turns = phase_turns;
            return;
        }
        let n = ramp_ticks.min(i32::MAX as u32) as i32;
        // |amp| <= 1e9 pm, so the difference fits in i32; clamp anyway.
        let amp_delta = (amp_pm as i64 - self.amp_pm as i64).clamp(i32::MIN as i64, i32::MAX as i64) as i32;
        self.amp_step_pm = amp_delta / n;
        // Shorter way round: the wrapped difference read as signed.
        self.phase_step_turns = (phase_turns.wrapping_sub(self.phase_turns) as i32) / n;
    }

    /// One step of a ramp with more than one tick left.
    #[inline]
    pub(super) fn step(&mut self) {
        self.amp_pm = self.amp_pm.saturating_add(self.amp_step_pm);
        self.phase_turns = self.phase_turns.wrapping_add(self.phase_step_turns as u32);
    }

    /// `ticks` calls of [`Ramp::step`]: with a constant step the sums are monotonic, so one
    /// saturation at the end is the same as saturating at every step.
    pub(super) fn step_n(&mut self, ticks: u32) {
        let amp = self.amp_pm as i64 + self.amp_step_pm as i64 * ticks as i64;
        self.amp_pm = amp.clamp(i32::MIN as i64, i32::MAX as i64) as i32;
        self.phase_turns = self.phase_turns.wrapping_add((self.phase_step_turns as u32).wrapping_mul(ticks));
    }

    /// The last step: exactly onto the target.
    #[inline]
    pub(super) fn finish(&mut self) {
        self.amp_pm = self.amp_target_pm;
        self.phase_turns = self.phase_target_turns;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::harmonic_pm;
    use crate::synth::tests::rng;

    #[test]
    fn the_ramp_harmonic_is_the_plain_one_bit_for_bit() {
        let mut seed = 7u64;
        for k in 0..200_000 {
            let amp = match k % 4 {
                0 => RAMP_AMP_LIMIT_PM,
                1 => -RAMP_AMP_LIMIT_PM,
                _ => (rng(&mut seed) % (2 * RAMP_AMP_LIMIT_PM as u64 + 1)) as i64 as i32 - RAMP_AMP_LIMIT_PM,
            };
            let phase = rng(&mut seed) as u32;
            assert_eq!(ramp_harmonic_pm(amp, phase), harmonic_pm(amp, phase), "amp {amp} phase {phase:#x}");
        }
    }

    #[test]
    fn a_ramps_steps_at_once_are_its_steps_one_by_one() {
        let mut seed = 5u64;
        for _ in 0..20_000 {
            let mut ramp = Ramp::IDLE;
            ramp.amp_pm = (rng(&mut seed) % 2_000_000_001) as i32 - 1_000_000_000;
            ramp.phase_turns = rng(&mut seed) as u32;
            let n = 1 + (rng(&mut seed) % 400) as u32;
            ramp.retarget((rng(&mut seed) % 2_000_000_001) as i32 - 1_000_000_000, rng(&mut seed) as u32, n);
            let ticks = (rng(&mut seed) % u64::from(n)) as u32;
            let mut one_by_one = ramp;
            for _ in 0..ticks {
                one_by_one.step();
            }
            ramp.step_n(ticks);
            assert_eq!(ramp, one_by_one);
        }
    }
}
