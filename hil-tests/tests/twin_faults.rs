//! Faults, with the twin firmware in QEMU: a saturating, stuck or dead accelerometer, no
//! model, malformed and non-finite models, K_dv = 0 or NaN, a host that stops feeding
//! samples, and a control link that drops 1% and corrupts 0.1% of its frames.
//!
//! For each: the DAC never steps beyond the slew limit, compensation ramps to zero with
//! `OUT_FLAG_DEGRADED` / `Status::degraded` while the inputs cannot be trusted, it resumes
//! when they return, every fault is counted in `Status::counters`, the host's fault report
//! names it, and QEMU is still running (no panic, no HardFault) at the end.

use std::time::{Duration, Instant};

use sts_rig::{
    expect_ack, fault_report, Coprocessor, FrameInjector, HilCoprocessor, LinkFaults, LossyHilCoprocessor, RetryPolicy,
    SimCoprocessor,
};
use sts_twin_core::bus::{InputSlot, OutputSlot, OUT_FLAG_DEGRADED, OUT_FLAG_MODEL_ACTIVE};
use sts_twin_core::feedforward::{Feedforward, FeedforwardParams, ParamError};
use sts_twin_core::program::{Program, ProgramBuilder, REG_AMP_UM, REG_PHASE_DEG};
use sts_twin_core::servo::{
    ModelTiming, ServoConfig, DEGRADED_MODEL, DEGRADED_NO_INPUT, DEGRADED_SATURATED, DEGRADED_STUCK,
};
use sts_twin_core::wire::{Rejection, Request, Response, Status, PROTOCOL_VERSION};

use sts_hil_tests::twin::{boot, configure, params, program, status, ENABLE_RAMP_TICKS as RAMP, WINDOW};

/// Model interval and latency for the window.
fn timing() -> ModelTiming {
    ModelTiming::new(&ServoConfig::default(), WINDOW)
}

/// Healthy ticks before compensation resumes after an input fault: a clean window, then a
/// model result computed on it and the synthesiser's ramp to it.
fn recovery_ticks() -> u32 {
    WINDOW + timing().interval_ticks + timing().latency_ticks + ServoConfig::default().synth_ramp_ticks
}

/// The largest DAC step one tick may make under `params()`.
fn slew_limit_codes() -> i32 {
    Feedforward::new(params()).0.max_step_codes()
}

/// A program that validates but whose amplitude is 1/0 = inf at every evaluation.
fn non_finite_program(id: u32) -> Program {
    let mut b = ProgramBuilder::new();
    b.id(id).constant(1.0).constant(0.0).div().store(REG_AMP_UM);
    b.constant(0.0).store(REG_PHASE_DEG);
    b.finish().unwrap()
}

use sts_hil_tests::tone_input as input;

/// Streams ticks through the firmware and checks every output: in order, and never a DAC
/// step beyond the slew limit, across all calls. With an oracle (the host core, configured
/// like the firmware), also keeps what the fault-free input gives there.
struct Stream {
    next: u32,
    last_dac: Option<i16>,
    limit: i32,
    oracle: Option<SimCoprocessor>,
    /// The oracle's outputs of the last run.
    clean: Vec<OutputSlot>,
}

impl Stream {
    fn new() -> Self {
        Self { next: 0, last_dac: None, limit: slew_limit_codes(), oracle: None, clean: Vec::new() }
    }

    fn with_oracle(oracle: SimCoprocessor) -> Self {
        Self { oracle: Some(oracle), ..Self::new() }
    }

    /// `ticks` ticks of the clean input, with `fault(offset, input)` applied to each.
    fn run(
        &mut self,
        hil: &mut HilCoprocessor,
        ticks: u32,
        mut fault: impl FnMut(u32, &mut InputSlot),
    ) -> Vec<OutputSlot> {
        let first = self.next;
        if let Some(oracle) = &mut self.oracle {
            self.clean = (first..first + ticks).map(|k| oracle.tick(&input(k)).unwrap()).collect();
        }
        let inputs: Vec<InputSlot> = (0..ticks)
            .map(|i| {
                let mut slot = input(first + i);
                fault(i, &mut slot);
                slot
            })
            .collect();
        let outputs = hil.hil().run_open_loop(&inputs).expect("the firmware serves every tick");
        assert_eq!(outputs.len(), inputs.len());
        self.check(&outputs);
        outputs
    }

