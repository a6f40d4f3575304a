//! The twin firmware in QEMU against the host: bit-identity with the host core, program
//! upload and rejection, corrupted control frames, a million ticks, no steps on the DAC.

use std::time::Duration;

use sts_hil::HilConfig;
use sts_rig::{expect_ack, Coprocessor, HilCoprocessor, SimCoprocessor};
use sts_twin_core::bus::{InputSlot, OutputSlot};
use sts_twin_core::feedforward::FeedforwardParams;
use sts_twin_core::program::{Program, TickTerm};
use sts_twin_core::wire::{encode_frame, Rejection, Request, Response, Status, MAX_ENCODED_FRAME, PROTOCOL_VERSION};

use sts_hil_tests::tone_input as input;
use sts_hil_tests::twin::{boot, configure, params, program, status};

/// The tone stream with the other axes moving: X acceleration (3 Hz, 2 m/s^2) and the spindle
/// (10 revolutions per second).
fn input_with_axes(k: u32) -> InputSlot {
    let t = f64::from(k) / 8000.0;
    InputSlot {
        x_acc_um_per_s2: (2e6 * (2.0 * std::f64::consts::PI * 3.0 * t).sin()) as i32,
        spindle_turns: k.wrapping_mul(5_368_709), // 2^32 * 10 / 8000
        ..input(k)
    }
}

/// The test program plus an axis-coupling term (0.5 um per m/s^2, 80 nm once per revolution).
fn program_with_coupling(id: u32) -> sts_twin_core::program::Program {
    let mut p = program(id, 2.0);
    p.terms
        .push(TickTerm::AxisCoupling {
            x_gain_pm_per_mps2: 500_000,
            spindle_amp_pm: 80_000,
            spindle_phase_turns: 1 << 30,
        })
        .unwrap();
    p
}

/// a) The firmware's DAC codes equal the host core's, bit for bit, on the same stream, with
/// every input word in use (the axis-coupling term reads the X acceleration and spindle words).
#[test]
fn dac_codes_are_bit_identical_to_the_host_core() {
    let _serial = sts_hil_tests::serial();
    dac_codes_are_the_host_cores_on(sts_hil_tests::twin_config());
}

/// The body of [`dac_codes_are_bit_identical_to_the_host_core`] on the board `config` boots.
pub(crate) fn dac_codes_are_the_host_cores_on(config: HilConfig) {
    let inputs: Vec<InputSlot> = (0..24_000).map(input_with_axes).collect();
    let mut sim = SimCoprocessor::boot(&[]);
    configure(&mut sim, Some(program_with_coupling(11)));
    let expected: Vec<OutputSlot> = inputs.iter().map(|i| sim.tick(i).unwrap()).collect();
    // The other axes' words matter: without them the same core predicts something else.
    let mut still = SimCoprocessor::boot(&[]);
    configure(&mut still, Some(program_with_coupling(11)));
    let differing = (0..24_000)
        .map(input)
        .zip(&expected)
        .filter(|(i, e)| still.tick(i).unwrap().de_pred_pm != e.de_pred_pm)
        .count();
    assert!(differing > 20_000, "the axis-coupling term changed only {differing} predictions");

    let mut hil = HilCoprocessor::start(config).expect("the twin firmware boots in QEMU");
    configure(&mut hil, Some(program_with_coupling(11)));
    let outputs = hil.hil().run_open_loop(&inputs).expect("stream");
    assert_eq!(outputs.len(), expected.len());
    for (k, (got, want)) in outputs.iter().zip(&expected).enumerate() {
        assert_eq!(got, want, "tick {k} differs");
    }
    let fw = status(&mut hil);
    // 24,000 ticks at one update per 112 ticks (a 2,000-tick window), after the window filled.
    assert!(fw.counters.model_updates >= 25, "{:?}", fw.counters);
    assert_eq!(fw.counters.model_late, 0);
    assert_eq!(fw.counters.bus_underruns, 0);
    // Some of the outputs are non-trivial.
    assert!(outputs.iter().any(|o| o.dac_code.unsigned_abs() > 1000));
    hil.shutdown().unwrap();
}

