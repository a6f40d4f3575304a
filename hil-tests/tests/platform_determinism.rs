//! Platform: under `-icount` the firmware's behaviour does not depend on how fast the host
//! feeds it. The outputs are identical, and so is *where* the background's model work
//! completes relative to the ticks (the firmware hashes the tick count and the timer
//! position at each completion), for a host that streams as fast as it can and a host that
//! steps in lockstep with irregular pauses.

use std::time::Duration;

use sts_hil::{bench_inputs, Diagnostics, Hil, HilConfig};
use sts_twin_core::bus::OutputSlot;

const TICKS: u32 = 3000;

fn finish(hil: Hil) -> Diagnostics {
    let diag = hil.diagnostics();
    assert_eq!(hil.counters().underruns, 0, "an underrun gives the background extra time by design");
    hil.shutdown().unwrap();
    diag
}

#[test]
fn background_timing_and_outputs_do_not_depend_on_the_host_pace() {
    let _serial = sts_hil_tests::serial();
    // No idle pause: a paused period gives the background extra time, which is the point here.
    let inputs = bench_inputs(TICKS);

    let mut fast = Hil::start(HilConfig { idle_paused: false, ..sts_hil_tests::bringup_config() }).expect("boot");
    let fast_out = fast.run_open_loop(&inputs).unwrap();
    let fast_diag = finish(fast);

    // Lockstep with pseudo-random host pauses of 0 to 0.5 ms between ticks.
    let mut slow = Hil::start(HilConfig { idle_paused: false, ..sts_hil_tests::bringup_config() }).expect("boot");
    let mut state: u32 = 0x9E37_79B9;
    let slow_out: Vec<OutputSlot> = inputs
        .iter()
        .map(|input| {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            if state.is_multiple_of(4) {
                std::thread::sleep(Duration::from_micros(u64::from(state % 500)));
            }
            slow.step(*input).unwrap()
        })
        .collect();
    let slow_diag = finish(slow);

    assert_eq!(fast_out, slow_out);
    assert!(fast_diag.model_runs > 0, "the run must exercise the background: {fast_diag:?}");
    assert_eq!(fast_diag.model_runs, slow_diag.model_runs);
    assert_eq!(
        fast_diag.model_timing_hash, slow_diag.model_timing_hash,
        "the model work completed at different points of the ticks"
    );
}

/// A host that is slow to take its outputs (the sink sleeps now and then, so the firmware
/// runs a whole ring ahead) still gets every output, in order: the stream never lets the
/// firmware overwrite an output slot the host has not read.
#[test]
fn a_host_slow_to_read_outputs_loses_none() {
    let _serial = sts_hil_tests::serial();
    let inputs = bench_inputs(20 * 256);
    let mut hil = Hil::start(sts_hil_tests::bringup_config()).expect("boot");
    let mut ticks = Vec::with_capacity(inputs.len());
    hil.stream_open_loop(inputs.iter().copied(), |o| {
        if o.tick % 97 == 0 {
            std::thread::sleep(Duration::from_millis(15));
        }
        ticks.push(o.tick);
    })
    .expect("stream");
    let expected: Vec<u32> = (0..inputs.len() as u32).collect();
    let first_wrong = ticks.iter().zip(&expected).position(|(got, want)| got != want);
    assert_eq!(first_wrong, None, "output {first_wrong:?} came from another tick");
    assert_eq!(ticks.len(), expected.len());
    hil.shutdown().unwrap();
}