    fn check(&mut self, outputs: &[OutputSlot]) {
        for o in outputs {
            assert_eq!(o.tick, self.next, "ticks out of order");
            if let Some(prev) = self.last_dac {
                let step = (i32::from(o.dac_code) - i32::from(prev)).abs();
                assert!(
                    step <= self.limit,
                    "DAC step {prev} -> {} at tick {} beyond the slew limit {}",
                    o.dac_code,
                    o.tick,
                    self.limit
                );
            }
            self.last_dac = Some(o.dac_code);
            self.next += 1;
        }
    }
}

fn degraded(o: &OutputSlot) -> bool {
    o.flags & OUT_FLAG_DEGRADED != 0
}

fn peak_dac(outputs: &[OutputSlot]) -> i32 {
    outputs.iter().map(|o| i32::from(o.dac_code).abs()).max().unwrap_or(0)
}

/// Compensating: trusted inputs, a model in force and a DAC that moves.
fn assert_compensating(outputs: &[OutputSlot], what: &str) {
    assert!(
        outputs.iter().all(|o| !degraded(o) && o.flags & OUT_FLAG_MODEL_ACTIVE != 0),
        "{what}: not compensating: {:?}",
        outputs.iter().find(|o| degraded(o) || o.flags & OUT_FLAG_MODEL_ACTIVE == 0)
    );
    assert!(peak_dac(outputs) > 500, "{what}: the DAC does not compensate (peak {})", peak_dac(outputs));
}

/// Ramped to zero compensation (offset 0 V: DAC code 0), flagged degraded.
fn assert_ramped_out(outputs: &[OutputSlot], what: &str) {
    assert!(
        outputs.iter().all(|o| degraded(o) && o.dac_code == 0),
        "{what}: not ramped out: {:?}",
        outputs.iter().find(|o| !degraded(o) || o.dac_code != 0)
    );
}

/// QEMU still runs, the firmware logged no error (panic, HardFault), and QEMU is ended.
fn finish(mut hil: HilCoprocessor) {
    hil.hil().alive("the end of the fault test").expect("QEMU is still running");
    let errors: Vec<String> = hil.hil().logs().iter().filter(|l| l.level == "ERROR").map(|l| l.to_string()).collect();
    assert!(errors.is_empty(), "the firmware logged errors: {errors:#?}");
    hil.shutdown().unwrap();
}

/// Asserts that the host's fault report has a line containing `text`.
fn assert_reported(status: &Status, text: &str) {
    let lines = fault_report(status);
    assert!(lines.iter().any(|l| l.contains(text)), "the fault report does not mention {text:?}: {lines:#?}");
}

/// Runs of full-scale codes of at least `limit` ticks (each is one saturation episode).
fn saturation_episodes(codes: impl IntoIterator<Item = i16>, limit: u32) -> u32 {
    let mut run = 0u32;
    let mut episodes = 0;
    for code in codes {
        run = if code == i16::MAX || code <= -i16::MAX { run + 1 } else { 0 };
        episodes += (run == limit) as u32;
    }
    episodes
}

