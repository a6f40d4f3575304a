//! Per-tick synthesis of the predicted dynamic error (the paper's Eq. 4):
//! `DE(t) = A * sin(theta(t) + dphi) + sum of tick terms`, where `theta` is the command phase
//! handed over by the motion controller every tick.
//!
//! Everything here is integer arithmetic: amplitudes in picometres (`i32`), phases in turns
//! where a full turn is 2^32 (`u32`, so phase arithmetic wraps exactly), the sine from the
//! core's table ([`crate::math::sin_q31`]). It is hand-written for the servo tick: `no_std`
//! without a heap, bit for bit the same on the firmware and on the host (which simulates the
//! firmware's ticks and must give its DAC codes), and the hot loop of the 8 kHz tick.
//!
//! A model update never makes the output jump: amplitude and phase offset move to their new
//! values linearly over [`Synth::ramp_ticks`] ticks, the phase along the shorter way round,
//! so the synthesised waveform stays continuous.
//!
//! A change of terms (a program switch) does not step it either: a harmonic that goes ramps
//! out over the same ramp, counted from the switch whatever model updates come meanwhile,
//! lands on zero exactly and is dropped; the terms that take its slot, and new kernel terms
//! (which have no ramp), start with the first update after, so the tick never runs the old
//! harmonics beside new kernel terms (see `Harmonics::retarget_terms` in `harmonics`).
//!
//! The modules, one concept each:
//! - `ramp`: a value moving linearly to its target (`Ramp`);
//! - `kernel`: the kernel terms (drift, axis coupling, Laguerre banks on the velocity sign,
//!   the Dahl state or a position sine, the servo-axis twin, a resonance) and their state;
//! - `resonance`: a structural mode's motion of the tool from the command (`Resonance`);
//! - `harmonics`: [`SynthTargets`] and the harmonic bank (`Harmonics`), with the fade of
//!   the harmonics that go;
//! - here, the synthesiser ([`Synth`]) with its double buffer: two banks and two kernel
//!   cells per slot, so that a model update prepared at low priority is applied by a switch.

mod harmonics;
mod kernel;
mod ramp;
mod resonance;

pub use harmonics::SynthTargets;
pub use kernel::DRIFT_STEP_TICKS;
pub use resonance::Resonance;

use crate::program::{ModelOutput, TickTerm, MAX_TERMS};
use harmonics::Harmonics;
use kernel::{drift_at, kernel_pm, laguerre_pm, KernelState};
use ramp::ramp_harmonic_pm;

/// What the servo tick hands the synthesiser: the command and the other axes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TickInput {
    /// Command phase of the motion controller, a full turn is 2^32.
    pub cmd_phase_turns: u32,
    /// Command position of the Z axis, nanometres.
    pub cmd_pos_nm: i32,
    /// X-axis acceleration, micrometres per s^2 (0 where the bus does not carry it).
    pub x_acc_um_per_s2: i32,
    /// Spindle angle, a full turn is 2^32 (0 where the bus does not carry it).
    pub spindle_turns: u32,
}

// The term slots are walked by the bits of a byte (`Synth::apply`).
const _: () = assert!(MAX_TERMS == 8, "Synth::apply indexes term slots with 3 bits");

/// A kernel term slot's storage: the term (`None`: the slot holds none) and its state.
#[derive(Clone, Copy, Debug, PartialEq)]
struct KernelSlot {
    term: Option<TickTerm>,
    state: KernelState,
}

impl KernelSlot {
    const EMPTY: Self = Self { term: None, state: KernelState::REST };

    /// Resets of the axis twin state this cell holds (0 for other terms).
    fn axis_resets(&self) -> u32 {
        self.state.axis.as_ref().map_or(0, |(_, state)| state.resets)
    }
}

/// Storage cells per term slot: the live one and one for a prepared restart.
const CELLS: usize = 2 * MAX_TERMS;
const _: () = assert!(CELLS == 16, "kernel cells are indexed with 4 bits");

