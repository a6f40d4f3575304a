//! The harmonic part of the synthesiser: a model output converted to per-slot targets
//! ([`SynthTargets`]), and the fundamental's and each term slot's ramp and order
//! (`Harmonics`), with the rules by which a change of terms fades the harmonics that go
//! before the terms that replace them start.

use super::ramp::{ramp_harmonic_pm, Ramp};
use super::KernelIndex;
#[cfg(doc)]
use super::Synth;
use crate::math::{deg_to_turns, um_to_pm};
use crate::program::{ModelOutput, TickTerm, MAX_TERMS};

/// A model output converted for the synthesiser: the fundamental's and each harmonic
/// term's amplitude (picometres) and phase offset (turns), from the output registers the
/// terms name. Computing these is most of the cost of a model update (float conversions),
/// so the firmware does it with the model evaluation at low priority, and the servo tick
/// that applies the result ([`Synth::apply`]) only starts the ramps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SynthTargets {
    pub(super) amp_pm: i32,
    pub(super) phase_turns: u32,
    term_amp_pm: [i32; MAX_TERMS],
    term_phase_turns: [u32; MAX_TERMS],
    /// Harmonic order of each term (0 for kernel terms and beyond the terms).
    term_orders: [u32; MAX_TERMS],
    /// Bit `i` set: term `i` is a kernel term.
    pub(super) kernel_mask: u32,
}

impl SynthTargets {
    /// Silence: every amplitude zero (what [`ModelOutput::default`] gives).
    pub const SILENT: Self = Self {
        amp_pm: 0,
        phase_turns: 0,
        term_amp_pm: [0; MAX_TERMS],
        term_phase_turns: [0; MAX_TERMS],
        term_orders: [0; MAX_TERMS],
        kernel_mask: 0,
    };

    /// The targets of `output` for the tick terms `terms` (kernel terms have none).
    pub fn new(output: &ModelOutput, terms: &[TickTerm]) -> Self {
        let mut targets =
            Self { amp_pm: um_to_pm(output.amp_um()), phase_turns: deg_to_turns(output.phase_deg()), ..Self::SILENT };
        for (i, term) in terms.iter().take(MAX_TERMS).enumerate() {
            match *term {
                TickTerm::Harmonic { order, amp_reg, phase_reg } => {
                    let register = |r: u8| output.registers.get(r as usize).copied().unwrap_or(0.0);
                    targets.term_amp_pm[i] = um_to_pm(register(amp_reg));
                    targets.term_phase_turns[i] = deg_to_turns(register(phase_reg));
                    targets.term_orders[i] = u32::from(order);
                }
                // Silent until the axis twin's compensator sets it (`set_harmonic`).
                TickTerm::AxisHarmonic { order } => targets.term_orders[i] = u32::from(order),
                _ => targets.kernel_mask |= 1 << i,
            }
        }
        targets
    }

    /// Makes slot `slot` a harmonic of `order` with amplitude `amp_pm` and phase
    /// `phase_turns`, whatever term the program has there (the servo synthesises the axis
    /// twin's correction so; see `Models::compute`).
    pub fn set_harmonic(&mut self, slot: usize, order: u32, amp_pm: i32, phase_turns: u32) {
        if slot < MAX_TERMS {
            self.term_amp_pm[slot] = amp_pm;
            self.term_phase_turns[slot] = phase_turns;
            self.term_orders[slot] = order;
            self.kernel_mask &= !(1 << slot);
        }
    }
}

/// The harmonic part of a synthesiser: the fundamental's and each term slot's ramp and
/// order. A [`Synth`] holds two: the live one and one where a model update is prepared
/// ahead of its tick ([`Synth::prepare`]), so that applying it is a switch.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Harmonics {
    pub(super) fundamental: Ramp,
    /// Amplitude and phase offset of each slot's harmonic.
    pub(super) ramps: [Ramp; MAX_TERMS],
    /// Harmonic order of each slot (0 for kernel slots).
    pub(super) orders: [u32; MAX_TERMS],
    /// Slots the tick visits.
    pub(super) term_count: usize,
    /// Slots from here on are settled silent (amplitude, target and steps zero, phase at its
    /// target, no kernel): retargeting them to silence again would change nothing.
    idle_from: usize,
    /// Slots whose harmonic ramps out because the terms changed (a program switch, see
    /// [`Harmonics::retarget_terms`]): model updates leave them be, and the fade's last tick
    /// silences them exactly and stops visiting them (`Synth::ramp_left` counts to it).
    fading: u32,
    /// While slots fade: the other ramps' steps left after the fade's last tick (0: they end
    /// with it).
    rest_ticks: u32,
    /// Terms of the update in force: the slots visited once the fade is over.
    count: usize,
    /// The kernel terms' cells (switched with the bank, so that applying a prepared update
    /// is one switch).
    pub(super) kernels: KernelIndex,
}

