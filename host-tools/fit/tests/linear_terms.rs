//! `fit --effect` for the effects of the axis's linear response: an in-band structural mode
//! (a resonance term beside a velocity bank), a late setpoint (the bank) and a mode beside
//! friction (the servo-axis twin's second mode), identified on emulator measurements whose
//! parameters are known.

use sts_emulator::MeasureConfig;
use sts_fit::effects::prepare;
use sts_twin_core::program::TickTerm;

fn measure(effects: &[&str]) -> sts_dataset::Dataset {
    let config = MeasureConfig {
        effects: effects.iter().map(|e| e.parse().expect("effect")).collect(),
        duration_s: 3.0,
        seed: 5,
        ..MeasureConfig::default()
    };
    sts_emulator::measure::run(&config, &|_| {}).expect("measurement")
}

/// The parameter `key` of `effect`'s record.
pub(crate) fn param(records: &[sts_fit::effects::EffectRecord], effect: &str, key: &str) -> f64 {
    let record = records.iter().find(|r| r.effect == effect).expect("record");
    record.params.iter().find(|(k, _)| k == key).map(|(_, v)| *v).expect("parameter")
}

#[test]
fn an_in_band_mode_is_identified_and_carried_by_a_resonance() {
    let data = measure(&["structural-mode:freq_hz=22,damping=0.05,tcp_gain=0.008,acc_shape=1"]);
    let prepared = prepare(&data, &["structural-mode".to_string()]).expect("prepare");
    let kinds: Vec<bool> = prepared.terms.iter().map(|t| matches!(t, TickTerm::Resonance { .. })).collect();
    assert_eq!(kinds, [false, true], "a velocity bank, then the resonance: {:?}", prepared.terms);
    let freq_hz = param(&prepared.records, "structural-mode", "freq_hz");
    let damping = param(&prepared.records, "structural-mode", "damping");
    let gain = param(&prepared.records, "structural-mode", "tcp_gain").abs();
    println!("identified: {freq_hz:.2} Hz, damping {damping:.4}, modal gain {gain:.5} (true 22, 0.05, 0.008)");
    assert!((freq_hz / 22.0 - 1.0).abs() < 0.03, "frequency {freq_hz} Hz");
    assert!((damping / 0.05 - 1.0).abs() < 0.3, "damping {damping}");
    assert!((gain / 0.008 - 1.0).abs() < 0.15, "modal gain {gain}");
    // A mode above the band stays with the formulas.
    let above = measure(&["structural-mode:freq_hz=250,damping=0.03,tcp_gain=0.8,acc_shape=1"]);
    assert!(prepare(&above, &["structural-mode".to_string()]).expect("prepare").terms.is_empty());
}

#[test]
fn a_late_setpoint_shows_as_the_velocity_banks_lag() {
    let lag_us = |effects: &[&str]| {
        let prepared = prepare(&measure(effects), &["setpoint-delay".to_string()]).expect("prepare");
        assert!(matches!(prepared.terms.as_slice(), [TickTerm::Laguerre { .. }]), "{:?}", prepared.terms);
        param(&prepared.records, "setpoint-delay", "velocity_lag_us")
    };
    // The bank's lag is the whole response's; a setpoint 300 us late adds 300 us to it.
    let added = lag_us(&["setpoint-delay:delay_us=300"]) - lag_us(&[]);
    println!("lag added by a setpoint 300 us late: {added:.1} us");
    assert!((added - 300.0).abs() < 15.0, "lag added {added} us");
}