/// Which storage cell each term slot uses, and the cells of the kernel terms in force.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct KernelIndex {
    /// Slot `i` lives in cell `2i` or `2i + 1` (the other one receives a prepared restart).
    cell_of_slot: [u8; MAX_TERMS],
    /// The cells of the slots holding kernel terms, `kernel_count` of them: first the
    /// `laguerre_count` Laguerre banks, then the others, each in slot order (the tick runs
    /// the banks in a loop of their own, without dispatching on the kind).
    kernel_cells: [u8; MAX_TERMS],
    kernel_count: u32,
    laguerre_count: u32,
    /// Bit `i` set: slot `i` holds a kernel term.
    kernel_mask: u32,
}

impl KernelIndex {
    const INITIAL: Self = Self {
        cell_of_slot: [0, 2, 4, 6, 8, 10, 12, 14],
        kernel_cells: [0; MAX_TERMS],
        kernel_count: 0,
        laguerre_count: 0,
        kernel_mask: 0,
    };

    /// Sets the kernel slots to `mask` (of `terms`), listing their cells.
    fn set_kernels(&mut self, mask: u32, terms: &[TickTerm]) {
        self.kernel_mask = mask;
        let mut count = 0;
        for laguerre in [true, false] {
            for (slot, (&cell, term)) in self.cell_of_slot.iter().zip(terms).enumerate() {
                if mask & (1 << slot) != 0 && matches!(term, TickTerm::Laguerre { .. }) == laguerre {
                    self.kernel_cells[count] = cell;
                    count += 1;
                }
            }
            if laguerre {
                self.laguerre_count = count as u32;
            }
        }
        self.kernel_count = count as u32;
    }
}

/// What a prepared model update was computed from (see [`Synth::prepare`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Prepared {
    /// [`Synth`]`::generation` when it was prepared.
    generation: u32,
    /// The ramp length it used.
    ramp_ticks: u32,
    /// The machine time ([`Synth`]`::ticks`) at which it applies.
    at_ticks: u64,
    /// `Synth::ramp_left` after it.
    ramp_left: u32,
}

/// What preparing a model update reads of a [`Synth`] ([`Synth::view`]).
#[derive(Clone, Copy, Debug)]
pub struct SynthView {
    bank: Harmonics,
    ramp_left: u32,
    ticks: u64,
    generation: u32,
    ramp_ticks: u32,
    /// The update's kernel slots whose term runs in its slot now (and so runs on).
    kept: u32,
}

/// A model update prepared away from the synthesiser ([`Synth::prepare_from`]), for
/// [`Synth::install`].
#[derive(Clone, Copy, Debug)]
pub struct PreparedUpdate {
    /// The bank in force from the update on (its kernel slots in their cells then).
    bank: Harmonics,
    /// Slots whose kernel term stops, and those whose term starts from rest, in the spare cell.
    stop: u32,
    start: u32,
    prepared: Prepared,
}

/// The error synthesiser. See the [module docs](self).
///
/// Term slot `i` holds the `i`-th tick term of the program in force: a harmonic (its order
/// and ramp) or a kernel term (its kind and filter state; its ramp stays idle at zero, so
/// the harmonic loop may run over it and add exactly nothing).
///
/// `repr(C)`, the per-tick fields first and the kernel cells (2.9 KB) last, for short
/// offsets (see [`crate::servo::Servo`]).
#[derive(Clone, Debug, PartialEq)]
#[repr(C)]
pub struct Synth {
    /// Machine time: ticks since the synthesiser started (or [`Synth::set_time_ticks`]).
    ticks: u64,
    /// Index of the live bank, 0 or 1.
    live: usize,
    /// Ticks left to the ramps' next event: their end (all of them were retargeted
    /// together), or the end of a fade while others run on (see `Harmonics::end_ramps`).
    ramp_left: u32,
    /// Model updates applied (wrapping): a prepared update is valid for one generation.
    generation: u32,
    /// Ticks over which a model update moves amplitude and phase to their new values.
    pub ramp_ticks: u32,
    /// The update prepared in the other bank and cells, if any.
    prepared: Option<Prepared>,
    /// The live harmonics (`banks[live]`) and a prepared update (the other one).
    banks: [Harmonics; 2],
    /// Kernel terms and their states, two cells per slot (see [`KernelIndex`]).
    cells: [KernelSlot; CELLS],
    /// Axis twin resets of the states overwritten so far (the cells hold the others').
    axis_resets_retired: u32,
}

