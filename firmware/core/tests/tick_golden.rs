//! The servo tick's outputs pinned bit for bit: a hash of every DAC code, prediction and flag
//! word of long runs of the twin (five programs within the tick budget: harmonics alone,
//! Laguerre banks on each of the three inputs, drifts, the paper's formulas), with program
//! changes and both update schedules (ramps that settle between model results and ramps that
//! never do), and of every prediction of the synthesiser driven directly with random terms
//! (64-bit Laguerre stages, divisions, couplings), ramp lengths, machine-time jumps, restarts
//! and the inputs the bus does not carry yet. The runs are `tick_scenarios`'.
//!
//! That the outputs are right, `tick_reference` checks on the same runs: every tick's
//! prediction, DAC code and flags against a plain f64 reference of the synthesiser and the DAC
//! stage, within bounds derived from the core's fixed-point formats (the servo-axis twin and
//! the resonance, which have no simpler form there, are in none of these runs). What the hashes
//! add is that nothing changed at all: a change within those bounds (a rounding, the order of
//! a sum) fails here alone. Below the tick, `synth::kernel`'s unit tests hold each fast kernel
//! to its plain 64-bit form bit for bit (or the coupling's product within its bound), and the
//! HIL tests hold the firmware's DAC codes to the host core's.
//!
//! The runs without a program switch (each program alone, the synthesiser with fixed terms)
//! and those with switches are pinned apart, so that a change of the switching behaviour
//! leaves the first ones standing. A hash is pinned again only with a change of behaviour on
//! purpose, with `tick_reference` passing on the new outputs, and its commit says what changed
//! and why (`git log -- firmware/core/tests/tick_golden.rs`); a change of speed alone must
//! leave every hash as it is.

use crate::tick_scenarios::{
    fixed_random_terms, one_program_requests, programs, switching_requests, synth_steps, twin_params, twin_run, Hash,
    SynthStep, SYNTH_ONE_PROGRAM_RUNS, SYNTH_SEEDS, SYNTH_TICKS, TWIN_ONE_PROGRAM_TICKS, TWIN_TICKS, TWIN_WINDOWS,
};
use sts_twin_core::program::{Program, TickTerm};
use sts_twin_core::synth::Synth;

/// Runs the twin for `ticks` ticks under `window_samples`, changing programs on the way,
/// and hashes every output.
fn twin_hash(window_samples: u32, ticks: u32) -> u64 {
    twin_run(window_samples, ticks, twin_params(), switching_requests(ticks), |_, _, _| {})
}

/// Runs the twin for `ticks` ticks under `window_samples` with `program` uploaded at the
/// start and never switched, and hashes every output.
fn twin_hash_one_program(window_samples: u32, ticks: u32, program: &Program) -> u64 {
    twin_run(window_samples, ticks, twin_params(), one_program_requests(program), |_, _, _| {})
}

#[test]
fn the_twins_outputs_are_those_pinned_ramps_settling_between_updates() {
    assert_eq!(twin_hash(TWIN_WINDOWS[0], TWIN_TICKS), 1_172_237_732_981_430_062, "window 2000");
}

#[test]
fn the_twins_outputs_are_those_pinned_ramps_never_settling() {
    assert_eq!(twin_hash(TWIN_WINDOWS[1], TWIN_TICKS), 18_048_703_951_985_695_510, "window 800");
}

/// Each program of the run alone, never switched, under both schedules: a program switch may
/// change the outputs of the ticks after it, a run without one must not change at all.
#[test]
fn the_twins_outputs_without_a_program_switch_are_those_pinned() {
    let pinned: [[u64; 2]; 5] = [
        [9_100_906_065_443_868_003, 9_571_390_674_043_219_037],
        [4_715_860_211_714_405_979, 3_838_874_250_454_834_930],
        [9_679_915_960_794_309_429, 8_331_655_143_772_813_187],
        [14_419_431_135_460_686_159, 16_391_232_033_328_672_457],
        [13_188_647_319_128_626_359, 2_583_491_077_265_107_475],
    ];
    let mut got = vec![];
    for program in programs().iter() {
        got.push(TWIN_WINDOWS.map(|window| twin_hash_one_program(window, TWIN_ONE_PROGRAM_TICKS, program)));
    }
    assert_eq!(got, pinned);
}

/// Drives the synthesiser directly: random programs, ramp lengths, machine-time jumps,
/// restarts, and per-tick inputs with X acceleration, spindle angle and position jumps.
fn synth_hash(seed: u64, ticks: u32) -> u64 {
    synth_run(seed, ticks, None)
}

/// [`synth_hash`] with the `term_count` random terms drawn once: model updates without a
/// program switch.
fn synth_hash_one_program(seed: u64, ticks: u32, term_count: usize) -> u64 {
    let (terms, seed) = fixed_random_terms(seed, term_count);
    synth_run(seed, ticks, Some(&terms))
}

/// [`synth_hash`], with new random terms at every model update or always `fixed_terms`.
fn synth_run(seed: u64, ticks: u32, fixed_terms: Option<&[TickTerm]>) -> u64 {
    let mut synth = Synth::new(80);
    let mut hash = Hash::new();
    synth_steps(seed, ticks, fixed_terms, |step| match step {
        SynthStep::Update { output, terms, ramp_ticks } => {
            synth.ramp_ticks = ramp_ticks;
            synth.update(&output, &terms);
        }
        SynthStep::SetTime(ticks) => synth.set_time_ticks(ticks),
        SynthStep::Restart => synth.restart_kernels(),
        SynthStep::Tick(input) => hash.add(i64::from(synth.next_input(&input))),
    });
    hash.0
}

#[test]
fn the_synthesisers_outputs_are_those_pinned() {
    assert_eq!(synth_hash(SYNTH_SEEDS[0], SYNTH_TICKS), 17_174_907_237_876_833_646, "seed 1");
    assert_eq!(synth_hash(SYNTH_SEEDS[1], SYNTH_TICKS), 12_700_657_915_622_410_726, "seed 2");
}

#[test]
fn the_synthesisers_outputs_without_a_program_switch_are_those_pinned() {
    let got = SYNTH_ONE_PROGRAM_RUNS.map(|(seed, count)| synth_hash_one_program(seed, SYNTH_TICKS, count));
    assert_eq!(
        got,
        [7_066_689_386_559_545_409, 983_777_811_597_032_170, 13_924_118_992_660_030_052, 5_816_555_242_102_462_526]
    );
}
