//! Resuming after an input fault: compensation comes back only with a prediction made from
//! healthy samples alone, i.e. bit-identical to that of a run that never saw the fault.

use sts_twin_core::bus::{InputSlot, OutputSlot, IN_FLAG_PHASE_VALID, OUT_FLAG_DEGRADED};
use sts_twin_core::features::FeatureConfig;
use sts_twin_core::feedforward::FeedforwardParams;
use sts_twin_core::program::{Program, ProgramBuilder, REG_AMP_UM, REG_PHASE_DEG};
use sts_twin_core::servo::ServoConfig;
use sts_twin_core::twin::Twin;
use sts_twin_core::wire::{Request, Response};

fn input(k: u32) -> InputSlot {
    let t = k as f64 / 8000.0;
    let amp = 4000.0 + 2000.0 * (2.0 * std::f64::consts::PI * 0.3 * t).sin();
    let phase = 2.0 * std::f64::consts::PI * 40.0 * t;
    let noise = ((k.wrapping_mul(2_654_435_761) >> 16) % 9) as f64 - 4.0;
    InputSlot {
        tick: k,
        acc_code: (-amp * phase.sin() + noise).round() as i16,
        flags: IN_FLAG_PHASE_VALID,
        cmd_phase_turns: ((40.0 * t).fract() * 4_294_967_296.0) as u64 as u32,
        cmd_pos_nm: (3000.0 * phase.sin()) as i32,
        ..Default::default()
    }
}

fn rms_program() -> Program {
    let mut b = ProgramBuilder::new();
    b.id(5).constant(2.0).feature(4).mul().store(REG_AMP_UM);
    b.constant(-0.2).feature(0).mul().store(REG_PHASE_DEG);
    b.finish().unwrap()
}

/// A twin on the open-loop test stream: the supervisor is switched off (the accelerometer
/// does not see the DAC here, so there is no machine for it to judge).
fn twin(config: ServoConfig) -> Box<Twin> {
    let mut twin = Box::new(Twin::boot(FeatureConfig { window_samples: 2000, ..FeatureConfig::DEFAULT }, config, &[]));
    let params = FeedforwardParams { enable_ramp_ticks: 400, slew_v_per_tick: 0.05, ..FeedforwardParams::default() };
    assert_eq!(twin.handle(Request::SetParams(params)), Response::Ack);
    let off = sts_twin_core::supervisor::SupervisorParams { active: false, ..Default::default() };
    assert_eq!(twin.handle(Request::SetSupervisor(off)), Response::Ack);
    assert_eq!(twin.handle(Request::UploadProgram { program: rms_program(), activate: true }), Response::Ack);
    assert_eq!(twin.handle(Request::SetEnabled(true)), Response::Ack);
    twin
}

/// Runs a faulted and a clean twin side by side; returns both output streams.
fn side_by_side(
    config: ServoConfig,
    ticks: u32,
    fault: impl Fn(u32, &mut InputSlot),
) -> (Vec<OutputSlot>, Vec<OutputSlot>) {
    let (mut faulted, mut clean) = (twin(config), twin(config));
    (0..ticks)
        .map(|k| {
            let mut slot = input(k);
            let reference = clean.tick(Some(&slot));
            fault(k, &mut slot);
            (faulted.tick(Some(&slot)), reference)
        })
        .unzip()
}

fn check_resume(config: ServoConfig, what: &str, fault_end: u32, outputs: &[OutputSlot], reference: &[OutputSlot]) {
    let resumed =
        (fault_end as usize..outputs.len()).find(|&k| outputs[k].flags & OUT_FLAG_DEGRADED == 0).expect("resumes");
    // Not before a whole window of healthy samples.
    assert!(resumed as u32 >= fault_end + 2000 - 1, "{what}: resumed at {resumed}");
    // From the first trusted tick on, the prediction is the clean run's, bit for bit.
    for k in resumed..outputs.len() {
        assert_eq!(
            outputs[k].de_pred_pm,
            reference[k].de_pred_pm,
            "{what}: tick {k} ({} after resuming) predicts from faulty samples",
            k - resumed
        );
    }
    let timing = twin(config).servo().model_timing();
    let recovery = 2000 + timing.interval_ticks + timing.latency_ticks + config.synth_ramp_ticks;
    assert!(resumed as u32 <= fault_end + recovery, "{what}: resumed only at {resumed}");
}

#[test]
fn compensation_resumes_only_with_a_prediction_from_healthy_samples() {
    // Short updates (the window's default share) and long ones (one per window).
    for config in [
        ServoConfig::default(),
        ServoConfig { model_updates_per_window: 1, min_model_interval_ticks: 800, ..ServoConfig::default() },
    ] {
        // Saturation: the clipped window's RMS is far above the real one.
        let (out, reference) = side_by_side(config, 14_000, |k, s| {
            if (6000..6300).contains(&k) {
                s.acc_code = if s.acc_code >= 0 { i16::MAX } else { i16::MIN };
            }
        });
        check_resume(config, "saturation", 6300, &out, &reference);
        // Stuck at a code.
        let (out, reference) = side_by_side(config, 14_000, |k, s| {
            if (6000..7500).contains(&k) {
                s.acc_code = 1234;
            }
        });
        check_resume(config, "stuck", 7500, &out, &reference);
    }
}

#[test]
fn a_missing_host_resumes_with_a_prediction_from_healthy_samples() {
    let config = ServoConfig::default();
    let (mut faulted, mut clean) = (twin(config), twin(config));
    let (mut outputs, mut reference) = (Vec::new(), Vec::new());
    for k in 0..12_000u32 {
        if k == 6000 {
            for _ in 0..50 {
                faulted.tick(None);
            }
        }
        outputs.push(faulted.tick(Some(&input(k))));
        reference.push(clean.tick(Some(&input(k))));
    }
    check_resume(config, "underrun", 6000, &outputs, &reference);
}