/// The evidence `diagnose` names an in-band mode from: found where `fit --effect
/// structural-mode` carries one, at its frequency, and held out it takes most of what the
/// velocity bank alone leaves in nearly every group; none on a clean machine or a late
/// setpoint, whose best resonance lies above the band (the axis's own mode).
#[test]
fn the_in_band_evidence_is_held_out_and_absent_without_a_mode() {
    use sts_fit::effects::in_band_mode_evidence;
    let data = measure(&["structural-mode:freq_hz=22,damping=0.05,tcp_gain=0.008,acc_shape=1"]);
    let e = in_band_mode_evidence(&data, 5).expect("evidence").expect("an in-band mode");
    assert!((e.freq_hz / 22.0 - 1.0).abs() < 0.03, "frequency {} Hz", e.freq_hz);
    let n = e.bank_only_ss_um2.len();
    assert_eq!(n, data.groups.len());
    assert!(e.bank_only_ss_um2.iter().chain(&e.with_mode_ss_um2).all(|x| x.is_finite() && *x >= 0.0));
    let better = e.bank_only_ss_um2.iter().zip(&e.with_mode_ss_um2).filter(|(a, b)| b < a).count();
    let (bank, mode): (f64, f64) = (e.bank_only_ss_um2.iter().sum(), e.with_mode_ss_um2.iter().sum());
    println!(
        "held out: {better} of {n} groups better, {:.1}% of the bank's leftover taken",
        100.0 * (1.0 - mode / bank)
    );
    assert!(better * 10 >= n * 8, "only {better} of {n} groups better");
    assert!(mode < 0.2 * bank, "with the mode {mode} of the bank's {bank} um^2");
    for effects in [&[][..], &["setpoint-delay:delay_us=300"][..]] {
        assert!(in_band_mode_evidence(&measure(effects), 5).expect("evidence").is_none(), "{effects:?}");
    }
}

/// The evidence `diagnose` names a late setpoint from in the lab's workflow: at the slowest
/// groups the error lags the motion as a delay's does, and the lag read there is the whole
/// response's (the controller's own 2-tick pipeline included), so a setpoint 300 us late adds
/// 300 us to it; the velocity bank's held-out leftover is known for every group, and small
/// beside the error it fits.
#[test]
fn the_linear_response_evidence_reads_the_whole_responses_lag() {
    use sts_fit::effects::linear_response_evidence;
    let clean = linear_response_evidence(&measure(&[]), 5).expect("evidence");
    let late_data = measure(&["setpoint-delay:delay_us=300"]);
    let late = linear_response_evidence(&late_data, 5).expect("evidence");
    println!(
        "slowest groups ({} Hz): clean {:.1} us at {:.1} deg, late {:.1} us at {:.1} deg",
        clean.slowest_freq_hz,
        clean.slowest_lag_us,
        clean.slowest_phase_deg,
        late.slowest_lag_us,
        late.slowest_phase_deg
    );
    assert_eq!(late.slowest_freq_hz, 1.0);
    for e in [&clean, &late] {
        assert!((e.slowest_phase_deg + 90.0).abs() < 15.0, "phase {} deg", e.slowest_phase_deg);
    }
    let added = late.slowest_lag_us - clean.slowest_lag_us;
    assert!((added - 300.0).abs() < 15.0, "lag added {added} us");
    assert!(clean.slowest_lag_us > 200.0, "the pipeline's 250 us: {} us", clean.slowest_lag_us);
    assert_eq!(late.bank_only_ss_um2.len(), late_data.groups.len());
    assert!(late.bank_only_ss_um2.iter().all(|x| x.is_finite() && *x >= 0.0));
    // What the bank leaves held out: under (32 nm)^2 per group on average, where the error's
    // own phasors reach 0.04-11 um.
    let left_um2: f64 = late.bank_only_ss_um2.iter().sum();
    assert!(left_um2 < 1e-3 * late_data.groups.len() as f64, "the bank leaves {left_um2} um^2");
}