/// Runs `program` on `inputs` in the host core and in the firmware under QEMU, asserts that
/// every tick's output is the same bit for bit (`what` names the case), and returns the
/// host's outputs and the firmware's status.
fn bit_identical_run(program: Program, inputs: &[InputSlot], what: &str) -> (Vec<OutputSlot>, Status) {
    let mut sim = SimCoprocessor::boot(&[]);
    configure(&mut sim, Some(program.clone()));
    let expected: Vec<OutputSlot> = inputs.iter().map(|i| sim.tick(i).unwrap()).collect();
    let mut hil = boot();
    configure(&mut hil, Some(program));
    let outputs = hil.hil().run_open_loop(inputs).expect("stream");
    let fw = status(&mut hil);
    hil.shutdown().unwrap();
    assert_eq!(outputs.len(), expected.len());
    for (k, (got, want)) in outputs.iter().zip(&expected).enumerate() {
        assert_eq!(got, want, "{what}: tick {k} differs");
    }
    (expected, fw)
}

/// The largest difference, pm, between `outputs` and what the host core predicts on the same
/// inputs with `without` (the program less the terms under test).
fn most_added_pm(outputs: &[OutputSlot], without: Program, inputs: &[InputSlot]) -> i64 {
    let mut plain = SimCoprocessor::boot(&[]);
    configure(&mut plain, Some(without));
    inputs
        .iter()
        .zip(outputs)
        .map(|(i, o)| (i64::from(o.de_pred_pm) - i64::from(plain.tick(i).unwrap().de_pred_pm)).abs())
        .max()
        .unwrap_or(0)
}

/// The servo-axis twin (single-precision simulation of the axis in the tick) gives the same
/// DAC codes in the firmware as in the host core, bit for bit, with each of its effects, each
/// pair and all three (each a separately compiled instance of its step), and all three with a
/// second structural mode, the compensator learning at low priority without a late model
/// result.
#[test]
fn the_axis_twin_is_bit_identical_to_the_host_core() {
    use sts_twin_core::axis::{AxisParams, Friction, Hysteresis, Ripple, StructuralMode};
    let _serial = sts_hil_tests::serial();
    let axis = sts_twin_core::axis::default_machine();
    let friction = Some(Friction { coulomb_mps2: 0.067, static_mps2: 0.1, stribeck_mps: 2e-4, smooth_mps: 1e-5 });
    let hysteresis = Some(Hysteresis { force_mps2: 0.056, stiffness_per_s2: 66_667.0 });
    let ripple = Some(Ripple { amp_nm: 50.0, harmonic2_nm: 8.0, turns_per_nm: 810_383, phase_turns: 1 << 29 });
    let second_mode = Some(StructuralMode { freq_hz: 210.0, damping: 0.03, tcp_gain: 0.9 });
    // Each effect alone, each pair and all three (a machine has several at once).
    let variants = [
        AxisParams { friction, ..axis },
        AxisParams { hysteresis, ..axis },
        AxisParams { ripple, ..axis },
        AxisParams { friction, hysteresis, ..axis },
        AxisParams { friction, ripple, ..axis },
        AxisParams { hysteresis, ripple, ..axis },
        AxisParams { friction, hysteresis, ripple, ..axis },
        AxisParams { friction, hysteresis, ripple, second_mode, ..axis },
    ];
    let inputs: Vec<InputSlot> = (0..8000).map(input).collect();
    for (i, params) in variants.into_iter().enumerate() {
        let mut p = program(61 + i as u32, 2.0);
        p.terms.push(TickTerm::Axis(params)).unwrap();
        let (expected, fw) = bit_identical_run(p, &inputs, &format!("{params:?}"));
        let counters = fw.counters;
        // The twin's simulation and learning, at low priority, keep up with the model period.
        assert_eq!((counters.model_late, counters.axis_resets), (0, 0), "{params:?}: {counters:?}");
        assert!(counters.model_updates > 0, "{params:?}: {counters:?}");
        // The compensator's learned correction is in the output: microns on the 3 um, 40 Hz
        // command beside the program's own fundamental.
        let most = most_added_pm(&expected, program(61 + i as u32, 2.0), &inputs);
        assert!(most > 500_000, "{params:?}: the correction adds at most {most} pm");
    }
}