/// ADC saturation bursts, a stuck accelerometer and a dead one (constant zero), one after
/// the other on one boot: each is detected, flagged, ramped out, counted, reported, and
/// compensation resumes once a whole feature window of healthy samples has come in.
#[test]
fn accelerometer_faults_ramp_compensation_out_and_it_resumes() {
    let _serial = sts_hil_tests::serial();
    let servo = ServoConfig::default();
    let mut hil = boot();
    configure(&mut hil, Some(program(61, 2.0)));
    let mut oracle = SimCoprocessor::boot(&[]);
    configure(&mut oracle, Some(program(61, 2.0)));
    let mut stream = Stream::with_oracle(oracle);
    let warm = stream.run(&mut hil, 6000, |_, _| {});
    assert_compensating(&warm[5200..], "after the warm-up");
    assert_eq!(warm, stream.clean, "the firmware is the host core, bit for bit");

    // Saturation: four 60-tick bursts at the rails, 200 ticks apart, the last one ending
    // the phase.
    let burst = |i: u32, slot: &mut InputSlot| {
        if i % 200 < 60 {
            slot.acc_code = if (i / 200).is_multiple_of(2) { i16::MAX } else { i16::MIN };
        }
    };
    // Stuck at an arbitrary code, and dead (zero).
    let stuck_at = |code: i16| move |_: u32, slot: &mut InputSlot| slot.acc_code = code;
    type Fault = Box<dyn Fn(u32, &mut InputSlot)>;
    let phases: [(&str, u32, Fault, u16, u32); 3] = [
        ("saturation bursts", 660, Box::new(burst), DEGRADED_SATURATED, servo.saturation_limit_ticks - 1),
        ("stuck accelerometer", 1600, Box::new(stuck_at(1234)), DEGRADED_STUCK, servo.stuck_limit_ticks),
        ("dead accelerometer", 1600, Box::new(stuck_at(0)), DEGRADED_STUCK, servo.stuck_limit_ticks),
    ];
    for (what, ticks, fault, bit, detected_at) in phases {
        let before = status(&mut hil);
        let first = stream.next;
        let faulty = stream.run(&mut hil, ticks, |i, slot| fault(i, slot));
        // Detected exactly when the limit is reached, not before.
        assert!(faulty[..detected_at as usize].iter().all(|o| !degraded(o)), "{what}: degraded before detection");
        assert!(faulty[detected_at as usize..].iter().all(degraded), "{what}: not flagged degraded after detection");
        // Ramped to zero compensation within the gain ramp, without a step (checked by `run`).
        assert_ramped_out(&faulty[(detected_at + RAMP + 20) as usize..], what);
        let during = status(&mut hil);
        assert_ne!(during.degraded & bit, 0, "{what}: degraded bits {:#x}", during.degraded);
        let c0 = &before.counters;
        let c1 = &during.counters;
        if bit == DEGRADED_SATURATED {
            let codes = (0..ticks).map(|i| {
                let mut slot = input(first + i);
                fault(i, &mut slot);
                slot.acc_code
            });
            let expected = saturation_episodes(codes, servo.saturation_limit_ticks);
            assert_eq!(expected, 4);
            assert_eq!(c1.input_saturated - c0.input_saturated, expected, "{what}: {c1:?}");
            assert_reported(&during, "accelerometer is saturated");
            assert_reported(&during, "episodes of accelerometer saturation");
        } else {
            assert_eq!(c1.input_stuck - c0.input_stuck, 1, "{what}: {c1:?}");
            assert_reported(&during, "stuck or dead");
            assert_reported(&during, "episodes of a stuck or dead accelerometer");
        }
        assert!(c1.degraded_entries > c0.degraded_entries, "{what}: {c1:?}");
        assert!(faulty.last().unwrap().fault_count > warm.last().unwrap().fault_count);

        // Healthy again: still degraded until a model result from a window without bad
        // samples is in force, then the gain ramps back in.
        let last_bad = {
            let mut slot = input(first + ticks - 1);
            fault(ticks - 1, &mut slot);
            slot.acc_code
        };
        let recovery = stream.run(&mut hil, 3200, |_, _| {});
        // A healthy code that happens to equal the stuck one prolongs the fault.
        let still_bad = (stream.next - 3200..).take_while(|&k| input(k).acc_code == last_bad).count();
        let resumed = recovery.iter().position(|o| !degraded(o)).unwrap_or(recovery.len());
        assert_eq!(
            resumed,
            still_bad + recovery_ticks() as usize - 1,
            "{what}: trusted again after {resumed} healthy ticks"
        );
        assert!(recovery[resumed..].iter().all(|o| !degraded(o)), "{what}: degraded again after resuming");
        // From then on the prediction is the fault-free one, bit for bit: nothing of the
        // faulty samples is left in it.
        for (k, (got, clean)) in recovery.iter().zip(&stream.clean).enumerate().skip(resumed) {
            assert_eq!(
                got.de_pred_pm,
                clean.de_pred_pm,
                "{what}: {} ticks after resuming the prediction still differs from the fault-free one",
                k - resumed
            );
        }
        assert_compensating(&recovery[recovery.len() - 400..], what);
        let after = status(&mut hil);
        assert_eq!(after.degraded, 0, "{what}");
        assert!(after.gain > 0.99, "{what}: gain {}", after.gain);
    }
    // (Bus underruns are not asserted: on a loaded machine the host may stall for real.)
    assert_eq!(status(&mut hil).counters.model_faults, 0);
    finish(hil);
}

