//! Platform: a host that stops feeding the bus makes the firmware count underruns (and log
//! them) without hanging; a paused host counts none; feeding again resumes exactly at the
//! next tick.

use std::time::{Duration, Instant};

use sts_hil::board::bringup::{reference_outputs, DEFAULT_GAIN};
use sts_hil::{bench_inputs, Hil, HilConfig};
use sts_twin_core::bus::OutputSlot;

#[test]
fn a_stalled_host_is_counted_as_underruns_and_the_loop_resumes() {
    let _serial = sts_hil_tests::serial();
    let inputs = bench_inputs(300);
    let expected: Vec<OutputSlot> = reference_outputs(&inputs, DEFAULT_GAIN).collect();
    let mut hil = Hil::start(HilConfig { idle_paused: false, ..sts_hil_tests::bringup_config() }).expect("boot");
    for (k, input) in inputs[..100].iter().enumerate() {
        assert_eq!(hil.step(*input).unwrap(), expected[k]);
    }
    assert_eq!(hil.counters().underruns, 0);

    // Stop feeding: every bounded wait of the servo tick ends in an underrun.
    let deadline = Instant::now() + Duration::from_secs(60);
    while hil.counters().underruns < 3 {
        assert!(Instant::now() < deadline, "no underruns counted: {:?}", hil.counters());
        hil.alive("stalled host").unwrap();
        std::thread::sleep(Duration::from_millis(5));
    }
    hil.wait_for_log(Duration::from_secs(10), |l| l.level == "WARN" && l.message.contains("underrun"))
        .expect("the background logs underruns");
    // The firmware is not hung: the control link answers while the bus is stalled.
    let echo = hil.transact(b"x", Duration::from_secs(10), |r| !r.is_empty()).unwrap();
    assert_eq!(echo, b"x");

    // Paused: the tick stops waiting, no more underruns.
    hil.pause();
    std::thread::sleep(Duration::from_millis(200));
    let paused_at = hil.counters().underruns;
    std::thread::sleep(Duration::from_millis(500));
    assert_eq!(hil.counters().underruns, paused_at, "underruns counted while paused");
    assert_eq!(hil.counters().fw_seq, 100, "nothing served while paused");
    hil.resume();

    // Feeding again: tick 100 processes input 100, bit-identical to the reference.
    let rest = hil.run_open_loop(&inputs[100..]).unwrap();
    assert_eq!(rest, expected[100..]);
    assert_eq!(hil.counters().fw_seq, 300);
}