/// An in-band structural mode as `fit --effect structural-mode` carries it (a resonance in
/// f32 beside a Laguerre bank on the command velocity) and a late setpoint (the bank alone):
/// the same DAC codes in the firmware as in the host core, bit for bit, the resonance's
/// output in them.
#[test]
fn the_linear_response_terms_are_bit_identical_to_the_host_core() {
    use sts_twin_core::program::TermInput;
    let _serial = sts_hil_tests::serial();
    let bank = TickTerm::Laguerre {
        input: TermInput::VelocitySign { smooth_nm_per_4_ticks: 1800 },
        pole_q30: (0.93 * (1u64 << 30) as f64).round() as i32,
        gains_pm: [-120_000, 80_000, -45_000, 30_000, -20_000, 12_000, -6_000, 3_000],
    };
    // A mode at 38 Hz near the tone's 40 Hz, so that its output is large.
    let resonance = TickTerm::Resonance { freq_hz: 38.0, damping: 0.05, gain: 0.02 };
    let inputs: Vec<InputSlot> = (0..8000).map(input).collect();
    for (i, terms) in [vec![bank, resonance], vec![bank], vec![resonance]].into_iter().enumerate() {
        let mut p = program(71 + i as u32, 2.0);
        for t in &terms {
            p.terms.push(*t).unwrap();
        }
        let (expected, fw) = bit_identical_run(p, &inputs, &format!("{terms:?}"));
        assert_eq!(fw.counters.model_late, 0, "{terms:?}: {:?}", fw.counters);
        // The terms are in the output: without them the same core predicts otherwise.
        let most = most_added_pm(&expected, program(71 + i as u32, 2.0), &inputs);
        assert!(most > 10_000, "{terms:?}: the terms add at most {most} pm");
    }
}

/// b) and c): a new program changes the predictions; a malformed one is rejected and the old
/// one stays in force.
#[test]
fn uploads_change_the_prediction_and_malformed_programs_are_rejected() {
    let _serial = sts_hil_tests::serial();
    uploads_change_the_prediction_on(sts_hil_tests::twin_config());
}

/// The body of [`uploads_change_the_prediction_and_malformed_programs_are_rejected`] on the
/// board `config` boots.
pub(crate) fn uploads_change_the_prediction_on(config: HilConfig) {
    let mut hil = HilCoprocessor::start(config).expect("the twin firmware boots in QEMU");
    configure(&mut hil, Some(program(21, 1.0)));
    let inputs: Vec<InputSlot> = (0..6000).map(input).collect();
    hil.hil().run_open_loop(&inputs).unwrap();
    let before = status(&mut hil);
    assert_eq!(before.program_id, Some(21));

    expect_ack("upload", hil.request(Request::UploadProgram { program: program(22, 3.0), activate: true }).unwrap())
        .unwrap();
    let inputs: Vec<InputSlot> = (6000..12_000).map(input).collect();
    hil.hil().run_open_loop(&inputs).unwrap();
    let after = status(&mut hil);
    assert_eq!(after.program_id, Some(22));
    let ratio = after.amp_um / before.amp_um;
    assert!((2.0..4.5).contains(&ratio), "amplitude {} -> {}", before.amp_um, after.amp_um);

    let mut bad = program(23, 1.0);
    bad.code[3] = 12; // feature index past f12
    match hil.request(Request::UploadProgram { program: bad, activate: true }).unwrap() {
        Response::Rejected(Rejection::Program(_)) => {}
        other => panic!("a malformed program was not rejected: {other:?}"),
    }
    let inputs: Vec<InputSlot> = (12_000..16_000).map(input).collect();
    hil.hil().run_open_loop(&inputs).unwrap();
    let last = status(&mut hil);
    assert_eq!(last.program_id, Some(22), "the old program stays in force");
    assert_eq!(last.counters.rejected_programs, 1);
    hil.shutdown().unwrap();
}

/// d) Corrupted and truncated frames are counted and ignored; the loop never stalls.
#[test]
fn corrupted_and_truncated_frames_are_counted_and_ignored() {
    let _serial = sts_hil_tests::serial();
    bad_frames_are_counted_and_ignored_on(sts_hil_tests::twin_config());
}