/// What [`Harmonics::retarget_terms`] decided besides the ramps.
pub(super) struct TermsUpdate {
    /// Kernel slots that run from the update on (those already running and kept, and those
    /// starting from rest).
    pub(super) kernels: u32,
    /// Ticks to the ramps' next event ([`Harmonics::end_ramps`]).
    pub(super) ramp_left: u32,
}

impl Harmonics {
    pub(super) const IDLE: Self = Self {
        fundamental: Ramp::IDLE,
        ramps: [Ramp::IDLE; MAX_TERMS],
        orders: [0; MAX_TERMS],
        term_count: 0,
        idle_from: 0,
        fading: 0,
        rest_ticks: 0,
        count: 0,
        kernels: KernelIndex::INITIAL,
    };

    /// What the ticks of a running ramp end in: every visited value on its target.
    fn settle(&mut self) {
        self.fundamental.finish();
        let count = self.term_count.min(MAX_TERMS);
        self.ramps[..count].iter_mut().for_each(Ramp::finish);
    }

    /// The tick with one ramp tick left: the ramps end, settling on their targets, or a fade
    /// ends ([`Harmonics::end_fade`]) while other ramps run on (this tick holds them, they
    /// step on from the next). Returns the ramp ticks left after it.
    pub(super) fn end_ramps(&mut self) -> u32 {
        if self.fading != 0 {
            self.end_fade();
            if self.rest_ticks != 0 {
                return self.rest_ticks + 1;
            }
        }
        self.settle();
        0
    }

    /// The fade's last tick: the fading slots' amplitudes land on zero exactly (the step of
    /// a ramp's last tick: its step and the remainder the truncated steps left), and only the
    /// update's own terms are visited from now on.
    #[cold]
    fn end_fade(&mut self) {
        let mut fading = self.fading & 0xff;
        while fading != 0 {
            let i = (fading.trailing_zeros() & 7) as usize;
            fading &= fading - 1;
            // Target and phase step are already zero: settled silent.
            self.ramps[i].amp_pm = 0;
            self.ramps[i].amp_step_pm = 0;
        }
        self.fading = 0;
        self.term_count = self.count;
        self.idle_from = self.count;
    }

    /// Whether slot `i`'s harmonic sounds now or by its ramp's end.
    fn sounds(&self, i: usize) -> bool {
        let ramp = &self.ramps[i & 7];
        self.orders[i & 7] != 0 && (ramp.amp_pm != 0 || ramp.amp_target_pm != 0)
    }

    /// The harmonics of the slots in `slots` (bits) for command phase `cmd_phase_turns`,
    /// stepping their ramps first when `ramping`; picometres.
    #[inline(always)]
    pub(super) fn harmonic_slots_pm(&mut self, slots: u32, ramping: bool, cmd_phase_turns: u32) -> i64 {
        let mut total = 0i64;
        // Masked to MAX_TERMS = 8 slots: no index can be out of bounds.
        let mut visit = slots & 0xff;
        while visit != 0 {
            let i = (visit.trailing_zeros() & 7) as usize;
            visit &= visit - 1;
            let ramp = &mut self.ramps[i];
            if ramping {
                ramp.step();
            }
            let phase = cmd_phase_turns.wrapping_mul(self.orders[i]).wrapping_add(ramp.phase_turns);
            total += ramp_harmonic_pm(ramp.amp_pm, phase) as i64;
        }
        total
    }

