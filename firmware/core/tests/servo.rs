//! The servo pipeline end to end on the host: model timing, bit-identity of the split
//! (firmware-like) and the synchronous (host) schedules, faults and fallbacks.

use sts_twin_core::axis::{AxisParams, Friction};
use sts_twin_core::bus::{InputSlot, OutputSlot, IN_FLAG_PHASE_VALID, OUT_FLAG_DEGRADED};
use sts_twin_core::commands::DefaultCommandRing;
use sts_twin_core::features::{DefaultSpectralRings, FeatureConfig};
use sts_twin_core::feedforward::FeedforwardParams;
use sts_twin_core::program::{paper_program, Program, ProgramBuilder, TickTerm, REG_AMP_UM, REG_PHASE_DEG};
use sts_twin_core::servo::{Models, Servo, ServoConfig, DEGRADED_STUCK};
use sts_twin_core::supervisor::SupervisorParams;
use sts_twin_core::twin::Twin;
use sts_twin_core::wire::{ConfigSource, Rejection, Request, Response};

const FS_HZ: f64 = 8000.0;

/// A small window keeps the tests fast: 0.25 s.
fn feature_config() -> FeatureConfig {
    FeatureConfig { window_samples: 2000, ..FeatureConfig::DEFAULT }
}

fn servo_config() -> ServoConfig {
    ServoConfig { model_interval_ticks: 400, model_latency_ticks: 200, ..ServoConfig::default() }
}

fn params() -> FeedforwardParams {
    FeedforwardParams { enable_ramp_ticks: 400, slew_v_per_tick: 0.05, ..FeedforwardParams::default() }
}

/// Tick `k` of a 40 Hz motion: acceleration 0.5 m/s^2 amplitude at 1e-4 m/s^2 per LSB plus a
/// deterministic pseudo-noise.
fn input(k: u32) -> InputSlot {
    let t = k as f64 / FS_HZ;
    let phase = 2.0 * std::f64::consts::PI * 40.0 * t;
    let noise = ((k.wrapping_mul(2_654_435_761) >> 16) % 7) as f64 - 3.0;
    let acc_code = (-5000.0 * phase.sin() + noise).round() as i16;
    let cmd_phase_turns = ((40.0 * t).fract() * 4_294_967_296.0) as u64 as u32;
    InputSlot {
        tick: k,
        acc_code,
        flags: IN_FLAG_PHASE_VALID,
        cmd_phase_turns,
        cmd_pos_nm: (3000.0 * phase.sin()) as i32,
        ..Default::default()
    }
}

/// A simple twin: amplitude = 2 * RMS (um per m/s^2), phase = -0.2 * f1 degrees.
fn rms_program(id: u32) -> Program {
    let mut b = ProgramBuilder::new();
    b.id(id).constant(2.0).feature(4).mul().store(REG_AMP_UM);
    b.constant(-0.2).feature(0).mul().store(REG_PHASE_DEG);
    b.finish().unwrap()
}

/// The simple twin with a servo-axis twin of the default emulated machine (per kg of its 45
/// kg slide) with Coulomb friction.
fn axis_program(id: u32) -> Program {
    let m = 45.0;
    let friction = Friction { coulomb_mps2: 3.0 / m, static_mps2: 4.5 / m, stribeck_mps: 2e-4, smooth_mps: 1e-5 };
    let axis = AxisParams { friction: Some(friction), ..sts_twin_core::axis::default_machine() };
    let mut program = rms_program(id);
    program.terms.push(TickTerm::Axis(axis)).unwrap();
    program
}

/// The supervisor is switched off: these input streams are open loop (the accelerometer does
/// not see the DAC), so there is no machine for it to judge (the rig's and the HIL tests
/// judge it in the closed loop).
fn booted_twin_with(program: Program) -> Box<Twin> {
    booted_twin_supervised(program, SUPERVISOR_OFF)
}

const SUPERVISOR_OFF: SupervisorParams = SupervisorParams { active: false, ..SupervisorParams::DEFAULT };