/// The body of [`corrupted_and_truncated_frames_are_counted_and_ignored`] on the board
/// `config` boots.
pub(crate) fn bad_frames_are_counted_and_ignored_on(config: HilConfig) {
    let mut hil = HilCoprocessor::start(config).expect("the twin firmware boots in QEMU");
    configure(&mut hil, Some(program(31, 1.0)));
    let mut frame = [0u8; MAX_ENCODED_FRAME];
    let len = encode_frame(500, &Request::Ping { nonce: 77 }, &mut frame).unwrap();
    let mut flipped = frame;
    // A flipped bit that does not create a delimiter inside the frame.
    flipped[len / 2] ^= if flipped[len / 2] == 0x21 { 0x42 } else { 0x21 };
    let mut truncated = frame[..len / 2].to_vec();
    truncated.push(0);
    for bad in [&flipped[..len], &truncated[..], &[0x03, 0xff, 0x00][..]] {
        let reply = hil.exchange_raw(bad, Duration::from_millis(300));
        assert!(reply.map(|r| r.is_empty()).unwrap_or(true), "a bad frame was answered");
        hil.hil().run_open_loop(&(0..400).map(input).collect::<Vec<_>>()).expect("the loop keeps running");
    }
    assert_eq!(
        hil.request(Request::Ping { nonce: 78 }).unwrap(),
        Response::Pong { nonce: 78, protocol_version: PROTOCOL_VERSION }
    );
    let s = status(&mut hil);
    assert_eq!(s.counters.frame_errors, 3, "{:?}", s.counters);
    hil.shutdown().unwrap();
}

/// e) A million ticks: every one served, in order, no underrun, overrun or fault.
#[test]
fn a_million_ticks_without_a_fault_or_a_missed_tick() {
    let _serial = sts_hil_tests::serial();
    let mut hil = boot();
    configure(&mut hil, Some(program(41, 1.0)));
    let mut next = 0u32;
    let mut first_bad: Option<OutputSlot> = None;
    let served = hil
        .hil()
        .stream_open_loop((0..1_000_000u32).map(input), |o| {
            if (o.tick != next || o.fault_count != 0) && first_bad.is_none() {
                first_bad = Some(o);
            }
            next = next.wrapping_add(1);
        })
        .expect("stream of a million ticks");
    assert_eq!(served, 1_000_000);
    assert_eq!(
        first_bad,
        None,
        "a tick was missed, out of order or faulty (expected tick {next}); {:?}",
        status(&mut hil).counters
    );
    let s = status(&mut hil);
    assert_eq!(s.counters.ticks, 1_000_000);
    assert_eq!(s.counters.bus_underruns, 0);
    assert_eq!(s.counters.bus_overruns, 0);
    assert_eq!(s.counters.model_faults, 0);
    assert_eq!(s.counters.model_late, 0);
    hil.shutdown().unwrap();
}

/// f) Enabling, disabling and changing the offset never step the DAC beyond the slew limit.
#[test]
fn offset_changes_and_enable_never_step_the_dac() {
    let _serial = sts_hil_tests::serial();
    parameter_changes_never_step_the_dac_on(sts_hil_tests::twin_config());
}

/// The body of [`offset_changes_and_enable_never_step_the_dac`] on the board `config` boots.
pub(crate) fn parameter_changes_never_step_the_dac_on(config: HilConfig) {
    let mut hil = HilCoprocessor::start(config).expect("the twin firmware boots in QEMU");
    configure(&mut hil, Some(program(51, 2.0)));
    expect_ack("disable", hil.request(Request::SetEnabled(false)).unwrap()).unwrap();
    let limit = 1 + (0.05f64 / (10.0 / 32767.0)).ceil() as i32;
    let mut last: Option<i16> = None;
    let mut k = 0u32;
    let mut run = |hil: &mut HilCoprocessor, ticks: u32| {
        let inputs: Vec<InputSlot> = (k..k + ticks).map(input).collect();
        k += ticks;
        for o in hil.hil().run_open_loop(&inputs).unwrap() {
            if let Some(prev) = last {
                assert!(
                    (o.dac_code as i32 - prev as i32).abs() <= limit,
                    "step {prev} -> {} at tick {}",
                    o.dac_code,
                    o.tick
                );
            }
            last = Some(o.dac_code);
        }
    };
    run(&mut hil, 4000);
    expect_ack("enable", hil.request(Request::SetEnabled(true)).unwrap()).unwrap();
    run(&mut hil, 4000);
    let offset = FeedforwardParams { offset_v: 1.5, ..params() };
    expect_ack("offset", hil.request(Request::SetParams(offset)).unwrap()).unwrap();
    run(&mut hil, 4000);
    expect_ack("disable", hil.request(Request::SetEnabled(false)).unwrap()).unwrap();
    run(&mut hil, 4000);
    // The offset was followed: -1.5 V is about -4915 codes.
    assert!((last.unwrap() as i32 + 4915).abs() < 20, "settled at {:?}", last);
    hil.shutdown().unwrap();
}