impl Eq for Synth {}

impl Synth {
    /// A silent synthesiser (amplitude zero) that ramps model updates over `ramp_ticks`.
    pub const fn new(ramp_ticks: u32) -> Self {
        Self {
            banks: [Harmonics::IDLE; 2],
            live: 0,
            cells: [KernelSlot::EMPTY; CELLS],
            ramp_left: 0,
            generation: 0,
            prepared: None,
            ticks: 0,
            ramp_ticks,
            axis_resets_retired: 0,
        }
    }

    /// Servo-axis twin states reset after diverging, since the synthesiser started (wrapping;
    /// counted off the tick: the tick only counts in the state it steps).
    pub fn axis_resets(&self) -> u32 {
        self.cells.iter().fold(self.axis_resets_retired, |sum, cell| sum.wrapping_add(cell.axis_resets()))
    }

    /// Keeps the count of the state in `cell`, which is about to be overwritten.
    fn retire(&mut self, cell: usize) {
        self.axis_resets_retired = self.axis_resets_retired.wrapping_add(self.cells[cell].axis_resets());
    }

    #[inline(always)]
    fn harmonics(&self) -> &Harmonics {
        &self.banks[self.live & 1]
    }

    #[inline(always)]
    fn harmonics_mut(&mut self) -> &mut Harmonics {
        &mut self.banks[self.live & 1]
    }

    /// The live storage of term slot `i`.
    fn slot(&self, i: usize) -> &KernelSlot {
        &self.cells[self.harmonics().kernels.cell_of_slot[i & 7] as usize & (CELLS - 1)]
    }

    fn slot_mut(&mut self, i: usize) -> &mut KernelSlot {
        let cell = self.harmonics().kernels.cell_of_slot[i & 7] as usize & (CELLS - 1);
        &mut self.cells[cell]
    }

    /// Takes a new model output: the fundamental from its amplitude and phase registers and
    /// the tick terms' coefficients from theirs. Terms that disappear ramp to zero first.
    /// The same as [`Synth::apply`] of [`SynthTargets::new`].
    pub fn update(&mut self, output: &ModelOutput, terms: &[TickTerm]) {
        self.apply(&SynthTargets::new(output, terms), terms);
    }

    /// Takes a new model output, converted beforehand ([`SynthTargets::new`] of the same
    /// `terms`): starts the ramps to it. When the terms change, harmonics that go ramp out
    /// first and the terms taking their place wait for them (see `Harmonics::retarget_terms`).
    pub fn apply(&mut self, targets: &SynthTargets, terms: &[TickTerm]) {
        let ramp = self.ramp_ticks;
        let count = terms.len().min(MAX_TERMS);
        let kept = self.kept_kernels(targets, &terms[..count]);
        let (live, ramp_left) = (self.live & 1, self.ramp_left);
        let h = &mut self.banks[live];
        h.fundamental.retarget(targets.amp_pm, targets.phase_turns, ramp);
        let running = h.kernels.kernel_mask;
        let update = h.retarget_terms(targets, count, running, kept, ramp_left, ramp);
        self.change_kernels(running & !kept, update.kernels & !kept, &terms[..count]);
        self.ramp_left = update.ramp_left;
        self.harmonics_mut().kernels.set_kernels(update.kernels, &terms[..count]);
        self.generation = self.generation.wrapping_add(1);
        self.prepared = None;
    }

    /// The kernel slots of `terms` whose term runs in its slot now (and so runs on).
    fn kept_kernels(&self, targets: &SynthTargets, terms: &[TickTerm]) -> u32 {
        let mut kept = 0;
        for (i, term) in terms.iter().enumerate() {
            if targets.kernel_mask & (1 << i) != 0 && self.slot(i).term == Some(*term) {
                kept |= 1 << i;
            }
        }
        kept
    }