fn booted_twin_supervised(program: Program, supervisor: SupervisorParams) -> Box<Twin> {
    let mut twin = Box::new(Twin::boot(feature_config(), servo_config(), &[]));
    assert_eq!(twin.handle(Request::SetParams(params())), Response::Ack);
    assert_eq!(twin.handle(Request::SetSupervisor(supervisor)), Response::Ack);
    assert_eq!(twin.handle(Request::UploadProgram { program, activate: true }), Response::Ack);
    assert_eq!(twin.handle(Request::SetEnabled(true)), Response::Ack);
    twin
}

fn booted_twin() -> Box<Twin> {
    booted_twin_with(rms_program(7))
}

fn status(twin: &mut Twin) -> sts_twin_core::wire::Status {
    match twin.handle(Request::GetStatus) {
        Response::Status(status) => status,
        other => panic!("unexpected {other:?}"),
    }
}

#[test]
fn the_model_takes_effect_and_the_output_follows_it() {
    let mut twin = booted_twin();
    let mut outputs = Vec::new();
    for k in 0..8000 {
        outputs.push(twin.tick(Some(&input(k))));
    }
    let status = match twin.handle(Request::GetStatus) {
        Response::Status(status) => status,
        other => panic!("unexpected {other:?}"),
    };
    assert_eq!(status.program_id, Some(7));
    assert!(status.counters.model_updates >= 15, "{:?}", status.counters);
    // RMS of a 0.5 m/s^2 sine is 0.354 m/s^2 -> 0.707 um; f1 = 40 Hz -> -8 degrees.
    assert!((status.amp_um - 0.707).abs() < 0.01, "amp {}", status.amp_um);
    assert!((status.phase_deg + 8.0).abs() < 0.05, "phase {}", status.phase_deg);
    assert!((status.features[0] - 40.0).abs() < 0.1, "f1 {}", status.features[0]);
    // The last second: DE amplitude 0.707 um = 0.707 V at K_dv 1 um/V = 2317 codes, negated.
    let peak = outputs[7000..].iter().map(|o| o.dac_code.unsigned_abs()).max().unwrap();
    assert!((2250..=2330).contains(&peak), "peak code {peak}");
    assert_eq!(status.counters.model_faults, 0);
    assert_eq!(status.counters.model_late, 0);
}

/// The firmware computes the model at low priority some time after the request; the host
/// computes it at once. Both must write the same DAC codes, bit for bit: also with an axis
/// twin, whose compensator reads the ticks' commands from the ring while the servo goes on,
/// and with the supervisor judging each update (here it holds compensation off until its
/// baseline, then lets it in).
#[test]
fn a_late_computed_model_gives_bit_identical_output() {
    for supervisor in [SUPERVISOR_OFF, SupervisorParams::default()] {
        late_computed_models_give_bit_identical_output(rms_program(7), supervisor);
        late_computed_models_give_bit_identical_output(axis_program(7), supervisor);
    }
}

fn late_computed_models_give_bit_identical_output(program: Program, supervisor: SupervisorParams) {
    let mut host = booted_twin_supervised(program.clone(), supervisor);
    let expected: Vec<OutputSlot> = (0..6000).map(|k| host.tick(Some(&input(k)))).collect();
    if supervisor.active {
        // Held off until two bare windows agree, then let in.
        assert_ne!(host.servo().supervisor_state().bare_freq_hz, 0.0);
        assert!(expected.iter().any(|o| o.flags & OUT_FLAG_DEGRADED != 0));
        assert!(expected.last().is_some_and(|o| o.flags & OUT_FLAG_DEGRADED == 0));
    }

    let rings = Box::new(DefaultSpectralRings::new());
    let commands = Box::new(DefaultCommandRing::new());
    let (servo, check) = Servo::new(feature_config(), servo_config(), params());
    assert_eq!(check, Ok(()));
    let mut servo = Box::new(servo);
    servo.set_supervisor_params(supervisor).unwrap();
    let mut models = Box::new(Models::new());
    models.upload(program, true).unwrap();
    servo.set_enabled(true);
    let mut queue = Vec::new();
    let latency = servo.model_timing().latency_ticks;
    for k in 0..6000u32 {
        let (output, requested) = servo.tick(&rings, &commands, &input(k));
        assert_eq!(output, expected[k as usize], "tick {k}");
        let request = servo.take_request();
        assert_eq!(requested, request.is_some(), "tick {k}");
        if let Some(request) = request {
            // Computed 1..=latency ticks later, while the servo keeps pushing samples.
            queue.push((k + 1 + (k * 7919) % latency, request));
        }
        while let Some(pos) = queue.iter().position(|(at, _)| *at == k) {
            let (_, request) = queue.remove(pos);
            let path = *servo.analogue_path();
            servo.deliver(models.compute(&rings, &commands, &request, &path));
        }
    }
    assert_eq!(servo.counters().model_late, 0);
}