    /// Starts the term slots' ramps to `targets` for `count` terms over `ramp` ticks, with
    /// `ramp_left` ticks to the ramps' next event before the update. `running` marks the
    /// slots whose kernel term runs, `kept` those of them whose term stays (the same term in
    /// the same slot: it runs on with its state).
    ///
    /// A harmonic that has to go (its slot is beyond the terms, or holds another kind of
    /// term now) ramps out over `ramp` ticks and is then dropped: the fade. It starts when
    /// the terms change (a program switch), and later updates neither restart nor retarget
    /// it, so it ends `ramp` ticks after the switch however often model updates come
    /// (restarting it with truncated steps would leave an amplitude below `ramp` pm short of
    /// zero for good). Meanwhile the terms that replace a fading harmonic in its slot, and any
    /// kernel term that is not kept, wait: they start with the first update after the fade
    /// (a harmonic from silence, a kernel from rest), so that the tick never runs the old
    /// harmonics beside new kernel terms and stays within the budget of the programs on
    /// either side (see [`crate::program::tick_cost`]). New harmonics in free slots start at
    /// once, kernel terms that go stop at once (as before: they have no ramp).
    pub(super) fn retarget_terms(
        &mut self,
        targets: &SynthTargets,
        count: usize,
        running: u32,
        kept: u32,
        ramp_left: u32,
        ramp: u32,
    ) -> TermsUpdate {
        let count = count.min(MAX_TERMS);
        // Masked to MAX_TERMS = 8 slots: no index below can be out of bounds.
        let in_update = ((1u32 << count) - 1) & 0xff;
        let kernel_slots = targets.kernel_mask & in_update;
        let mut fading = self.fading;
        let mut new_fading = 0u32;
        let mut harmonics = !targets.kernel_mask & in_update;
        while harmonics != 0 {
            let i = (harmonics.trailing_zeros() & 7) as usize;
            let bit = harmonics & harmonics.wrapping_neg();
            harmonics &= harmonics - 1;
            let order = targets.term_orders[i];
            let phase = targets.term_phase_turns[i];
            if self.orders[i] == order && running & bit == 0 {
                // The same harmonic, also one that was fading: on from where it is.
                fading &= !bit;
            } else if self.sounds(i) {
                // Another harmonic sounds in the slot: it ramps out first.
                new_fading |= bit & !fading;
                continue;
            } else {
                // A new kind of term starts from silence at its own phase. (Its kernel state
                // is not read while it is a harmonic, and is reset when it becomes a kernel.)
                self.orders[i] = order;
                self.ramps[i] = Ramp { phase_turns: phase, ..Ramp::IDLE };
                fading &= !bit;
            }
            self.ramps[i].retarget(targets.term_amp_pm[i], phase, ramp);
        }
        let mut kernels = kernel_slots & !kept;
        while kernels != 0 {
            let i = (kernels.trailing_zeros() & 7) as usize;
            let bit = kernels & kernels.wrapping_neg();
            kernels &= kernels - 1;
            if self.sounds(i) {
                // A harmonic sounds in the slot: it ramps out first.
                new_fading |= bit & !fading;
            } else {
                // Silent: the slot is the kernel's (its ramp stays idle).
                self.orders[i] = 0;
                self.ramps[i] = Ramp::IDLE;
                fading &= !bit;
            }
        }
        // Beyond the terms: harmonics ramp out, kernel terms stop.
        let mut idle_from = count;
        for i in count..self.idle_from.max(count) {
            let bit = 1 << i;
            if fading & bit != 0 {
                continue;
            }
            if self.sounds(i) {
                new_fading |= bit;
                continue;
            }
            let slot = &mut self.ramps[i];
            let phase = slot.phase_turns;
            slot.retarget(0, phase, ramp);
            if slot.amp_pm != 0 {
                idle_from = i + 1;
            }
        }
        fading |= new_fading;
        let ramp_left = if new_fading != 0 || (fading != 0 && (ramp < ramp_left || ramp_left == 0)) {
            // A fade starts (or the update's ramps would end before the fade does; or no
            // event is due, which a fade always has): every fading harmonic ramps out from
            // where it is, in step with the update's ramps.
            let mut restart = fading & 0xff;
            while restart != 0 {
                let i = (restart.trailing_zeros() & 7) as usize;
                restart &= restart - 1;
                let slot = &mut self.ramps[i];
                let phase = slot.phase_turns;
                slot.retarget(0, phase, ramp);
                if slot.amp_pm == 0 {
                    // At once (no ramp): gone.
                    fading &= !(1 << i);
                }
            }
            self.rest_ticks = 0;
            ramp
        } else if fading != 0 {
            // The fade runs on to its end; the update's ramps go on after it.
            self.rest_ticks = ramp - ramp_left;
            ramp_left
        } else {
            self.rest_ticks = 0;
            ramp
        };
        let fading_to = (32 - fading.leading_zeros()) as usize;
        self.fading = fading;
        self.count = count;
        self.term_count = count.max(fading_to);
        self.idle_from = idle_from.max(fading_to);
        // Kernel terms that are not kept wait while harmonics fade.
        let kernels = if fading != 0 { kernel_slots & kept } else { kernel_slots };
        TermsUpdate { kernels, ramp_left }
    }

