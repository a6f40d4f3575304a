//! The servo tick's outputs against the plain f64 reference of `synth_reference`, on the
//! golden runs of `tick_scenarios`: every prediction of the synthesiser driven directly, and
//! every prediction, DAC code and flag word of the twin, each within the bound the reference
//! derives from the core's fixed-point formats. `tick_golden` pins the same runs bit for bit;
//! these tests say that the values are right. One more run of the twin, not pinned, takes the
//! DAC parameters the golden runs leave at their defaults (an offset, a negative scale).
//!
//! What the twin's tick is given comes from the twin, not from the reference: the model
//! outputs (the features and the program's evaluation have oracles of their own, `reference`
//! and `program::eval`'s tests) and the ticks they apply on.

use std::collections::HashMap;

use crate::synth_reference::{Bounded, DacReference, SynthReference};
use crate::tick_scenarios::{
    fixed_random_terms, input, one_program_requests, programs, switching_requests, synth_steps, twin_params, twin_run,
    SynthStep, SYNTH_ONE_PROGRAM_RUNS, SYNTH_SEEDS, SYNTH_TICKS, TWIN_ONE_PROGRAM_TICKS, TWIN_TICKS, TWIN_WINDOWS,
};
use sts_twin_core::bus::{OUT_FLAG_ENABLED, OUT_FLAG_MODEL_ACTIVE, OUT_FLAG_SATURATED, OUT_FLAG_SLEWING};
use sts_twin_core::feedforward::FeedforwardParams;
use sts_twin_core::program::{ModelOutput, Program, TickTerm};
use sts_twin_core::synth::{Synth, TickInput};
use sts_twin_core::wire::Request;

/// The bounds a run's checks allowed: what a defect has to exceed to be seen.
#[derive(Debug, Default)]
struct Allowed {
    bounds_pm: Vec<f64>,
    code: f64,
}

impl Allowed {
    /// Asserts that the core's prediction `got_pm` lies within the reference's bound, and
    /// keeps the bound.
    fn admit(&mut self, want: Bounded, got_pm: f64, at: std::fmt::Arguments) {
        assert!(want.admits(got_pm), "{at}: {got_pm} pm, the reference {:.1} +- {:.1} pm", want.value, want.bound);
        self.bounds_pm.push(want.bound);
    }

    fn median_pm(&mut self) -> f64 {
        self.bounds_pm.sort_by(f64::total_cmp);
        self.bounds_pm[self.bounds_pm.len() / 2]
    }

    fn largest_pm(&self) -> f64 {
        self.bounds_pm.iter().copied().fold(0.0, f64::max)
    }
}

/// Runs the synthesiser directly (as `tick_golden`'s runs) beside the reference and checks
/// every tick's prediction.
fn check_synth_run(run: &str, seed: u64, fixed_terms: Option<&[TickTerm]>) -> Allowed {
    let mut synth = Synth::new(80);
    let mut reference = SynthReference::new(80);
    let mut allowed = Allowed::default();
    let mut tick = 0u32;
    synth_steps(seed, SYNTH_TICKS, fixed_terms, |step| match step {
        SynthStep::Update { output, terms, ramp_ticks } => {
            synth.ramp_ticks = ramp_ticks;
            synth.update(&output, &terms);
            reference.ramp_ticks = ramp_ticks;
            reference.update(&output, &terms);
        }
        SynthStep::SetTime(ticks) => {
            synth.set_time_ticks(ticks);
            reference.set_time_ticks(ticks);
        }
        SynthStep::Restart => {
            synth.restart_kernels();
            reference.restart_kernels();
        }
        SynthStep::Tick(input) => {
            let got = f64::from(synth.next_input(&input));
            allowed.admit(reference.next_input(&input), got, format_args!("{run} tick {tick}"));
            tick += 1;
        }
    });
    allowed
}

/// Half the ticks or more are held within 100 pm (the check must stay able to see a defect of
/// that size); those where 64-bit banks with gains near 2^28 pm per unit run are held far less
/// closely, as their Q24 stages are.
#[test]
fn the_synthesiser_follows_the_reference_with_new_terms_at_every_update() {
    for seed in SYNTH_SEEDS {
        let median = check_synth_run(&format!("seed {seed:#x}"), seed, None).median_pm();
        assert!(median < 100.0, "seed {seed:#x}: half the ticks allowed {median:.0} pm or more");
    }
}

#[test]
fn the_synthesiser_follows_the_reference_without_a_program_switch() {
    for (seed, count) in SYNTH_ONE_PROGRAM_RUNS {
        let (terms, run_seed) = fixed_random_terms(seed, count);
        check_synth_run(&format!("seed {seed:#x}"), run_seed, Some(&terms));
    }
}