/// A program with an axis twin compensates through it: the correction it learns joins the
/// program's fundamental (here 0.707 um from the formulas) and cancels the simulated axis's
/// error on the 3 um, 40 Hz command (microns: `|G - 1|` is 0.97 there).
#[test]
fn an_axis_twin_program_compensates_through_its_learned_correction() {
    let mut plain = booted_twin();
    let mut axis = booted_twin_with(axis_program(8));
    let (mut plain_out, mut axis_out) = (Vec::new(), Vec::new());
    for k in 0..16_000 {
        plain_out.push(plain.tick(Some(&input(k))));
        axis_out.push(axis.tick(Some(&input(k))));
    }
    let (plain, axis) = (status(&mut plain), status(&mut axis));
    assert_eq!(axis.program_id, Some(8));
    assert_eq!((axis.counters.axis_resets, axis.counters.model_faults, axis.counters.model_late), (0, 0, 0));
    assert!((plain.amp_um - 0.707).abs() < 0.01, "{}", plain.amp_um);
    assert!(axis.amp_um > 1.0 && axis.amp_um < 5.0, "fundamental with the correction {} um", axis.amp_um);
    let most = plain_out[12_000..]
        .iter()
        .zip(&axis_out[12_000..])
        .map(|(a, b)| (i64::from(a.de_pred_pm) - i64::from(b.de_pred_pm)).abs())
        .max()
        .unwrap();
    assert!(most > 1_000_000, "the correction adds at most {most} pm");
}

#[test]
fn a_malformed_program_is_rejected_and_the_old_one_stays() {
    let mut twin = booted_twin();
    let mut bad = rms_program(9);
    bad.code[1] = 40; // constant index past the table
    match twin.handle(Request::UploadProgram { program: bad, activate: true }) {
        Response::Rejected(Rejection::Program(_)) => {}
        other => panic!("unexpected {other:?}"),
    }
    for k in 0..4000 {
        twin.tick(Some(&input(k)));
    }
    assert_eq!(twin.servo().program_id(), Some(7));
    assert_eq!(twin.servo().counters().rejected_programs, 1);
    assert_eq!(twin.handle(Request::ActivateStaged), Response::Rejected(Rejection::NoStagedProgram));
}

#[test]
fn a_stuck_accelerometer_ramps_compensation_out_without_a_step_and_recovers() {
    let mut twin = booted_twin();
    let max_step = 1 + (0.05 / (10.0 / 32767.0)) as i32 + 1;
    let mut last: Option<i16> = None;
    let mut degraded_seen = false;
    let mut gain_after_fault = 1.0;
    for k in 0..20_000u32 {
        let mut slot = input(k);
        if (6000..9000).contains(&k) {
            slot.acc_code = 1234; // stuck
        }
        let out = twin.tick(Some(&slot));
        if let Some(prev) = last {
            assert!((out.dac_code as i32 - prev as i32).abs() <= max_step, "step at tick {k}");
        }
        last = Some(out.dac_code);
        if out.flags & OUT_FLAG_DEGRADED != 0 {
            degraded_seen = true;
        }
        if k == 8999 {
            gain_after_fault = twin.servo().gain();
            assert_ne!(twin.servo().degraded() & DEGRADED_STUCK, 0);
        }
    }
    assert!(degraded_seen);
    assert_eq!(gain_after_fault, 0.0);
    assert_eq!(twin.servo().counters().input_stuck, 1);
    assert_eq!(twin.servo().degraded(), 0, "recovered after a clean window");
    assert_eq!(twin.servo().gain(), 1.0);
}

