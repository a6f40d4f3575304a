//! The twin firmware on the STM32H7's core: the very image the Cortex-M4F tests run, booted on
//! QEMU `mps2-an500` (Cortex-M7), passes the core HIL tests there: DAC codes bit-identical to
//! the host core and the 40 Hz cut number for number, and its instructions per servo tick
//! are the Cortex-M4F's, counted by the firmware's own timer under `-icount`.

use sts_hil::board::qemu::QemuBoard;
use sts_hil::{bench_instructions, HilConfig};

fn on_the_m7() -> HilConfig {
    HilConfig { board: QemuBoard::An500, ..sts_hil_tests::twin_config() }
}

#[test]
fn dac_codes_on_the_cortex_m7_are_bit_identical_to_the_host_core() {
    let _serial = sts_hil_tests::serial();
    crate::twin_hil::dac_codes_are_the_host_cores_on(on_the_m7());
}

#[test]
fn the_40_hz_cut_on_the_cortex_m7_is_the_host_cores_and_removes_over_90_percent() {
    let _serial = sts_hil_tests::serial();
    crate::trial_hil::the_40_hz_cut_removes_over_90_percent_on(on_the_m7(), false);
}

/// The same image executes the same instructions on both cores: the per-tick counts on the
/// M7 equal the M4F's, and the worst tick stays within the servo budget (the 800-instruction
/// budget is the twin's share; the whole tick's is below a tenth of the 31,250
/// instructions of a 125 us period at `-icount shift=2`).
#[test]
fn the_servo_tick_on_the_cortex_m7_executes_the_instructions_it_does_on_the_m4f() {
    let _serial = sts_hil_tests::serial();
    let ticks = 4000;
    let m7 = bench_instructions(on_the_m7(), ticks).expect("instruction count on the M7");
    let m4 = bench_instructions(sts_hil_tests::twin_config(), ticks).expect("instruction count on the M4F");
    eprintln!("{m7}");
    assert_eq!(m7.board, QemuBoard::An500);
    assert_eq!(m7.underruns + m7.overruns, 0);
    for (what, a, b) in [
        ("median", m7.busy_median, m4.busy_median),
        ("worst", m7.busy_max, m4.busy_max),
        ("entry", m7.entry_max, m4.entry_max),
        ("paper program", m7.paper_eval, m4.paper_eval),
    ] {
        assert_eq!(a, b, "{what}: {a} instructions on the M7, {b} on the M4F");
    }
    assert!(m7.worst_per_tick() > 100.0 && m7.worst_per_tick() < 3125.0, "{m7}");
}
