//! The controller's analogue input: interface offset, ADC, K_vc, motion pulses, enable.

use sts_emulator::{Machine, PlantParams, StepInput};

/// Holds the axis at command zero with a constant analogue input for 0.5 s; returns the last
/// output and the mean encoder position over the last 0.1 s.
fn hold(voltage: f64, enabled: bool) -> (sts_emulator::StepOutput, f64) {
    let mut machine = Machine::new(&PlantParams::default(), &[], 3).unwrap();
    let input = StepInput { analog_in_v: voltage, analog_enabled: enabled, ..StepInput::default() };
    let mut last = machine.step(&input);
    let mut sum = 0.0;
    for k in 1..4000 {
        last = machine.step(&input);
        if k >= 3200 {
            sum += last.z_enc_um;
        }
    }
    (last, sum / 800.0)
}

#[test]
fn offset_is_read_and_moves_the_axis_only_when_enabled() {
    let p = PlantParams::default();
    // At 0 V the controller reads the interface's offset: 12 mV = 24 pulses of 1 nm.
    let (out, pos) = hold(0.0, false);
    assert!((out.ain_read_v - p.interface.offset_v).abs() < 2.0 * 20.0 / 65536.0);
    assert_eq!(out.ain_pulses, 24);
    assert!(pos.abs() < 0.002, "disabled: axis stays, {pos} um");
    let (_, pos) = hold(0.0, true);
    assert!((pos - 0.024).abs() < 0.002, "enabled: moves by the offset's pulses, {pos} um");
    // A calibrated offset cancels it: less than one pulse.
    let (out, pos) = hold(-p.interface.offset_v, true);
    assert!(out.ain_pulses.abs() <= 1 && pos.abs() < 0.002, "{} pulses, {pos} um", out.ain_pulses);
}

#[test]
fn volts_become_motion_pulses_with_k_vc() {
    let p = PlantParams::default();
    let (out, pos) = hold(0.5 - p.interface.offset_v, true);
    assert!((out.ain_pulses - 1000).abs() <= 1, "{} pulses", out.ain_pulses);
    assert!((pos - 1.0).abs() < 0.003, "0.5 V x 2000 pulses/V x 1 nm = 1 um, got {pos}");
    assert!((out.z_servo_cmd_um - out.ain_pulses as f64 * 1e-3).abs() < 1e-12);
    // Beyond the ADC's range the reading clips.
    let (out, _) = hold(25.0, false);
    assert!(out.ain_read_v < 10.0 && out.ain_read_v > 9.99);
}