#[test]
fn saturation_bursts_and_missing_input_are_counted_and_degrade() {
    let mut twin = booted_twin();
    for k in 0..4000u32 {
        let mut slot = input(k);
        if (3000..3100).contains(&k) {
            slot.acc_code = i16::MAX;
        }
        twin.tick(Some(&slot));
    }
    assert_eq!(twin.servo().counters().input_saturated, 1);
    assert_ne!(twin.servo().degraded(), 0);
    let held = twin.tick(None);
    for _ in 0..20 {
        assert_eq!(twin.tick(None).dac_code, held.dac_code);
    }
    assert_eq!(twin.servo().counters().bus_underruns, 21);
}

#[test]
fn the_config_store_round_trips_and_a_corrupt_one_falls_back() {
    let mut twin = booted_twin();
    let calibrated = FeedforwardParams { offset_v: 0.0042, ..params() };
    let lab_thresholds = sts_twin_core::supervisor::SupervisorParams {
        worse_ratio: 1.25,
        min_motion_share: 0.3,
        ..sts_twin_core::supervisor::SupervisorParams::DEFAULT
    };
    assert_eq!(twin.handle(Request::SetParams(calibrated)), Response::Ack);
    assert_eq!(twin.handle(Request::SetSupervisor(lab_thresholds)), Response::Ack);
    assert_eq!(twin.handle(Request::SaveConfig), Response::Ack);
    let record = twin.stored_config().to_vec();
    let mut rebooted = Twin::boot(feature_config(), servo_config(), &record);
    match rebooted.handle(Request::GetStatus) {
        Response::Status(status) => {
            assert_eq!(status.params, calibrated);
            assert_eq!(status.supervisor_params, lab_thresholds, "the lab's thresholds survive a power cycle");
            assert_eq!(status.config_source, ConfigSource::Stored);
        }
        other => panic!("unexpected {other:?}"),
    }
    let mut corrupt = record.clone();
    corrupt[10] ^= 0xff;
    let mut fallback = Twin::boot(feature_config(), servo_config(), &corrupt);
    match fallback.handle(Request::GetStatus) {
        Response::Status(status) => {
            assert_eq!(status.params, FeedforwardParams::default());
            assert_eq!(status.config_source, ConfigSource::DefaultsAfterCorrupt);
            assert!(!status.enabled);
        }
        other => panic!("unexpected {other:?}"),
    }
}

#[test]
fn bad_parameters_are_rejected_and_counted() {
    let mut twin = booted_twin();
    let bad = FeedforwardParams { k_dv_um_per_v: f32::NAN, ..params() };
    assert!(matches!(twin.handle(Request::SetParams(bad)), Response::Rejected(Rejection::Params(_))));
    assert_eq!(twin.servo().params(), params());
    assert_eq!(twin.servo().counters().rejected_params, 1);
}

#[test]
fn bad_feature_settings_are_rejected_and_counted() {
    let mut twin = booted_twin();
    let faults = twin.servo().fault_count();
    for window_samples in [0, u32::MAX] {
        let bad = FeatureConfig { window_samples, ..feature_config() };
        assert!(
            matches!(twin.handle(Request::SetFeatureConfig(bad)), Response::Rejected(_)),
            "window {window_samples}"
        );
    }
    assert_eq!(twin.servo().counters().rejected_feature_configs, 2);
    assert_eq!(twin.servo().fault_count(), faults + 2);
    assert_eq!(twin.handle(Request::SetFeatureConfig(feature_config())), Response::Ack);
    assert_eq!(twin.servo().counters().rejected_feature_configs, 2);
}

#[test]
fn the_paper_program_runs_in_the_pipeline() {
    let mut twin = Box::new(Twin::boot(feature_config(), servo_config(), &[]));
    assert_eq!(twin.handle(Request::UploadProgram { program: paper_program(), activate: true }), Response::Ack);
    for k in 0..4000 {
        twin.tick(Some(&input(k)));
    }
    let out = twin.servo().last_output();
    assert!(out.amp_um().is_finite() && out.amp_um() > 0.0);
    assert_eq!(twin.servo().counters().model_faults, 0);
}