    /// Applies an update's kernel changes to the live cells: the terms of the slots `stop`
    /// go, those of `start` (of `terms`) start from rest.
    #[inline(never)]
    fn change_kernels(&mut self, stop: u32, start: u32, terms: &[TickTerm]) {
        let ticks = self.ticks;
        for i in 0..MAX_TERMS {
            match terms.get(i) {
                Some(term) if start & (1 << i) != 0 => {
                    self.retire(self.harmonics().kernels.cell_of_slot[i & 7] as usize & (CELLS - 1));
                    *self.slot_mut(i) = KernelSlot { term: Some(*term), state: KernelState::start(term, ticks) };
                }
                _ if stop & (1 << i) != 0 => self.slot_mut(i).term = None,
                _ => {}
            }
        }
    }

    /// Prepares the model update `targets` of `terms` (as [`Synth::apply_prepared`] will
    /// apply it) for `ticks_ahead` ticks from now: on the state the running ramps will be in
    /// then, with any kernel term that starts then set up in its slot's spare cell. The tick
    /// applying it then only switches banks and cells. The same as [`Synth::view`],
    /// [`Synth::prepare_from`] and [`Synth::install`] in a row.
    pub fn prepare(&mut self, targets: &SynthTargets, terms: &[TickTerm], ticks_ahead: u32) {
        let view = self.view(targets, terms);
        let update = Self::prepare_from(&view, targets, terms, ticks_ahead);
        let installed = self.install(&update, terms);
        debug_assert!(installed, "nothing changed since the view");
    }

    /// What preparing the update `targets` of `terms` reads of the synthesiser: a copy of
    /// the live bank and the kernel slots that run on. Taken where the tick cannot run (a
    /// few hundred bytes copied), so that [`Synth::prepare_from`] can run where it can.
    pub fn view(&self, targets: &SynthTargets, terms: &[TickTerm]) -> SynthView {
        let count = terms.len().min(MAX_TERMS);
        SynthView {
            bank: *self.harmonics(),
            ramp_left: self.ramp_left,
            ticks: self.ticks,
            generation: self.generation,
            ramp_ticks: self.ramp_ticks,
            kept: self.kept_kernels(targets, &terms[..count]),
        }
    }

    /// Prepares the model update `targets` of `terms` from `view`, for `ticks_ahead` ticks
    /// after the view was taken (see [`Synth::prepare`]); it touches no synthesiser, so it
    /// may run while the tick does. [`Synth::install`] hands it over.
    pub fn prepare_from(
        view: &SynthView,
        targets: &SynthTargets,
        terms: &[TickTerm],
        ticks_ahead: u32,
    ) -> PreparedUpdate {
        let ramp = view.ramp_ticks;
        let count = terms.len().min(MAX_TERMS);
        let at_ticks = view.ticks.wrapping_add(u64::from(ticks_ahead));
        let (mut next, ramp_left) = view.bank.advanced(view.ramp_left, ticks_ahead);
        // (The cells do not change before then: only an update changes them.)
        let kept = view.kept;
        next.fundamental.retarget(targets.amp_pm, targets.phase_turns, ramp);
        let running = next.kernels.kernel_mask;
        let update = next.retarget_terms(targets, count, running, kept, ramp_left, ramp);
        // As `change_kernels`, in the spare cells (written by `install`).
        let (stop, start) = (running & !kept, update.kernels & !kept);
        for i in 0..MAX_TERMS {
            if (stop | start) & (1 << i) != 0 {
                next.kernels.cell_of_slot[i] ^= 1;
            }
        }
        next.kernels.set_kernels(update.kernels, &terms[..count]);
        PreparedUpdate {
            bank: next,
            stop: stop & !start,
            start,
            prepared: Prepared { generation: view.generation, ramp_ticks: ramp, at_ticks, ramp_left: update.ramp_left },
        }
    }

