//! The twin firmware on RISC-V: its own image (`firmware/riscv-virt-app`, RV32IMAC, no FPU)
//! on QEMU `virt` passes the core HIL tests there: DAC codes bit-identical to the host core,
//! the 40 Hz cut number for number as the host core (which the Cortex-M4F's equals,
//! `trial_hil`), outputs and background timing independent of the host's pace, the control
//! link on its 16550 UART, and a servo tick that fits 125 us on a typical RISC-V MCU.

use std::time::Duration;

use sts_hil::board::qemu::QemuBoard;
use sts_hil::{bench_inputs, bench_instructions, HilConfig};
use sts_rig::HilCoprocessor;
use sts_twin_core::bus::OutputSlot;

use sts_hil_tests::twin::{configure, program, status};

fn on_riscv() -> HilConfig {
    HilConfig { board: QemuBoard::RiscvVirt, ..sts_hil_tests::twin_config() }
}

#[test]
fn dac_codes_on_risc_v_are_bit_identical_to_the_host_core() {
    let _serial = sts_hil_tests::serial();
    crate::twin_hil::dac_codes_are_the_host_cores_on(on_riscv());
}

#[test]
fn the_40_hz_cut_on_risc_v_is_the_host_cores_and_removes_over_90_percent() {
    let _serial = sts_hil_tests::serial();
    crate::trial_hil::the_40_hz_cut_removes_over_90_percent_on(on_riscv(), false);
}

/// Same outputs, same model updates and the same place in the ticks where each completed
/// (the firmware's timing hash, from the RTC's nanoseconds) for a host that streams as fast
/// as it can and one that steps in lockstep with pauses of up to 0.5 ms.
#[test]
fn the_twin_on_risc_v_does_not_depend_on_the_host_pace() {
    let _serial = sts_hil_tests::serial();
    let inputs = bench_inputs(4000);
    // No idle pause: a paused period gives the background extra time, which is the point here.
    let run = |lockstep: bool| {
        let mut hil = HilCoprocessor::start(HilConfig { idle_paused: false, ..on_riscv() }).expect("boot");
        configure(&mut hil, Some(program(61, 1.0)));
        let mut state: u32 = 0x9E37_79B9;
        let outputs: Vec<OutputSlot> = if lockstep {
            inputs
                .iter()
                .map(|input| {
                    state ^= state << 13;
                    state ^= state >> 17;
                    state ^= state << 5;
                    if state.is_multiple_of(4) {
                        std::thread::sleep(Duration::from_micros(u64::from(state % 500)));
                    }
                    hil.hil().step(*input).unwrap()
                })
                .collect()
        } else {
            hil.hil().run_open_loop(&inputs).unwrap()
        };
        let diag = hil.hil().diagnostics();
        let counters = status(&mut hil).counters;
        hil.shutdown().unwrap();
        assert_eq!(counters.bus_underruns, 0, "an underrun gives the background extra time by design");
        (outputs, diag, counters.model_updates)
    };
    let (fast, fast_diag, fast_updates) = run(false);
    let (slow, slow_diag, slow_updates) = run(true);
    assert_eq!(fast, slow);
    assert!(fast_diag.model_runs > 0 && fast_updates > 0, "the run must exercise the background: {fast_diag:?}");
    assert_eq!((fast_diag.model_runs, fast_updates), (slow_diag.model_runs, slow_updates));
    assert_eq!(
        fast_diag.model_timing_hash, slow_diag.model_timing_hash,
        "the model work completed at different points of the ticks"
    );
}

#[test]
fn uploads_on_risc_v_change_the_prediction_and_malformed_programs_are_rejected() {
    let _serial = sts_hil_tests::serial();
    crate::twin_hil::uploads_change_the_prediction_on(on_riscv());
}

#[test]
fn parameter_changes_on_risc_v_never_step_the_dac() {
    let _serial = sts_hil_tests::serial();
    crate::twin_hil::parameter_changes_never_step_the_dac_on(on_riscv());
}

#[test]
fn bad_frames_on_risc_v_are_counted_and_ignored() {
    let _serial = sts_hil_tests::serial();
    crate::twin_hil::bad_frames_are_counted_and_ignored_on(on_riscv());
}

/// The servo tick's instructions, counted by the RTC under `-icount`: the worst tick fits a
/// tenth of the 31,250 instructions of a 125 us period at `-icount shift=2`, and so 125 us on
/// a GD32VF103 at 108 MHz (13,500 cycles) with room to spare. One evaluation of the paper's
/// model runs in software floating point (RV32IMAC has no FPU): several times the
/// Cortex-M4F's, in the background, not in the tick.
#[test]
fn the_servo_tick_on_risc_v_fits_125_us_on_a_108_mhz_mcu() {
    let _serial = sts_hil_tests::serial();
    let report = bench_instructions(on_riscv(), 4000).expect("instruction count on RISC-V");
    eprintln!("{report}");
    assert_eq!(report.board, QemuBoard::RiscvVirt);
    assert_eq!(report.underruns + report.overruns, 0);
    assert!(report.worst_per_tick() > 100.0 && report.worst_per_tick() < 3125.0, "{report}");
    assert!(report.paper_eval > 1000.0 && report.paper_eval < 13_500.0, "{report}");
}
