//! Platform: the firmware boots under QEMU, serves the bus tick by tick with the bring-up
//! application, bit-identical to its host reference and to itself across runs; the control
//! link and the config store work, also across a reboot.

use std::sync::Mutex;
use std::time::Duration;

use sts_hil::board::bringup::{reference_outputs, DEFAULT_GAIN};
use sts_hil::{bench_inputs, Hil};
use sts_twin_core::bus::{InputSlot, OutputSlot, OUT_FLAG_MODEL_ACTIVE};

/// One QEMU at a time: the machine has two cores and the guest spins while it waits.
static SERIAL: Mutex<()> = Mutex::new(());

const TIMEOUT: Duration = Duration::from_secs(10);

fn hil_shift() -> u32 {
    sts_hil_tests::bringup_config().icount_shift
}

fn status(hil: &mut Hil) -> (u32, u32, u32, u32, i16) {
    let reply = hil.transact(b"?", TIMEOUT, |r| r.len() >= 19).expect("status reply");
    assert_eq!(reply[0], b's', "status reply {reply:?}");
    let word = |i: usize| u32::from_le_bytes(reply[1 + 4 * i..5 + 4 * i].try_into().unwrap());
    (word(0), word(1), word(2), word(3), i16::from_le_bytes([reply[17], reply[18]]))
}

#[test]
fn boots_and_serves_ticks_bit_identical_to_the_reference_and_across_runs() {
    let _serial = sts_hil_tests::serial();
    let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    const TICKS: u32 = 3000;
    let inputs = bench_inputs(TICKS);
    let expected: Vec<OutputSlot> = reference_outputs(&inputs, DEFAULT_GAIN).collect();
    assert!(expected.iter().any(|o| o.flags & OUT_FLAG_MODEL_ACTIVE != 0), "the run must reach the model path");

    // Run 1: lockstep.
    let mut hil = Hil::start(sts_hil_tests::bringup_config()).expect("boot");
    hil.wait_for_log(TIMEOUT, |l| l.message.contains("sts-twin firmware")).expect("boot banner in the defmt log");
    let lockstep: Vec<OutputSlot> = inputs.iter().map(|i| hil.step(*i).expect("tick")).collect();
    let counters = hil.counters();
    let diag = hil.diagnostics();
    hil.shutdown().unwrap();
    assert_eq!(lockstep, expected);
    assert_eq!(counters.fw_seq, TICKS);
    assert_eq!((counters.underruns, counters.overruns), (0, 0));
    assert!(diag.booted);
    assert_eq!(diag.model_requests, TICKS / 64);
    assert!(diag.busy_max_counts > 0 && diag.busy_max_counts < diag.period_counts, "{diag:?}");
    // One evaluation of the paper program, timed at boot (at the default -icount shift=2 one
    // 25 MHz timer count is 10 instructions). The background's budget for it is 20,000
    // instructions; it takes about 1,320, and a quarter more fails here,
    // so that a slower evaluation is seen in CI rather than as a smaller margin in the field.
    let eval_instructions = diag.paper_eval_counts * 40 / (1 << hil_shift());
    assert!(eval_instructions > 100 && eval_instructions <= 1_650, "{eval_instructions} instructions: {diag:?}");

    // Run 2: a fresh QEMU, pipelined through the ring: the same bits.
    let mut hil = Hil::start(sts_hil_tests::bringup_config()).expect("boot");
    let streamed = hil.run_open_loop(&inputs).expect("stream");
    assert_eq!(hil.counters().underruns, 0);
    hil.shutdown().unwrap();
    assert_eq!(streamed, expected);
}

#[test]
fn control_link_echoes_sets_the_gain_and_reports_status() {
    let _serial = sts_hil_tests::serial();
    let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let mut hil = Hil::start(sts_hil_tests::bringup_config()).expect("boot");
    let echo = hil.transact(b"hello, firmware", TIMEOUT, |r| r.len() >= 15).unwrap();
    assert_eq!(echo, b"hello, firmware");
    let gain: i16 = -384;
    let [lo, hi] = gain.to_le_bytes();
    assert_eq!(hil.transact(&[b'G', lo, hi], TIMEOUT, |r| r.len() >= 3).unwrap(), [b'g', lo, hi]);
    let inputs: Vec<InputSlot> = bench_inputs(500);
    let outputs: Vec<OutputSlot> = inputs.iter().map(|i| hil.step(*i).unwrap()).collect();
    assert_eq!(outputs, reference_outputs(&inputs, gain).collect::<Vec<_>>());
    let (ticks, underruns, overruns, model_runs, reported_gain) = status(&mut hil);
    assert_eq!((ticks, underruns, overruns, reported_gain), (500, 0, 0, gain));
    assert_eq!(model_runs, 500 / 64);
    assert!(hil.diagnostics().control_rx_bytes >= 19);
}

#[test]
fn config_store_survives_a_reboot() {
    let _serial = sts_hil_tests::serial();
    let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let mut hil = Hil::start(sts_hil_tests::bringup_config()).expect("boot");
    assert_eq!(status(&mut hil).4, DEFAULT_GAIN, "a fresh bus file has an empty config store");
    let [lo, hi] = 300i16.to_le_bytes();
    hil.transact(&[b'G', lo, hi], TIMEOUT, |r| r.len() >= 3).unwrap();
    assert_eq!(hil.transact(b"W", TIMEOUT, |r| r.len() >= 2).unwrap(), [b'w', 1]);
    let mut hil = hil.reboot().expect("reboot");
    assert_eq!(hil.next_tick(), 0);
    assert_eq!(status(&mut hil).4, 300);
    let inputs = bench_inputs(200);
    let outputs: Vec<OutputSlot> = inputs.iter().map(|i| hil.step(*i).unwrap()).collect();
    assert_eq!(outputs, reference_outputs(&inputs, 300).collect::<Vec<_>>(), "the stored gain is in force from tick 0");
    // A factory reset of the store: back to the default after the next boot.
    hil.bus().erase_config();
    let mut hil = hil.reboot().expect("reboot");
    assert_eq!(status(&mut hil).4, DEFAULT_GAIN);
}