    /// Hands over an update [`Synth::prepare_from`] prepared of `terms` (the same terms):
    /// its bank and the kernel terms that start, in the spare cells, for the tick that
    /// applies it. Returns false, changing nothing, when the view it was prepared from is
    /// out of date: an update was applied since, or its tick has passed.
    pub fn install(&mut self, update: &PreparedUpdate, terms: &[TickTerm]) -> bool {
        let p = update.prepared;
        if p.generation != self.generation || p.ramp_ticks != self.ramp_ticks || p.at_ticks < self.ticks {
            return false;
        }
        let live = self.live & 1;
        let mut changed = (update.stop | update.start) & 0xff;
        while changed != 0 {
            let i = (changed.trailing_zeros() & 7) as usize;
            changed &= changed - 1;
            let spare = update.bank.kernels.cell_of_slot[i] as usize & (CELLS - 1);
            match terms.get(i) {
                Some(term) if update.start & (1 << i) != 0 => {
                    self.retire(spare);
                    self.cells[spare] = KernelSlot { term: Some(*term), state: KernelState::start(term, p.at_ticks) };
                }
                _ => self.cells[spare].term = None,
            }
        }
        self.banks[live ^ 1] = update.bank;
        self.prepared = Some(p);
        true
    }

    /// Applies a model update: the one [`Synth::prepare`]d, by switching banks and cells,
    /// when it is applied at the machine time it was prepared for and nothing changed since;
    /// otherwise as [`Synth::apply`]. Either way the result is that of [`Synth::apply`], bit
    /// for bit, provided `targets` and `terms` are those last prepared (when something else
    /// is to be applied, call [`Synth::apply`]).
    #[inline]
    pub fn apply_prepared(&mut self, targets: &SynthTargets, terms: &[TickTerm]) {
        if !self.switch_prepared() {
            self.apply(targets, terms);
        }
    }

    /// Applies the update [`Synth::prepare`]d, by switching banks and cells, if it was
    /// prepared for this machine time and nothing changed since; returns whether it did
    /// (otherwise nothing changes: apply the update with [`Synth::apply`]).
    #[inline]
    pub fn switch_prepared(&mut self) -> bool {
        match self.prepared {
            Some(p)
                if p.generation == self.generation && p.ramp_ticks == self.ramp_ticks && p.at_ticks == self.ticks =>
            {
                self.live ^= 1;
                self.ramp_left = p.ramp_left;
                self.generation = self.generation.wrapping_add(1);
                self.prepared = None;
                true
            }
            _ => false,
        }
    }

    /// Ramps everything to silence (no model in force).
    pub fn silence(&mut self) {
        self.apply(&SynthTargets::SILENT, &[]);
    }

    /// The predicted dynamic error at this tick, picometres, for command phase `cmd_phase_turns`
    /// (kernel terms see a command position of zero and no other axes; see [`Synth::next_input`]).
    #[inline]
    pub fn next(&mut self, cmd_phase_turns: u32) -> i32 {
        self.next_input(&TickInput { cmd_phase_turns, ..TickInput::default() })
    }

    /// The predicted dynamic error at this tick, picometres, from everything the tick knows.
    #[inline]
    pub fn next_input(&mut self, input: &TickInput) -> i32 {
        let cmd_phase_turns = input.cmd_phase_turns;
        let live = self.live & 1;
        let kernel_mask = self.banks[live].kernels.kernel_mask;
        let ramping = self.ramp_left > 1;
        if ramping {
            self.ramp_left -= 1;
        } else if self.ramp_left == 1 {
            self.finish_ramps();
        }
        // (After the ramps' event: the end of a fade no longer visits the faded slots.)
        let count = self.banks[live].term_count.min(MAX_TERMS);
        let h = &mut self.banks[live];
        if ramping {
            h.fundamental.step();
        }
        let mut total =
            ramp_harmonic_pm(h.fundamental.amp_pm, cmd_phase_turns.wrapping_add(h.fundamental.phase_turns)) as i64;
        if kernel_mask == 0 {
            // Kernel-free: every visited slot is a harmonic (or an idle one), in one pass.
            if ramping {
                for (ramp, &order) in h.ramps[..count].iter_mut().zip(&h.orders[..count]) {
                    ramp.step();
                    let phase = cmd_phase_turns.wrapping_mul(order).wrapping_add(ramp.phase_turns);
                    total += ramp_harmonic_pm(ramp.amp_pm, phase) as i64;
                }
            } else {
                for (ramp, &order) in h.ramps[..count].iter().zip(&h.orders[..count]) {
                    let phase = cmd_phase_turns.wrapping_mul(order).wrapping_add(ramp.phase_turns);
                    total += ramp_harmonic_pm(ramp.amp_pm, phase) as i64;
                }
            }
            self.ticks = self.ticks.wrapping_add(1);
        } else {
            // Kernel slots' ramps are idle (amplitude and steps zero) and would add exactly
            // nothing: the harmonic pass skips them.
            total =
                total.wrapping_add(h.harmonic_slots_pm(((1u32 << count) - 1) & !kernel_mask, ramping, cmd_phase_turns));
            let ticks = self.ticks;
            total = total.wrapping_add(self.kernels_pm(input, ticks));
            self.ticks = ticks.wrapping_add(1);
        }
        total.clamp(i32::MIN as i64, i32::MAX as i64) as i32
    }

