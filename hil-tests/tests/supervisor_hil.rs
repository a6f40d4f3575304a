//! The supervisor with the firmware in the loop: a twin used where it must not be (far above
//! the frequencies it was fitted on, on another machine, with a correction of the wrong sign
//! or three times too large, or one the DAC cannot carry) never makes the cut more than 10%
//! worse than the bare machine's, never steps the output beyond the slew limit, raises the
//! flag and counts the trip; and compensation comes back once conditions are sound. Each case
//! runs in QEMU and on the host, the same cut number for number: the faulty cut on a freshly
//! booted co-processor with the analogue path measured on the host, the sound one after a
//! recalibration through the co-processor itself.

use std::path::Path;

use sts_emulator::PlantParams;
use sts_model::ModelFile;
use sts_rig::machine_params;
use sts_rig::trial::{run_trial, TrialConfig, TrialReport};
use sts_rig::{Coprocessor, HilCoprocessor, SimCoprocessor};
use sts_twin_core::feedforward::FeedforwardParams;

fn model() -> ModelFile {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join("twin-default-machine.json");
    ModelFile::read(&path).expect("the fixture model")
}

/// A fault case: the machine, the cut's frequency and what is wrong with the parameters.
struct Case {
    plant: PlantParams,
    freq_hz: f64,
    /// The parameters the co-processor is given, from the calibrated ones.
    params: fn(FeedforwardParams) -> FeedforwardParams,
}

/// The bare cut of `case`'s machine (seed 1).
fn bare(case: &Case) -> TrialReport {
    let params = sts_rig::trial::calibrated(&mut SimCoprocessor::boot(&[]), &case.plant, &[], 1, false).unwrap().0;
    let config = TrialConfig { freq_hz: case.freq_hz, seed: 1, ..TrialConfig::default() };
    run_trial(&mut SimCoprocessor::boot(&[]), &case.plant, &[], None, params, &config).unwrap()
}

/// The parameters calibrated for `plant` on the host's core: offset, `K_dv` and the analogue
/// path measured through it (seed 1). The firmware in QEMU measures the same, number for
/// number (`trial_hil`'s 40 Hz cuts), so each case calibrates once, on the host, and every cut
/// starts on a freshly booted co-processor given these parameters.
fn calibrated(plant: &PlantParams) -> FeedforwardParams {
    sts_rig::trial::calibrated(&mut SimCoprocessor::boot(&[]), plant, &[], 1, true).unwrap().0
}

/// The cut of `case` with the twin and the supervisor switched off, on the host: what the
/// fault does to the cut without it.
fn unsupervised(case: &Case, calibrated: FeedforwardParams) -> TrialReport {
    let mut sim = SimCoprocessor::boot(&[]);
    sts_rig::supervisor_off(&mut sim).unwrap();
    let config = TrialConfig { freq_hz: case.freq_hz, seed: 1, ..TrialConfig::default() };
    run_trial(&mut sim, &case.plant, &[], Some(&model()), (case.params)(calibrated), &config).unwrap()
}

/// The cut of `case` with the twin, given the parameters `calibrated` for its machine.
fn faulty(coprocessor: &mut dyn Coprocessor, case: &Case, calibrated: FeedforwardParams) -> TrialReport {
    let config = TrialConfig { freq_hz: case.freq_hz, seed: 1, ..TrialConfig::default() };
    run_trial(coprocessor, &case.plant, &[], Some(&model()), (case.params)(calibrated), &config).unwrap()
}

/// After `faulty`, on the same co-processor: the default machine recalibrated (offset, `K_dv`
/// and the analogue path measured through the co-processor, which switches the supervisor off meanwhile and
/// so forgets the other machine's bare error), then its 40 Hz cut with sound parameters.
fn sound(coprocessor: &mut dyn Coprocessor) -> TrialReport {
    let plant = PlantParams::default();
    let (calibrated, _) = sts_rig::trial::calibrated(coprocessor, &plant, &[], 1, true).unwrap();
    let config = TrialConfig { freq_hz: 40.0, seed: 1, ..TrialConfig::default() };
    run_trial(coprocessor, &plant, &[], Some(&model()), calibrated, &config).unwrap()
}

fn same_cut(a: &TrialReport, b: &TrialReport) -> bool {
    a.form_error_pv_um == b.form_error_pv_um
        && a.phase_error_deg == b.phase_error_deg
        && a.max_dac_step_codes == b.max_dac_step_codes
        && a.supervisor_trips == b.supervisor_trips
        && a.cut_ticks_held_off == b.cut_ticks_held_off
}