/// No model, malformed models, a model that evaluates to infinity, and K_dv = 0 or NaN.
#[test]
fn model_and_parameter_faults_are_rejected_or_ramped_out_and_counted() {
    let _serial = sts_hil_tests::serial();
    let mut hil = boot();
    configure(&mut hil, None);
    let mut stream = Stream::new();

    // No model: enabled, but nothing to compensate with; the DAC stays at the offset.
    let bare = stream.run(&mut hil, 4000, |_, _| {});
    assert!(bare.iter().all(|o| o.dac_code == 0 && o.flags & OUT_FLAG_MODEL_ACTIVE == 0));
    let s = status(&mut hil);
    assert_eq!((s.program_id, s.counters.model_updates), (None, 0));
    assert_reported(&s, "no twin model is active");

    // A model arrives: compensation starts (ramping, checked by `run`).
    expect_ack("upload", hil.request(Request::UploadProgram { program: program(71, 2.0), activate: true }).unwrap())
        .unwrap();
    let on = stream.run(&mut hil, 3000, |_, _| {});
    assert_compensating(&on[2200..], "with a model");

    // Malformed models are rejected and counted; the model in force keeps working.
    let mut bad_version = program(72, 1.0);
    bad_version.version = 99;
    let mut empty = program(73, 1.0);
    empty.code.clear();
    let mut bad_feature = program(74, 1.0);
    bad_feature.code[3] = 12; // feature index past f12
    let mut unknown_op = program(75, 1.0);
    unknown_op.code[0] = 0xEE;
    let mut truncated = program(76, 1.0);
    truncated.code.truncate(truncated.code.len() - 1);
    let malformed = [bad_version, empty, bad_feature, unknown_op, truncated];
    for bad in &malformed {
        match hil.request(Request::UploadProgram { program: bad.clone(), activate: true }).unwrap() {
            Response::Rejected(Rejection::Program(_)) => {}
            other => panic!("malformed program {} was not rejected: {other:?}", bad.id),
        }
    }
    let kept = stream.run(&mut hil, 1600, |_, _| {});
    assert_compensating(&kept, "after the malformed uploads");
    let s = status(&mut hil);
    assert_eq!(s.program_id, Some(71), "the old model stays in force");
    assert_eq!(s.counters.rejected_programs, malformed.len() as u32);
    assert_reported(&s, &format!("{} uploaded models rejected", malformed.len()));

    // A model that validates but evaluates to infinity: every evaluation is a fault, the
    // prediction ramps out, flagged.
    expect_ack(
        "upload",
        hil.request(Request::UploadProgram { program: non_finite_program(77), activate: true }).unwrap(),
    )
    .unwrap();
    let bad_model = stream.run(&mut hil, 2400, |_, _| {});
    let flagged = bad_model.iter().position(degraded).expect("a failing model is flagged");
    assert!(flagged as u32 <= timing().interval_ticks + timing().latency_ticks, "flagged only after {flagged} ticks");
    assert_ramped_out(&bad_model[flagged + RAMP as usize + 20..], "failing model");
    let s = status(&mut hil);
    assert_ne!(s.degraded & DEGRADED_MODEL, 0);
    assert!(s.counters.model_faults >= 2, "{:?}", s.counters);
    assert_reported(&s, "model's last evaluation failed");
    assert_reported(&s, "failed model evaluations");
    // A good model again: compensation resumes.
    expect_ack("upload", hil.request(Request::UploadProgram { program: program(78, 2.0), activate: true }).unwrap())
        .unwrap();
    let good = stream.run(&mut hil, 3000, |_, _| {});
    assert_compensating(&good[2200..], "after the failing model was replaced");
    let s = status(&mut hil);
    assert_eq!((s.degraded, s.program_id), (0, Some(78)));

    // K_dv = 0, NaN and infinite: rejected, counted, the parameters in force unchanged, the
    // output uninterrupted.
    let before = status(&mut hil);
    for k_dv in [0.0, -0.0, f32::NAN, f32::INFINITY] {
        let bad = FeedforwardParams { k_dv_um_per_v: k_dv, ..params() };
        assert_eq!(
            hil.request(Request::SetParams(bad)).unwrap(),
            Response::Rejected(Rejection::Params(ParamError::KDv)),
            "K_dv = {k_dv}"
        );
        let running = stream.run(&mut hil, 400, |_, _| {});
        assert_compensating(&running, &format!("after K_dv = {k_dv}"));
    }
    let after = status(&mut hil);
    assert_eq!(after.params, before.params);
    assert_eq!(after.counters.rejected_params - before.counters.rejected_params, 4);
    assert_reported(&after, "4 parameter sets rejected (e.g. K_dv");

    // Removing the model: the prediction ramps to zero, no longer flagged as model-active.
    expect_ack("clear", hil.request(Request::ClearProgram).unwrap()).unwrap();
    let cleared = stream.run(&mut hil, 2000, |_, _| {});
    let tail = &cleared[1400..];
    assert!(
        tail.iter().all(|o| o.dac_code == 0 && o.flags & OUT_FLAG_MODEL_ACTIVE == 0),
        "{:?}",
        tail.iter().find(|o| o.dac_code != 0)
    );
    assert_reported(&status(&mut hil), "no twin model is active");
    finish(hil);
}