/// Beside friction (or hysteresis, or a ripple) a mode is the servo-axis twin's second mode,
/// driven like its first by the slide's acceleration: identified with the axis, frequency and
/// modal gain close to the emulated machine's.
#[test]
fn a_mode_beside_friction_is_the_axis_twins_second_mode() {
    let data = measure(&[
        "coulomb-friction:coulomb_n=3,static_n=4.5,stribeck_mps=2e-4",
        "structural-mode:freq_hz=210,damping=0.03,tcp_gain=0.9,acc_shape=1",
    ]);
    let names = ["coulomb-friction".to_string(), "structural-mode".to_string()];
    let prepared = prepare(&data, &names).expect("prepare");
    let [TickTerm::Axis(axis), higher @ ..] = prepared.terms.as_slice() else {
        panic!("one axis twin: {:?}", prepared.terms)
    };
    // The rest are slots for its correction's higher harmonics.
    assert!(higher.iter().all(|t| matches!(t, TickTerm::AxisHarmonic { .. })), "{higher:?}");
    let mode = axis.second_mode.expect("a second mode");
    println!(
        "identified: {:.2} Hz, damping {:.4}, modal gain {:.4} (true 210, 0.03, 0.9); first mode {:.1} Hz",
        mode.freq_hz, mode.damping, mode.tcp_gain, axis.mode_freq_hz
    );
    assert!((mode.freq_hz / 210.0 - 1.0).abs() < 0.02, "frequency {} Hz", mode.freq_hz);
    assert!((mode.tcp_gain / 0.9 - 1.0).abs() < 0.1, "modal gain {}", mode.tcp_gain);
    assert!((mode.damping / 0.03 - 1.0).abs() < 0.5, "damping {}", mode.damping);
    assert!(axis.friction.is_some());
    assert_eq!(param(&prepared.records, "structural-mode", "freq_hz"), f64::from(mode.freq_hz));
}

/// A late setpoint or an in-band mode beside a drift and a coupling: their kernel terms (a
/// velocity bank, a resonance) and the others' would take the servo tick over its budget (the
/// bank, a drift and a coupling 839 of 800; the mode's bank and resonance with a coupling 865),
/// so the servo-axis twin carries the axis's linear response (the setpoint in its command
/// delay, the mode as its second mode, started from where the command's phasors put it), and
/// the program is one the firmware takes.
#[test]
fn the_linear_response_over_the_budget_rides_on_the_axis_twin() {
    let program_with = |terms: &[TickTerm]| {
        let mut program = sts_twin_core::program::paper_program();
        for term in terms {
            program.terms.push(*term).expect("room for the terms");
        }
        program
    };
    let coupling = "axis-coupling:x_um_per_mps2=1.2,spindle_um=0.05,spindle_phase_deg=40";
    let late = measure(&["setpoint-delay:delay_us=300", "thermal-drift", coupling]);
    let names = ["setpoint-delay".to_string(), "thermal-drift".to_string(), "axis-coupling".to_string()];
    let prepared = prepare(&late, &names).expect("prepare");
    assert!(
        matches!(prepared.terms.as_slice(), [TickTerm::Drift { .. }, TickTerm::AxisCoupling { .. }, TickTerm::Axis(_)]),
        "{:?}",
        prepared.terms
    );
    assert_eq!(program_with(&prepared.terms).validate(), Ok(()));
    let axis = prepared.records.iter().find(|r| r.effect == "servo-axis").expect("the axis twin's record");
    assert!(axis.note.contains("839"), "{}", axis.note);
    assert!((param(&prepared.records, "axis-coupling", "x_um_per_mps2") / 1.2 - 1.0).abs() < 0.05);

    let mode = measure(&["structural-mode:freq_hz=22,damping=0.05,tcp_gain=0.008,acc_shape=1", coupling]);
    let names = ["structural-mode".to_string(), "axis-coupling".to_string()];
    let prepared = prepare(&mode, &names).expect("prepare");
    let [TickTerm::AxisCoupling { .. }, TickTerm::Axis(axis)] = prepared.terms.as_slice() else {
        panic!("a coupling and an axis twin: {:?}", prepared.terms)
    };
    assert_eq!(program_with(&prepared.terms).validate(), Ok(()));
    let second = axis.second_mode.expect("the mode as the axis twin's second");
    println!("identified: {:.2} Hz, damping {:.4} (true 22, 0.05)", second.freq_hz, second.damping);
    assert!((second.freq_hz / 22.0 - 1.0).abs() < 0.03, "frequency {} Hz", second.freq_hz);
    assert!((second.damping / 0.05 - 1.0).abs() < 0.3, "damping {}", second.damping);
}