/// Runs the twin (as `tick_golden`'s runs, under `params`) beside the reference and checks
/// every tick's prediction, DAC code and flags. `programs` are those the run uploads, by id.
///
/// The reference learns a model update from what the twin shows after the tick that applied
/// it: results apply every model interval from the first (the twin computes each at once,
/// never late); one whose program is in force counts as a model update and brings its output
/// (`Servo::last_output`) for the program's terms, one without a program silences.
fn check_twin_run(
    window: u32,
    ticks: u32,
    params: FeedforwardParams,
    programs: &[Program],
    requests: impl Fn(u32) -> Option<Request>,
) {
    let by_id: HashMap<u32, &[TickTerm]> = programs.iter().map(|p| (p.id, &p.terms[..])).collect();
    let mut reference = SynthReference::new(sts_twin_core::servo::ServoConfig::default().synth_ramp_ticks);
    let mut dac = DacReference::new(&params);
    let mut model_active = false;
    let (mut updates, mut first_update) = (0, None);
    let mut allowed = Allowed::default();
    twin_run(window, ticks, params, requests, |k, twin, out| {
        let servo = twin.servo();
        assert_eq!((servo.degraded(), servo.counters().model_faults), (0, 0), "tick {k}");
        let interval = servo.model_timing().interval_ticks;
        let updated = servo.counters().model_updates != updates;
        updates = servo.counters().model_updates;
        if updated {
            first_update.get_or_insert(k);
        }
        let due = first_update.is_some_and(|first| (k - first) % interval == 0);
        assert!(!updated || due, "tick {k}: a model update off the interval");
        if due && updated {
            let id = servo.program_id().expect("a program in force");
            reference.update(servo.last_output(), by_id[&id]);
            model_active = true;
        } else if due {
            assert_eq!(servo.program_id(), None, "tick {k}");
            reference.update(&ModelOutput::default(), &[]);
            model_active = false;
        }
        let slot = input(k);
        let de = reference.next_input(&TickInput {
            cmd_phase_turns: slot.cmd_phase_turns,
            cmd_pos_nm: slot.cmd_pos_nm,
            x_acc_um_per_s2: slot.x_acc_um_per_s2,
            spindle_turns: slot.spindle_turns,
        });
        allowed.admit(de, f64::from(out.de_pred_pm), format_args!("window {window} tick {k}"));
        let dac_tick = dac.tick(de, model_active);
        let code = f64::from(out.dac_code);
        allowed.code = allowed.code.max(dac_tick.code.bound);
        assert!(
            dac_tick.code.admits(code),
            "window {window} tick {k}: code {code}, the reference {:.3} +- {:.3}",
            dac_tick.code.value,
            dac_tick.code.bound
        );
        let flag = |bit: u16| out.flags & bit != 0;
        assert!(flag(OUT_FLAG_ENABLED), "tick {k}");
        assert_eq!(flag(OUT_FLAG_MODEL_ACTIVE), model_active, "tick {k}");
        if let Some(saturated) = dac_tick.saturated {
            assert_eq!(flag(OUT_FLAG_SATURATED), saturated, "window {window} tick {k}: saturated");
        }
        if let Some(slewing) = dac_tick.slewing {
            assert_eq!(flag(OUT_FLAG_SLEWING), slewing, "window {window} tick {k}: slewing");
        }
    });
    // The programs' terms hold every tick within a nanometre and a few codes.
    let (largest, code) = (allowed.largest_pm(), allowed.code);
    assert!(largest < 1000.0 && code < 4.0, "window {window}: bounds up to {largest:.0} pm, {code:.1} codes");
}

#[test]
fn the_twin_follows_the_reference_through_program_switches() {
    for window in TWIN_WINDOWS {
        check_twin_run(window, TWIN_TICKS, twin_params(), &programs(), switching_requests(TWIN_TICKS));
    }
}

#[test]
fn the_twin_follows_the_reference_without_a_program_switch() {
    for program in programs() {
        for window in TWIN_WINDOWS {
            let requests = one_program_requests(&program);
            check_twin_run(window, TWIN_ONE_PROGRAM_TICKS, twin_params(), std::slice::from_ref(&program), requests);
        }
    }
}

/// The program switches under other DAC parameters: an offset to subtract (the golden runs'
/// is zero), a negative scale, a smaller full scale, a tighter slew limit and a longer enable
/// ramp.
#[test]
fn the_twin_follows_the_reference_with_an_offset_and_a_negative_scale() {
    let params = FeedforwardParams {
        k_dv_um_per_v: -2.0,
        offset_v: 0.3,
        dac_full_scale_v: 5.0,
        slew_v_per_tick: 0.02,
        enable_ramp_ticks: 1000,
        ..FeedforwardParams::default()
    };
    check_twin_run(TWIN_WINDOWS[1], TWIN_TICKS, params, &programs(), switching_requests(TWIN_TICKS));
}
