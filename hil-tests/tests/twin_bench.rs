//! Instructions per servo tick of the twin firmware with a program, per-tick terms and model
//! updates in force (ignored by default; prints figures for BENCHMARKS.md):
//!
//! ```text
//! cargo test -p sts-hil-tests --release --test twin_bench -- --ignored --nocapture --test-threads=1
//! ```
//!
//! `bench_twin_tick_*` give the figures of the platform's instruction benchmark;
//! `breakdown_twin_tick_*` run the same stream and sort every tick by what it did (the
//! schedule of block ends, model requests and model results is known in advance), to show
//! which kind of tick is the worst.

use sts_twin::hil::{bench_inputs, bench_instructions_prepared, Hil, HilError, INSTRUCTION_BENCH_SHIFT};
use sts_twin::rig::request_on;
use sts_twin_core::features::{FeatureConfig, BLOCK_SAMPLES};
use sts_twin_core::feedforward::FeedforwardParams;
use sts_twin_core::program::{paper_program, TickTerm};
use sts_twin_core::servo::{ModelTiming, ServoConfig};
use sts_twin_core::wire::{Request, Response};

/// A short window so that model updates land inside the run.
const WINDOW_SAMPLES: u32 = 2000;
/// Ticks measured.
const TICKS: u32 = 20_000;

/// Uploads the paper's program plus `terms` per-tick harmonic terms and enables compensation.
fn prepare(hil: &mut Hil, terms: u8) -> Result<(), HilError> {
    let mut program = paper_program();
    for order in (2..).take(terms as usize) {
        let _ = program.terms.push(TickTerm::Harmonic { order, amp_reg: 0, phase_reg: 1 });
    }
    let requests = [
        Request::SetFeatureConfig(FeatureConfig { window_samples: WINDOW_SAMPLES, ..FeatureConfig::DEFAULT }),
        Request::SetParams(FeedforwardParams { enable_ramp_ticks: 100, ..FeedforwardParams::default() }),
        Request::UploadProgram { program, activate: true },
        Request::SetEnabled(true),
    ];
    for (seq, request) in requests.into_iter().enumerate() {
        match request_on(hil, seq as u16 + 1, request) {
            Ok(Response::Ack) => {}
            other => return Err(HilError::Protocol(format!("preparing the benchmark: {other:?}"))),
        }
    }
    Ok(())
}

fn bench(terms: u8) {
    let _serial = sts_hil_tests::serial();
    let report = bench_instructions_prepared(sts_hil_tests::twin_config(), TICKS, |hil| prepare(hil, terms)).expect("instruction benchmark");
    println!("paper program + {terms} per-tick terms: {report}");
    assert_eq!(report.underruns, 0);
}

#[test]
#[ignore = "benchmark: run with --ignored --nocapture"]
fn bench_twin_tick_instructions_paper_program() {
    bench(0);
}

#[test]
#[ignore = "benchmark: run with --ignored --nocapture"]
fn bench_twin_tick_instructions_with_two_terms() {
    bench(2);
}

#[test]
#[ignore = "benchmark: run with --ignored --nocapture"]
fn bench_twin_tick_instructions_with_eight_terms() {
    bench(8);
}

/// What a tick did besides the feature update, synthesis and feedforward.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Kind {
    /// Nothing else, all ramps settled.
    Settled,
    /// The synthesiser's ramps to a model result were moving.
    Ramping,
    /// Closed a 16-sample feature block.
    BlockEnd,
    /// Captured the features for a model request.
    Request,
    /// Applied a model result.
    Apply,
}

/// Each tick's kind, from the servo's schedule: the feature window restarts at tick 0, the
/// first request comes one interval and half a block in, each takes effect a latency later,
/// and requests start once the window is full.
fn schedule(ticks: u32) -> Vec<Kind> {
    let config = ServoConfig::default();
    let timing = ModelTiming::new(&config, WINDOW_SAMPLES);
    let mut kinds = vec![Kind::Settled; ticks as usize];
    let mut mark = |k: u32, kind: Kind| {
        if let Some(slot) = kinds.get_mut(k as usize) {
            *slot = (*slot).max(kind);
        }
    };
    let first = timing.interval_ticks + (BLOCK_SAMPLES / 2) as u32 - 1;
    let mut request = first;
    while request < ticks {
        if request + 1 >= WINDOW_SAMPLES {
            let apply = request + timing.latency_ticks;
            for k in apply + 1..apply + config.synth_ramp_ticks {
                mark(k, Kind::Ramping);
            }
            mark(request, Kind::Request);
            mark(apply, Kind::Apply);
        }
        request += timing.interval_ticks;
    }
    for k in (BLOCK_SAMPLES as u32 - 1..ticks).step_by(BLOCK_SAMPLES) {
        mark(k, Kind::BlockEnd);
    }
    kinds
}

fn breakdown(terms: u8) {
    let _serial = sts_hil_tests::serial();
    let mut config = sts_hil_tests::twin_config();
    config.icount_shift = INSTRUCTION_BENCH_SHIFT;
    let per_count = 40.0 / f64::from(1u32 << INSTRUCTION_BENCH_SHIFT);
    let mut hil = Hil::start(config).expect("boot");
    prepare(&mut hil, terms).expect("prepare");
    let mut busy = Vec::with_capacity(TICKS as usize);
    for input in bench_inputs(TICKS) {
        hil.step(input).expect("tick");
        busy.push(f64::from(hil.diagnostics().busy_last_counts) * per_count);
    }
    let underruns = hil.counters().underruns;
    hil.shutdown().expect("shutdown");
    assert_eq!(underruns, 0);
    let kinds = schedule(TICKS);
    println!("paper program + {terms} per-tick terms, input arrival -> output written, by kind of tick:");
    for kind in [Kind::Settled, Kind::Ramping, Kind::BlockEnd, Kind::Request, Kind::Apply] {
        let mut of_kind: Vec<f64> = busy.iter().zip(&kinds).filter(|(_, k)| **k == kind).map(|(b, _)| *b).collect();
        if of_kind.is_empty() {
            continue;
        }
        of_kind.sort_by(f64::total_cmp);
        let median = of_kind[of_kind.len() / 2];
        let worst = of_kind[of_kind.len() - 1];
        println!("  {kind:?}: {} ticks, median {median:.0}, worst {worst:.0}", of_kind.len());
    }
    let (worst_tick, worst) = busy.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)).expect("ticks");
    println!("  worst tick {worst_tick} ({:?}, tick mod 16 = {}): {worst:.0}", kinds[worst_tick], worst_tick % 16);
}

#[test]
#[ignore = "benchmark: run with --ignored --nocapture"]
fn breakdown_twin_tick_paper_program() {
    breakdown(0);
}

#[test]
#[ignore = "benchmark: run with --ignored --nocapture"]
fn breakdown_twin_tick_with_two_terms() {
    breakdown(2);
}

#[test]
#[ignore = "benchmark: run with --ignored --nocapture"]
fn breakdown_twin_tick_with_eight_terms() {
    breakdown(8);
}
