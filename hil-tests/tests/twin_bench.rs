//! Instructions per servo tick of the twin firmware with a program, per-tick terms and model
//! updates in force (ignored by default; prints figures for BENCHMARKS.md):
//!
//! ```text
//! cargo test -p sts-hil-tests --release --test twin_bench -- --ignored --nocapture
//! ```

use sts_twin::hil::{bench_instructions_prepared, HilError};
use sts_twin::rig::request_on;
use sts_twin_core::features::FeatureConfig;
use sts_twin_core::feedforward::FeedforwardParams;
use sts_twin_core::program::{paper_program, TickTerm};
use sts_twin_core::wire::{Request, Response};

fn bench(terms: u8) {
    let _serial = sts_hil_tests::serial();
    let report = bench_instructions_prepared(sts_hil_tests::twin_config(), 20_000, |hil| {
        // The paper's program plus `terms` per-tick harmonic terms, a short window so that
        // model updates land inside the run.
        let mut program = paper_program();
        for order in (2..).take(terms as usize) {
            let _ = program.terms.push(TickTerm::Harmonic { order, amp_reg: 0, phase_reg: 1 });
        }
        let requests = [
            Request::SetFeatureConfig(FeatureConfig { window_samples: 2000, ..FeatureConfig::DEFAULT }),
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
    })
    .expect("instruction benchmark");
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