/// A host that stops feeding samples: every missed tick is counted, the DAC holds (no
/// step), compensation ramps out once samples return and resumes after a clean window.
#[test]
fn a_host_that_stops_feeding_samples_is_counted_ramped_out_and_resumed() {
    let _serial = sts_hil_tests::serial();
    let servo = ServoConfig::default();
    let mut hil = boot();
    configure(&mut hil, Some(program(81, 2.0)));
    let mut stream = Stream::new();
    let warm = stream.run(&mut hil, 6000, |_, _| {});
    assert_compensating(&warm[5200..], "after the warm-up");
    let fed = status(&mut hil).counters.bus_underruns;

    // The host stops: the bus is live but no sample comes. The firmware waits about a
    // second of polling for each sample before it counts an underrun.
    hil.hil().resume();
    let deadline = Instant::now() + Duration::from_secs(60);
    while hil.hil().counters().underruns < fed + servo.underrun_limit_ticks {
        assert!(Instant::now() < deadline, "no underruns counted: {:?}", hil.hil().counters());
        hil.hil().alive("a stalled host").unwrap();
        std::thread::sleep(Duration::from_millis(2));
    }
    hil.hil().pause();
    std::thread::sleep(Duration::from_millis(20));
    let missed = hil.hil().counters().underruns;
    let stalled = status(&mut hil);
    assert_eq!(stalled.counters.bus_underruns, missed, "every missed tick is counted once");
    assert!(missed >= fed + servo.underrun_limit_ticks);
    assert_ne!(stalled.degraded & DEGRADED_NO_INPUT, 0, "degraded bits {:#x}", stalled.degraded);
    assert_eq!(stalled.counters.ticks, 6000, "no tick consumed without its sample");
    assert_reported(&stalled, "samples stopped arriving");
    assert_reported(&stalled, &format!("{missed} bus underruns"));

    // Samples again: tick 6000 is served next, the DAC resumes from where it held without a
    // step (checked by `run`), ramps out, and comes back after a clean window.
    let back = stream.run(&mut hil, 3200, |_, _| {});
    let resume = recovery_ticks() as usize - 1;
    assert!(back[..resume].iter().all(degraded), "not degraded right after the stall");
    assert_ramped_out(&back[(RAMP + 20) as usize..resume], "after the stall");
    assert!(back[resume..].iter().all(|o| !degraded(o)), "not resumed after a clean window");
    assert_compensating(&back[back.len() - 400..], "after the stall");
    let s = status(&mut hil);
    assert_eq!(s.degraded, 0);
    assert!(s.counters.bus_underruns >= missed);
    assert!(s.counters.degraded_entries >= 1);
    finish(hil);
}