    /// The tick with one ramp tick left: the ramps' end, or a fade's (see
    /// `Harmonics::end_ramps`).
    #[inline(never)]
    fn finish_ramps(&mut self) {
        self.ramp_left = self.harmonics_mut().end_ramps();
    }

    /// The kernel terms' sum for this tick, picometres.
    #[inline(always)]
    fn kernels_pm(&mut self, input: &TickInput, ticks: u64) -> i64 {
        let mut total = 0i64;
        let Self { banks, live, cells, .. } = self;
        let kernels = &banks[*live & 1].kernels;
        let count = (kernels.kernel_count as usize).min(MAX_TERMS);
        let banks = (kernels.laguerre_count as usize).min(count);
        for &cell in &kernels.kernel_cells[..banks] {
            let KernelSlot { term, state } = &mut cells[cell as usize & (CELLS - 1)];
            if let Some(TickTerm::Laguerre { input: kind, pole_q30, gains_pm }) = term {
                total = total.wrapping_add(laguerre_pm(kind, *pole_q30, gains_pm, state, input));
            }
        }
        for &cell in &kernels.kernel_cells[banks..count] {
            let KernelSlot { term, state } = &mut cells[cell as usize & (CELLS - 1)];
            if let Some(term) = term {
                total = total.wrapping_add(kernel_pm(term, state, input, ticks));
            }
        }
        total
    }

    /// Sets the machine time (ticks since the machine started), e.g. to replay a measurement
    /// group that started at a known machine time; drift terms jump to their value then.
    pub fn set_time_ticks(&mut self, ticks: u64) {
        self.ticks = ticks;
        for i in 0..MAX_TERMS {
            let slot = self.slot_mut(i);
            if let Some(TickTerm::Drift { decay_pm, tau_ticks, .. }) = slot.term {
                drift_at(&mut slot.state, decay_pm, tau_ticks, ticks);
            }
        }
    }

    /// Restarts the kernel terms' filter states (a new motion from rest), keeping the model
    /// and the count of axis twin resets ([`Synth::axis_resets`]).
    pub fn restart_kernels(&mut self) {
        for i in 0..MAX_TERMS {
            let slot = self.slot_mut(i);
            if slot.term.is_some() {
                slot.state = slot.state.restarted();
            }
        }
    }

    /// The amplitude currently in force (after ramping), picometres.
    pub fn amp_pm(&self) -> i32 {
        self.harmonics().fundamental.amp_pm
    }

