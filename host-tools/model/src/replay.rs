//! Replaying a model on a measured group: the firmware program on the group's features, and
//! the firmware's synthesiser tick by tick, as the board would run them.

use std::f64::consts::PI;

use rayon::prelude::*;
use sts_analysis::GroupSample;
use sts_dataset::{Dataset, GroupData};
use sts_twin_core::program::{ModelOutput, Program};
use sts_twin_core::synth::{Synth, TickInput};

/// The model's firmware program output for a group's features (zero when it fails, as the
/// firmware then holds silence).
pub fn program_output(program: &Program, sample: &GroupSample) -> (ModelOutput, bool) {
    match program.evaluate(&sample.features) {
        Ok(out) => (out, true),
        Err(_) => (ModelOutput::default(), false),
    }
}

/// Command phase in turns (2^32 per turn) at time `t_s` from the command's sine fit.
pub fn cmd_phase_turns(sample: &GroupSample, t_s: f64) -> u32 {
    let cycles = sample.targets.freq_hz * t_s + sample.targets.cmd.phase_rad / (2.0 * PI);
    let frac = cycles - cycles.floor();
    (frac * 4_294_967_296.0) as u64 as u32
}

/// The synthesiser inputs of sample `k` of a group, as the firmware would receive them.
pub fn tick_input(sample: &GroupSample, group: &GroupData, k: usize) -> TickInput {
    tick_input_with_phase(group, k, cmd_phase_turns(sample, group.t_s[k]))
}

/// [`tick_input`] with the command phase given (the per-tick terms do not use it).
pub fn tick_input_with_phase(group: &GroupData, k: usize, cmd_phase_turns: u32) -> TickInput {
    let x_acc = group.x_acc_mps2.as_ref().map_or(0.0, |v| v[k]);
    let spindle = group.spindle_deg.as_ref().map_or(0.0, |v| v[k]);
    TickInput {
        cmd_phase_turns,
        cmd_pos_nm: (group.z_cmd_um[k] * 1000.0).round() as i32,
        x_acc_um_per_s2: (x_acc * 1e6).round().clamp(i32::MIN as f64, i32::MAX as f64) as i32,
        spindle_turns: turns_u32(spindle / 360.0),
    }
}

/// The predicted dynamic error of a whole group, um, sample by sample: the firmware's
/// synthesiser on the program's output, started at the group's machine time with its
/// kernels at rest (the group starts from rest).
pub fn predict_group(
    program: &Program,
    sample: &GroupSample,
    group: &GroupData,
    sample_rate_hz: f64,
) -> (Vec<f64>, bool) {
    let (output, ok) = program_output(program, sample);
    let mut synth = Synth::new(0);
    synth.set_time_ticks((sample.info.start_s.max(0.0) * sample_rate_hz).round() as u64);
    synth.update(&output, &program.terms);
    synth.restart_kernels();
    let out = (0..group.len()).map(|k| f64::from(synth.next_input(&tick_input(sample, group, k))) * 1e-6).collect();
    (out, ok)
}

/// Turns as u32 from a phase in turns (any real number).
pub fn turns_u32(phase_turns: f64) -> u32 {
    (phase_turns.rem_euclid(1.0) * 4_294_967_296.0) as u64 as u32
}

/// `dataset` with its probe readings divided by `gain`.
pub fn with_probe_gain(dataset: &Dataset, gain: f64) -> Dataset {
    let mut out = dataset.clone();
    out.groups.par_iter_mut().for_each(|g| g.z_tcp_um.iter_mut().for_each(|z| *z /= gain));
    out
}