/// 1% of the control frames dropped and 0.1% corrupted, both ways, seeded: the host
/// retries until every request is answered, each takes effect, the firmware counts every
/// corrupted frame it received, and the servo loop runs on between requests.
#[test]
fn a_lossy_control_link_loses_no_request() {
    let _serial = sts_hil_tests::serial();
    const REQUESTS: u32 = 2000;
    const SEED: u64 = 3;
    // The seed puts at least one dropped and one corrupted frame in each direction within
    // the first REQUESTS frames (each direction carries at least that many).
    for (direction, seed) in [("in", SEED), ("out", SEED ^ 0x6F75_7462_6F75_6E64)] {
        let mut probe = FrameInjector::new(LinkFaults::TYPICAL, seed);
        for _ in 0..REQUESTS {
            probe.pass(&mut [1, 2, 3]);
        }
        assert!(
            probe.counts().dropped >= 1 && probe.counts().corrupted >= 1,
            "seed {SEED} ({direction}): {:?}",
            probe.counts()
        );
    }
    let mut lossy =
        LossyHilCoprocessor::new(boot(), LinkFaults::TYPICAL, LinkFaults::TYPICAL, SEED, RetryPolicy::default());
    configure(&mut lossy, Some(program(91, 2.0)));
    let mut stream = Stream::new();
    let mut expected_offset_v = 0.0f32;
    for i in 0..REQUESTS {
        match i % 4 {
            0 | 2 => assert_eq!(
                lossy.request(Request::Ping { nonce: i }).unwrap(),
                Response::Pong { nonce: i, protocol_version: PROTOCOL_VERSION }
            ),
            1 => {
                expected_offset_v = ((i / 4) % 5) as f32 * 0.001;
                let p = FeedforwardParams { offset_v: expected_offset_v, ..params() };
                expect_ack("params", lossy.request(Request::SetParams(p)).unwrap()).unwrap();
            }
            _ => {
                let s = status(&mut lossy);
                assert_eq!(s.params.offset_v, expected_offset_v, "request {i}: the last parameters are in force");
                assert_eq!(s.program_id, Some(91));
            }
        }
        if i % 40 == 39 {
            stream.run(lossy.inner(), 200, |_, _| {});
        }
    }
    let stats = lossy.stats();
    let (inbound, outbound) = (lossy.inbound(), lossy.outbound());
    // And the five of `configure`.
    assert_eq!(stats.requests, u64::from(REQUESTS) + 5);
    assert!(
        inbound.dropped >= 1 && inbound.corrupted >= 1 && outbound.dropped >= 1 && outbound.corrupted >= 1,
        "{inbound:?} {outbound:?}"
    );
    // Each lost or damaged request costs at least one retry.
    assert!(stats.attempts - stats.requests >= inbound.dropped + inbound.corrupted, "{stats:?} {inbound:?}");
    // Read past the lossy link: the firmware counted every damaged frame it got.
    let s = status(lossy.inner());
    assert_eq!(s.counters.frame_errors, inbound.corrupted as u32, "{stats:?} {inbound:?} {outbound:?}");
    assert_reported(&s, &format!("{} control frames dropped as corrupt", inbound.corrupted));
    eprintln!("lossy link: {stats:?}, in {inbound:?}, out {outbound:?}");
    finish_lossy(lossy);
}

fn finish_lossy(mut lossy: LossyHilCoprocessor) {
    lossy.hil().alive("the end of the lossy-link test").expect("QEMU is still running");
    let errors: Vec<String> = lossy.hil().logs().iter().filter(|l| l.level == "ERROR").map(|l| l.to_string()).collect();
    assert!(errors.is_empty(), "the firmware logged errors: {errors:#?}");
    lossy.shutdown().unwrap();
}

/// The same faults on the host core give the same outputs as the firmware: a cross-check
/// that the HIL results above are the core's behaviour, not the harness's.
#[test]
fn the_host_core_sees_the_accelerometer_faults_like_the_firmware() {
    let _serial = sts_hil_tests::serial();
    let inputs: Vec<InputSlot> = (0..9000u32)
        .map(|k| {
            let mut slot = input(k);
            if (6000..6100).contains(&k) {
                slot.acc_code = i16::MAX;
            }
            slot
        })
        .collect();
    let mut sim = SimCoprocessor::boot(&[]);
    configure(&mut sim, Some(program(99, 2.0)));
    let expected: Vec<OutputSlot> = inputs.iter().map(|i| sim.tick(i).unwrap()).collect();
    let mut hil = boot();
    configure(&mut hil, Some(program(99, 2.0)));
    let got = hil.hil().run_open_loop(&inputs).unwrap();
    assert_eq!(got, expected);
    assert!(expected[6100..].iter().any(degraded));
    finish(hil);
}