    /// The state after `ticks` ticks of synthesis ([`Synth::next_input`]) with `ramp_left`
    /// ticks to the ramps' next event, and the ramp ticks left then.
    pub(super) fn advanced(mut self, mut ramp_left: u32, mut ticks: u32) -> (Self, u32) {
        while ramp_left != 0 && ticks != 0 {
            if ticks < ramp_left {
                self.step_n(ticks);
                return (self, ramp_left - ticks);
            }
            // Steps up to the event's tick, then the event (which settles every ramp that
            // ends with it: stepping those first would change nothing).
            if self.fading != 0 && self.rest_ticks != 0 {
                self.step_n(ramp_left - 1);
            }
            ticks -= ramp_left;
            ramp_left = self.end_ramps();
        }
        (self, ramp_left)
    }

    /// `ticks` steps of every visited ramp.
    fn step_n(&mut self, ticks: u32) {
        self.fundamental.step_n(ticks);
        let count = self.term_count.min(MAX_TERMS);
        self.ramps[..count].iter_mut().for_each(|ramp| ramp.step_n(ticks));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::program::TermInput;
    use crate::synth::tests::{harmonic_output, harmonic_terms, output};
    use crate::synth::{Synth, TickInput};

    #[test]
    fn harmonic_terms_add_at_their_order_and_ramp_out() {
        let mut synth = Synth::new(0);
        let mut out = output(0.0, 0.0);
        out.registers[2] = 1.0;
        out.registers[3] = 0.0;
        let term = TickTerm::Harmonic { order: 3, amp_reg: 2, phase_reg: 3 };
        synth.update(&out, &[term]);
        // theta = 30 degrees -> sin(90 degrees) = 1 um.
        assert!((synth.next(deg_to_turns(30.0)) - 1_000_000).abs() < 50);
        synth.ramp_ticks = 10;
        synth.update(&out, &[]);
        for _ in 0..10 {
            synth.next(0);
        }
        assert_eq!(synth.next(deg_to_turns(30.0)), 0);
    }

    #[test]
    fn harmonics_that_go_reach_zero_exactly_and_are_dropped_under_updates_faster_than_the_ramp() {
        // The schedules of the 2,000 and 800 sample windows: an update every 112 ticks (the
        // ramps settle in between) and every 48 (they never do).
        for interval in [112u32, 48] {
            let mut synth = Synth::new(80);
            synth.update(&harmonic_output(), &harmonic_terms(&[2, 3, 4, 5, 6, 7, 8, 9]));
            for _ in 0..100 {
                synth.next(0);
            }
            let two = harmonic_terms(&[2, 3]);
            let mut theta = 0u32;
            for k in 0..3000u32 {
                if k % interval == 0 {
                    synth.update(&harmonic_output(), &two);
                }
                theta = theta.wrapping_add(0x0147_ae14);
                synth.next(theta);
                let h = synth.harmonics();
                if k < 79 {
                    // Ramping out (the 50 pm ones too: they hold until the last tick).
                    assert_eq!(h.term_count, 8, "interval {interval} tick {k}");
                    assert!(
                        h.ramps[2..].iter().all(|r| r.amp_pm != 0 && r.amp_target_pm == 0),
                        "interval {interval} tick {k}"
                    );
                } else {
                    // From the fade's last tick (80 ticks from the switch) on: exactly zero and
                    // no longer visited, however often the updates came.
                    assert_eq!((h.term_count, h.idle_from, h.fading), (2, 2, 0), "interval {interval} tick {k}");
                    assert!(
                        h.ramps[2..].iter().all(|r| r.amp_pm == 0
                            && r.amp_step_pm == 0
                            && r.amp_target_pm == 0
                            && r.phase_step_turns == 0),
                        "interval {interval} tick {k}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_switch_to_kernel_terms_ramps_the_harmonics_out_before_the_kernels_start() {
        let sine = |phase_turns| TickTerm::Laguerre {
            input: TermInput::PositionSine { turns_per_nm: 4295, phase_turns },
            pole_q30: 998_579_896,
            gains_pm: [180_000, -95_000, 61_000, -40_000, 22_000, -15_000, 9_000, -4_000],
        };
        let banks = [sine(0), sine(1 << 30)];
        let out = harmonic_output();
        let eight = harmonic_terms(&[2, 3, 4, 5, 6, 7, 8, 9]);
        // A held command: the harmonics change only by their ramps. Per tick a ramp moves its
        // amplitude by its step (at most 1.5 um / 80), on its last tick by the remainder of
        // the truncated steps too (below 80 pm); the sine's rounding adds a picometre.
        let input = TickInput { cmd_phase_turns: 0x2345_6789, cmd_pos_nm: 1234, ..TickInput::default() };
        let bound: i64 = eight.iter().map(|_| 1_500_000 / 80 + 80 + 1).sum();
        for interval in [112u32, 48] {
            let mut synth = Synth::new(80);
            synth.update(&out, &eight);
            for _ in 0..100 {
                synth.next_input(&input);
            }
            let mut last = synth.next_input(&input);
            let (mut fade_end, mut kernels_start) = (None, None);
            for k in 0..1000u32 {
                if k % interval == 0 {
                    synth.update(&out, &banks);
                }
                let now = synth.next_input(&input);
                let h = synth.harmonics();
                if h.fading == 0 {
                    fade_end.get_or_insert(k);
                }
                if h.kernels.kernel_count == 0 {
                    assert!(
                        (i64::from(now) - i64::from(last)).abs() <= bound,
                        "interval {interval} tick {k}: {last} -> {now}"
                    );
                } else {
                    // Only once the old harmonics are gone (silent, not visited).
                    assert_eq!((h.fading, h.term_count), (0, 2), "interval {interval} tick {k}");
                    assert!(h.ramps.iter().all(|r| r.amp_pm == 0), "interval {interval} tick {k}");
                    kernels_start.get_or_insert(k);
                }
                last = now;
            }
            // The fade ends on the 80th tick after the switch, the banks start with the first
            // update after it.
            assert_eq!(fade_end, Some(79), "interval {interval}");
            assert_eq!(kernels_start, Some(79_u32.div_ceil(interval) * interval), "interval {interval}");
            assert_eq!(synth.harmonics().kernels.kernel_count, 2);
        }
    }

    #[test]
    fn a_kept_kernel_term_runs_on_through_a_switch_and_a_new_order_waits_for_the_old_one() {
        let bank = TickTerm::Laguerre {
            input: TermInput::VelocitySign { smooth_nm_per_4_ticks: 300 },
            pole_q30: 998_579_896,
            gains_pm: [90_000, -40_000, 20_000, 0, 0, 0, 0, 0],
        };
        let drift = TickTerm::Drift { offset_pm: 200_000, decay_pm: -300_000, tau_ticks: 5000 };
        let harmonic = |order, amp_reg| TickTerm::Harmonic { order, amp_reg, phase_reg: amp_reg + 1 };
        let out = harmonic_output();
        let (before, after) = ([bank, harmonic(2, 2), harmonic(3, 6)], [bank, harmonic(5, 2), drift]);
        let mut synth = Synth::new(80);
        // The bank alone, never switched: the kept bank's state must stay the same as its.
        let mut alone = Synth::new(80);
        synth.update(&out, &before);
        alone.update(&out, &[bank]);
        let mut pos = 0i32;
        let mut tick = |synth: &mut Synth, alone: &mut Synth, k: u32| {
            pos = pos.wrapping_add(((k * 37) % 301) as i32 - 150);
            let input =
                TickInput { cmd_phase_turns: k.wrapping_mul(0x0147_ae14), cmd_pos_nm: pos, ..TickInput::default() };
            synth.next_input(&input);
            alone.next_input(&input);
        };
        for k in 0..200 {
            tick(&mut synth, &mut alone, k);
        }
        for k in 0..300u32 {
            if k % 48 == 0 {
                synth.update(&out, &after);
            }
            tick(&mut synth, &mut alone, 200 + k);
            assert_eq!(synth.slot(0).state, alone.slot(0).state, "tick {k}");
            let h = synth.harmonics();
            let (slot_1, slot_2) = (h.ramps[1], h.ramps[2]);
            if k < 79 {
                // Both old harmonics fade (the second order's slot now a drift's); the bank runs.
                assert_eq!((h.fading, h.kernels.kernel_mask, h.orders[1]), (0b110, 0b1, 2), "tick {k}");
                assert!(slot_1.amp_pm != 0 && slot_2.amp_pm != 0, "tick {k}");
            } else if k < 96 {
                // Gone; the fifth order and the drift wait for the next update.
                assert_eq!((h.fading, h.kernels.kernel_mask, h.term_count), (0, 0b1, 3), "tick {k}");
                assert_eq!((slot_1.amp_pm, slot_2.amp_pm), (0, 0), "tick {k}");
            } else {
                // The update at tick 96 starts both: the fifth order ramps in from silence.
                assert_eq!((h.orders[1], h.kernels.kernel_mask), (5, 0b101), "tick {k}");
                if k < 96 + 79 {
                    let target = slot_1.amp_target_pm;
                    assert!(
                        slot_1.amp_pm.abs() <= target.abs() && slot_1.amp_pm != target,
                        "tick {k}: {} of {target}",
                        slot_1.amp_pm
                    );
                }
            }
        }
    }
}