/// Runs `case` in QEMU and on the host and checks everything the supervisor promises; the
/// fault, unsupervised, makes the cut worse than the bare machine's. The sound cut after it
/// runs on the host, and with `sound_in_qemu` in QEMU too (the same, number for number; once
/// is enough to keep CI's time).
fn check(name: &str, case: Case, sound_in_qemu: bool) {
    let _serial = sts_hil_tests::serial();
    let bare = bare(&case);
    let calibrated = self::calibrated(&case.plant);
    let unsupervised = unsupervised(&case, calibrated);
    assert!(
        unsupervised.form_error_pv_um > 1.5 * bare.form_error_pv_um,
        "{name}: unsupervised {:.3} um PV, bare {:.3}: not a harmful fault",
        unsupervised.form_error_pv_um,
        bare.form_error_pv_um
    );
    let mut sim = SimCoprocessor::boot(&[]);
    let sim_faulty = self::faulty(&mut sim, &case, calibrated);
    // The figures of docs/supervisor.md (`--nocapture`).
    eprintln!(
        "{name}: bare {:.3} um PV, unsupervised {:.3}, supervised {:.3} ({})",
        bare.form_error_pv_um,
        unsupervised.form_error_pv_um,
        sim_faulty.form_error_pv_um,
        sim_faulty.compensation_summary()
    );
    let sound = self::sound(&mut sim);
    let mut hil = HilCoprocessor::start(sts_hil_tests::twin_config()).expect("the twin firmware boots");
    let faulty = self::faulty(&mut hil, &case, calibrated);
    let hil_sound = sound_in_qemu.then(|| self::sound(&mut hil));
    hil.shutdown().unwrap();
    assert!(same_cut(&faulty, &sim_faulty), "{name}: HIL {faulty:?} differs from sim {sim_faulty:?}");
    if let Some(hil_sound) = hil_sound {
        assert!(same_cut(&hil_sound, &sound), "{name}: HIL {hil_sound:?} differs from sim {sound:?}");
    }

    assert!(
        faulty.form_error_pv_um <= 1.1 * bare.form_error_pv_um,
        "{name}: {:.3} um PV with the twin, {:.3} bare",
        faulty.form_error_pv_um,
        bare.form_error_pv_um
    );
    let params = machine_params(&case.plant, case.plant.interface.offset_v);
    let slew_codes = (f64::from(params.slew_v_per_tick) / f64::from(params.dac_full_scale_v) * 32767.0).ceil() as i32;
    assert!(
        faulty.max_dac_step_codes <= slew_codes + 1,
        "{name}: a DAC step of {} codes (slew limit {slew_codes})",
        faulty.max_dac_step_codes
    );
    assert!(faulty.supervisor.tripped.is_some(), "{name}: {:?}", faulty.supervisor);
    assert_eq!(faulty.supervisor_trips, 1, "{name}: the trip is counted once");
    assert!(faulty.cut_ticks_held_off > 0, "{name}: the flag is raised in the cut");

    // Sound again: compensation is back, and the cut as good as ever.
    assert_eq!(sound.supervisor.tripped, None, "{name}: {:?}", sound.supervisor);
    assert!(sound.cut_ticks_compensating > sound.points as u64 * 9 / 10, "{name}: {}", sound.compensation_summary());
    let sound_bare = bare_default_40hz();
    assert!(
        sound.form_error_pv_um < 0.1 * sound_bare,
        "{name}: after the fault, {:.3} um PV against {sound_bare:.3} bare",
        sound.form_error_pv_um
    );
}

fn bare_default_40hz() -> f64 {
    bare(&Case { plant: PlantParams::default(), freq_hz: 40.0, params: |p| p }).form_error_pv_um
}

#[test]
fn a_twin_far_above_its_fitted_range_is_switched_off() {
    // Fitted up to 40 Hz; at 80 Hz its correction runs away through the machine.
    let case = Case { plant: PlantParams::default(), freq_hz: 80.0, params: |p| p };
    check("80 Hz", case, true);
}

#[test]
fn a_correction_of_the_wrong_sign_is_switched_off() {
    // K_dv negated: the analogue input wired the other way round.
    let case = Case {
        plant: PlantParams::default(),
        freq_hz: 40.0,
        params: |p| FeedforwardParams { k_dv_um_per_v: -p.k_dv_um_per_v, ..p },
    };
    check("wrong sign", case, false);
}

#[test]
fn a_twin_of_another_machine_is_switched_off() {
    // A well-tuned machine (full acceleration feedforward) with a stiff tool post: its error
    // is a tenth of the default machine's, for which the twin was fitted.
    let mut plant = PlantParams::default();
    plant.servo.aff_kg = 45.0;
    plant.servo.vff_n_s_per_m = 300.0;
    plant.structure.mode_tcp_gain = 0.3;
    let case = Case { plant, freq_hz: 40.0, params: |p| p };
    check("another machine", case, false);
}

/// K_dv three times too high: the correction is a third of what it should be, which still
/// helps; the supervisor leaves it on (no trip, no flag) and the cut is better than bare.
#[test]
fn a_correction_a_third_too_small_still_helps_and_is_left_on() {
    let _serial = sts_hil_tests::serial();
    let case = Case {
        plant: PlantParams::default(),
        freq_hz: 40.0,
        params: |p| FeedforwardParams { k_dv_um_per_v: p.k_dv_um_per_v * 3.0, ..p },
    };
    let bare = bare(&case);
    let calibrated = self::calibrated(&case.plant);
    let mut hil = HilCoprocessor::start(sts_hil_tests::twin_config()).expect("the twin firmware boots");
    let faulty = self::faulty(&mut hil, &case, calibrated);
    hil.shutdown().unwrap();
    eprintln!(
        "K_dv x 3: bare {:.3} um PV, unsupervised {:.3}, supervised {:.3}",
        bare.form_error_pv_um,
        unsupervised(&case, calibrated).form_error_pv_um,
        faulty.form_error_pv_um
    );
    assert_eq!(faulty.supervisor_trips, 0, "{:?}", faulty.supervisor);
    assert!(faulty.cut_ticks_compensating > faulty.points as u64 * 9 / 10, "{}", faulty.compensation_summary());
    assert!(
        faulty.form_error_pv_um < 0.8 * bare.form_error_pv_um,
        "{:.3} um PV with a third of the correction, {:.3} bare",
        faulty.form_error_pv_um,
        bare.form_error_pv_um
    );
}

#[test]
fn a_correction_the_dac_cannot_carry_is_switched_off() {
    // K_dv a hundredth of the machine's: the correction asks for far beyond full scale, and
    // shakes the structure before the DAC clamps for long.
    let case = Case {
        plant: PlantParams::default(),
        freq_hz: 40.0,
        params: |p| FeedforwardParams { k_dv_um_per_v: p.k_dv_um_per_v / 100.0, ..p },
    };
    check("saturating", case, false);
}