    /// The phase offset currently in force, turns.
    pub fn phase_turns(&self) -> u32 {
        self.harmonics().fundamental.phase_turns
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::program::TermInput;

    /// Xorshift64: the synthesiser's tests' random numbers.
    pub(super) fn rng(seed: &mut u64) -> u64 {
        *seed ^= *seed << 13;
        *seed ^= *seed >> 7;
        *seed ^= *seed << 17;
        *seed
    }

    /// A model output with the fundamental's amplitude and phase.
    pub(super) fn output(amp_um: f32, phase_deg: f32) -> ModelOutput {
        let mut out = ModelOutput::default();
        out.registers[0] = amp_um;
        out.registers[1] = phase_deg;
        out
    }

    /// Harmonic terms of `orders`, their coefficients in the register pairs 2..8 in turn.
    pub(super) fn harmonic_terms(orders: &[u8]) -> std::vec::Vec<TickTerm> {
        orders
            .iter()
            .enumerate()
            .map(|(k, &order)| TickTerm::Harmonic {
                order,
                amp_reg: 2 + 2 * (k % 3) as u8,
                phase_reg: 3 + 2 * (k % 3) as u8,
            })
            .collect()
    }

    /// A model output for [`harmonic_terms`]: amplitudes of 1.5 um, 50 pm (a ramp's step over
    /// 80 ticks truncates to zero) and 0.7 um.
    pub(super) fn harmonic_output() -> ModelOutput {
        let mut out = output(2.0, 20.0);
        out.registers[2..8].copy_from_slice(&[1.5, 40.0, 5e-5, -100.0, 0.7, 170.0]);
        out
    }

    #[test]
    fn axis_twin_resets_are_counted_across_restarts_and_replacements() {
        // A derivative gain far beyond what the tick can carry: it diverges on any motion.
        let unstable = TickTerm::Axis(crate::axis::AxisParams { kd_per_s: 9e5, ..crate::axis::default_machine() });
        let mut synth = Synth::new(0);
        synth.update(&ModelOutput::default(), &[unstable]);
        let run = |synth: &mut Synth| {
            for k in 0..2000 {
                let cmd_pos_nm =
                    (3000.0 * libm::sin(2.0 * core::f64::consts::PI * 40.0 * f64::from(k) / 8000.0)) as i32;
                synth.next_input(&TickInput { cmd_phase_turns: 0, cmd_pos_nm, x_acc_um_per_s2: 0, spindle_turns: 0 });
            }
            synth.axis_resets()
        };
        let first = run(&mut synth);
        assert!(first > 0);
        // A restart from rest keeps the count, and the next motion adds to it.
        synth.restart_kernels();
        assert_eq!(synth.axis_resets(), first);
        let second = run(&mut synth);
        assert!(second > first);
        // Replacing the term (another program) keeps the old state's count.
        synth.update(&ModelOutput::default(), &[]);
        synth.update(&ModelOutput::default(), &[TickTerm::Axis(crate::axis::default_machine())]);
        assert_eq!(synth.axis_resets(), second);
    }

    #[test]
    fn a_settled_model_synthesises_eq4() {
        let mut synth = Synth::new(0);
        synth.update(&output(2.0, 30.0), &[]);
        for k in 0..200u32 {
            let theta = k.wrapping_mul(0x0123_4567);
            let got = synth.next(theta) as f64 * 1e-6;
            let angle = 2.0 * core::f64::consts::PI * theta as f64 / 4_294_967_296.0 + 30f64.to_radians();
            assert!((got - 2.0 * angle.sin()).abs() < 2e-5, "tick {k}: {got}");
        }
    }

    #[test]
    fn model_updates_never_step_the_waveform() {
        let mut synth = Synth::new(80);
        synth.update(&output(3.0, 10.0), &[]);
        let step = 4_294_967_296u64 / 200; // 40 Hz at 8 kHz
        let mut theta = 0u32;
        let mut last = synth.next(theta);
        let mut worst = 0i64;
        for k in 0..2000u32 {
            if k == 500 {
                synth.update(&output(1.0, 170.0), &[]);
            }
            if k == 1200 {
                synth.update(&output(5.0, -170.0), &[]);
            }
            theta = theta.wrapping_add(step as u32);
            let now = synth.next(theta);
            worst = worst.max((now as i64 - last as i64).abs());
            last = now;
        }
        // The largest change per tick of a 5 um, 40 Hz sine is 2 pi 40 * 5 um / 8 kHz = 0.157 um;
        // ramps over 80 ticks add well under that again.
        assert!(worst < 250_000, "largest per-tick change {worst} pm");
        assert_eq!(synth.amp_pm(), 5_000_000);
    }

    #[test]
    fn prepared_updates_synthesise_what_applied_ones_do_bit_for_bit() {
        let mut seed = 0x5eed_u64;
        let kernels = [
            TickTerm::Drift { offset_pm: 200_000, decay_pm: -300_000, tau_ticks: 5000 },
            TickTerm::AxisCoupling {
                x_gain_pm_per_mps2: 700_000,
                spindle_amp_pm: 40_000,
                spindle_phase_turns: 3 << 28,
            },
            TickTerm::Laguerre {
                input: TermInput::VelocitySign { smooth_nm_per_4_ticks: 300 },
                pole_q30: 998_579_896,
                gains_pm: [90_000, -40_000, 20_000, 0, 0, 0, 0, 0],
            },
            TickTerm::Laguerre {
                input: TermInput::Dahl { inv_x0_q30: 1 << 20 },
                pole_q30: 1_072_668_082,
                gains_pm: [50_000, 0, -20_000, 0, 0, 0, 0, 9_000],
            },
        ];
        for round in 0..60 {
            let ramp_ticks = [0, 1, 7, 80][round % 4];
            let mut plain = Synth::new(ramp_ticks);
            let mut prepared = Synth::new(ramp_ticks);
            let mut theta = 0u32;
            let mut pos = 0i32;
            let mut tick = |plain: &mut Synth, prepared: &mut Synth, what: &str| {
                theta = theta.wrapping_add(0x0147_ae14);
                pos = pos.wrapping_add(((theta >> 20) % 301) as i32 - 150);
                let input = TickInput {
                    cmd_phase_turns: theta,
                    cmd_pos_nm: pos,
                    x_acc_um_per_s2: (theta >> 8) as i32,
                    spindle_turns: theta.wrapping_mul(3),
                };
                assert_eq!(plain.next_input(&input), prepared.next_input(&input), "round {round}: {what}");
            };
            for update in 0..30 {
                let term_count = (rng(&mut seed) % 9) as usize;
                let mut out = output((rng(&mut seed) % 5000) as f32 * 1e-3, (rng(&mut seed) % 720) as f32 - 360.0);
                let mut terms = std::vec::Vec::new();
                for i in 0..term_count {
                    let amp_reg = 2 + 2 * (i % 3) as u8;
                    out.registers[amp_reg as usize] = (rng(&mut seed) % 3000) as f32 * 1e-3;
                    out.registers[amp_reg as usize + 1] = (rng(&mut seed) % 720) as f32 - 360.0;
                    // Orders and kinds change now and then: slots are recreated.
                    let kind = rng(&mut seed) % 8;
                    terms.push(match kind {
                        0..=3 => kernels[kind as usize],
                        _ => TickTerm::Harmonic {
                            order: 2 + (rng(&mut seed) % 3) as u8,
                            amp_reg,
                            phase_reg: amp_reg + 1,
                        },
                    });
                }
                let targets = if update % 7 == 6 { SynthTargets::SILENT } else { SynthTargets::new(&out, &terms) };
                let terms: &[TickTerm] = if update % 7 == 6 { &[] } else { &terms };
                // Prepared some ticks before its tick, usually for that tick (while the ramps
                // still run or after they settled), sometimes for another one (the fallback).
                let wait = rng(&mut seed) % 120;
                let ahead =
                    if rng(&mut seed).is_multiple_of(5) { (wait + 1 + rng(&mut seed) % 3) as u32 } else { wait as u32 };
                prepared.prepare(&targets, terms, ahead);
                for _ in 0..wait {
                    tick(&mut plain, &mut prepared, "before the update");
                }
                plain.apply(&targets, terms);
                prepared.apply_prepared(&targets, terms);
                for _ in 0..(rng(&mut seed) % 100) {
                    tick(&mut plain, &mut prepared, "after the update");
                }
                // (The kernels' cells differ: a prepared restart uses the spare one.)
                let without_cells = |h: &Harmonics| {
                    let mut h = *h;
                    h.kernels.cell_of_slot = [0; MAX_TERMS];
                    h.kernels.kernel_cells = [0; MAX_TERMS];
                    h
                };
                assert_eq!(without_cells(plain.harmonics()), without_cells(prepared.harmonics()));
                assert_eq!(plain.ramp_left, prepared.ramp_left);
                for i in 0..MAX_TERMS {
                    // (The state of an empty slot is never read: a kernel starts from rest.)
                    assert_eq!(plain.slot(i).term, prepared.slot(i).term, "round {round} slot {i}");
                    if plain.slot(i).term.is_some() {
                        assert_eq!(plain.slot(i).state, prepared.slot(i).state, "round {round} slot {i}");
                    }
                }
            }
        }
    }
}
