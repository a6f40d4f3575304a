//! Platform: a firmware panic and a HardFault end QEMU with a failing status, with the
//! reason in the decoded defmt log.

use std::sync::Mutex;
use std::time::Duration;

use sts_hil::{bench_inputs, Hil, HilError};

static SERIAL: Mutex<()> = Mutex::new(());

fn crash(command: u8, expect_in_log: &str) {
    let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let mut hil = Hil::start(sts_hil_tests::bringup_config()).expect("boot");
    for input in bench_inputs(50) {
        hil.step(input).unwrap();
    }
    hil.pause();
    hil.link().send(&[command]).unwrap();
    let status = hil.wait_exit(Duration::from_secs(20)).expect("QEMU must end by itself");
    assert!(!status.success(), "QEMU ended with {status}");
    assert!(
        hil.logs().iter().any(|l| l.level == "ERROR" && l.message.contains(expect_in_log)),
        "log: {:#?}",
        hil.logs()
    );
    // The harness reports the exit instead of waiting for a tick that never comes.
    hil.resume();
    match hil.step(Default::default()) {
        Err(HilError::QemuExited { log_tail, .. }) => assert!(log_tail.contains(expect_in_log), "{log_tail}"),
        other => panic!("expected QemuExited, got {other:?}"),
    }
}

#[test]
fn a_panic_ends_qemu_with_a_failing_status() {
    let _serial = sts_hil_tests::serial();
    crash(b'P', "panic requested over the control link");
}

#[test]
fn a_hard_fault_ends_qemu_with_a_failing_status() {
    let _serial = sts_hil_tests::serial();
    crash(b'F', "HardFault");
}
