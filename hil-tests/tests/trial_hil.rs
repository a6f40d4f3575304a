//! The paper's headline result with the firmware in the loop: the 40 Hz bicuspid cut on the
//! default emulated machine, without and with the twin (a model fitted by `sts-twin demo`,
//! kept as a fixture so that this test does not depend on the fit's search), the analogue
//! path measured first: through the firmware in QEMU for the 40 Hz cuts (the same path as the
//! host core's, number for number), through the host core for the others. The firmware in
//! QEMU and the core on the host give the same cut, number for number.

use std::path::Path;

use sts_emulator::{EffectSpec, PlantParams};
use sts_hil::HilConfig;
use sts_model::ModelFile;
use sts_rig::calibrate::PathPoint;
use sts_rig::trial::{run_trial, TrialConfig, TrialReport};
use sts_rig::{Coprocessor, HilCoprocessor, SimCoprocessor};
use sts_twin_core::feedforward::FeedforwardParams;
use sts_twin_core::program::TickTerm;

fn fixture(name: &str) -> ModelFile {
    ModelFile::read(&Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join(name)).expect("the fixture model")
}

fn model() -> ModelFile {
    fixture("twin-default-machine.json")
}

fn same_cut(a: &TrialReport, b: &TrialReport) -> bool {
    a.form_error_pv_um == b.form_error_pv_um
        && a.phase_error_deg == b.phase_error_deg
        && a.form_error_rms_um == b.form_error_rms_um
        && a.points == b.points
}

/// The parameters calibrated on `coprocessor` for the machine with `effects` (seed 1): offset,
/// `K_dv` and the analogue path measured through it, with the path's points.
fn calibrated(coprocessor: &mut dyn Coprocessor, effects: &[EffectSpec]) -> (FeedforwardParams, Vec<PathPoint>) {
    sts_rig::trial::calibrated(coprocessor, &PlantParams::default(), effects, 1, true).unwrap()
}

/// The parameters of a bare cut of the machine with `effects`: offset and `K_dv` calibrated on
/// the host's core (seed 1).
fn calibrated_bare(plant: &PlantParams, effects: &[EffectSpec]) -> FeedforwardParams {
    sts_rig::trial::calibrated(&mut SimCoprocessor::boot(&[]), plant, effects, 1, false).unwrap().0
}

/// The 40 Hz cut on the machine with `effects` (seed 1), the analogue path measured through
/// the co-processor first.
fn cut(coprocessor: &mut dyn Coprocessor, effects: &[EffectSpec], model: &ModelFile) -> TrialReport {
    let (params, _) = calibrated(coprocessor, effects);
    cut_with(coprocessor, 40.0, effects, model, params)
}

/// The cut at `freq_hz` on the machine with `effects` (seed 1) with `params`.
fn cut_with(
    coprocessor: &mut dyn Coprocessor,
    freq_hz: f64,
    effects: &[EffectSpec],
    model: &ModelFile,
    params: FeedforwardParams,
) -> TrialReport {
    let config = TrialConfig { freq_hz, seed: 1, ..TrialConfig::default() };
    run_trial(coprocessor, &PlantParams::default(), effects, Some(model), params, &config).unwrap()
}

/// The cut at `freq_hz` with the firmware in QEMU and with the core on the host, number for
/// number (asserted), the analogue path measured through the host's core. With
/// `path_in_qemu` the firmware measures it too (asserted the same) and both cut right after
/// their measurement; without, both cut freshly booted with the host's calibration (what the
/// calibration leaves in the co-processor changes the cut's last digits). The Cortex-M4F's
/// 40 Hz cut measures in QEMU; on the other cores, which run the same firmware code and whose
/// DAC codes are asserted the host core's bit for bit, a measurement there would cost some
/// 10 s of CI each for figures already shown the same. Returns the cut.
fn cut_at_in_qemu_as_on_the_host(
    config: HilConfig,
    freq_hz: f64,
    effects: &[EffectSpec],
    model: &ModelFile,
    path_in_qemu: bool,
) -> TrialReport {
    let mut sim = SimCoprocessor::boot(&[]);
    let (params, sim_path) = calibrated(&mut sim, effects);
    let mut hil = HilCoprocessor::start(config).expect("the twin firmware boots");
    if path_in_qemu {
        let (_, hil_path) = calibrated(&mut hil, effects);
        assert_eq!(sim_path, hil_path, "the analogue path measured through QEMU differs from the host core's");
    } else {
        sim = SimCoprocessor::boot(&[]);
    }
    let with_sim = cut_with(&mut sim, freq_hz, effects, model, params);
    let with_hil = cut_with(&mut hil, freq_hz, effects, model, params);
    hil.shutdown().unwrap();
    assert!(same_cut(&with_sim, &with_hil), "{freq_hz} Hz: HIL {with_hil:?} differs from sim {with_sim:?}");
    with_hil
}

/// [`cut_at_in_qemu_as_on_the_host`] at 40 Hz on the twin firmware's board, the path
/// measured on the host.
fn cut_in_qemu_as_on_the_host(effects: &[EffectSpec], model: &ModelFile) -> TrialReport {
    cut_at_in_qemu_as_on_the_host(sts_hil_tests::twin_config(), 40.0, effects, model, false)
}

/// The bare machine's 40 Hz cut (seed 1).
fn bare_cut(effects: &[EffectSpec]) -> TrialReport {
    bare_cut_at(40.0, effects)
}

/// [`bare_cut`] at `freq_hz`.
fn bare_cut_at(freq_hz: f64, effects: &[EffectSpec]) -> TrialReport {
    let plant = PlantParams::default();
    let params = calibrated_bare(&plant, effects);
    let config = TrialConfig { freq_hz, seed: 1, ..TrialConfig::default() };
    run_trial(&mut SimCoprocessor::boot(&[]), &plant, effects, None, params, &config).unwrap()
}

#[test]
fn at_40_hz_the_twin_in_qemu_removes_over_90_percent_of_the_form_error() {
    let _serial = sts_hil_tests::serial();
    the_40_hz_cut_removes_over_90_percent_on(sts_hil_tests::twin_config(), true);
}

/// The body of [`at_40_hz_the_twin_in_qemu_removes_over_90_percent_of_the_form_error`] on
/// the board `config` boots, the analogue path measured through it with `path_in_qemu`
/// ([`cut_at_in_qemu_as_on_the_host`]).
pub(crate) fn the_40_hz_cut_removes_over_90_percent_on(config: HilConfig, path_in_qemu: bool) {
    let bare = bare_cut(&[]);
    let with_hil = cut_at_in_qemu_as_on_the_host(config, 40.0, &[], &model(), path_in_qemu);
    let reduction = 1.0 - with_hil.form_error_pv_um / bare.form_error_pv_um;
    assert!(
        reduction >= 0.90,
        "form error {:.3} -> {:.3} um: only {:.1}% less",
        bare.form_error_pv_um,
        with_hil.form_error_pv_um,
        100.0 * reduction
    );
    assert!(with_hil.phase_error_deg.abs() < 0.3, "phase error {:.3} deg", with_hil.phase_error_deg);
    assert!(bare.phase_error_deg > 5.0, "the bare machine lags {:.2} deg", bare.phase_error_deg);
    assert_eq!(with_hil.fault_count, 0);
}

/// The twin for the machine's whole range (`trial-table`'s own: measured 1-100 Hz, `fit
/// --effect servo-axis`, seed 1, kept as a fixture) at 40 and 80 Hz, the firmware in QEMU
/// as the core on the host, number for number: the range table at the two frequencies cut
/// in QEMU.
#[test]
fn the_range_twin_in_qemu_cuts_40_and_80_hz_as_the_host_core_does() {
    let _serial = sts_hil_tests::serial();
    let model = fixture("twin-range-default-machine.json");
    for (freq_hz, least_reduction) in [(40.0, 0.985), (80.0, 0.80)] {
        let with_hil = cut_at_in_qemu_as_on_the_host(sts_hil_tests::twin_config(), freq_hz, &[], &model, false);
        let bare = bare_cut_at(freq_hz, &[]);
        let reduction = 1.0 - with_hil.form_error_pv_um / bare.form_error_pv_um;
        eprintln!(
            "{freq_hz} Hz: {:.3} -> {:.3} um ({:.1}% less), phase {:+.2} -> {:+.2} deg",
            bare.form_error_pv_um,
            with_hil.form_error_pv_um,
            100.0 * reduction,
            bare.phase_error_deg,
            with_hil.phase_error_deg
        );
        assert!(reduction >= least_reduction, "{freq_hz} Hz: only {:.1}% less", 100.0 * reduction);
        if freq_hz == 40.0 {
            assert!(with_hil.phase_error_deg.abs() <= 0.05, "40 Hz: phase {:+.3} deg", with_hil.phase_error_deg);
        }
        assert_eq!(with_hil.fault_count, 0, "{freq_hz} Hz");
    }
}

/// The loop's last step for an effect of another axis: a spindle with axial error motion
/// (80 nm once per revolution) and a tool post that deflects with X acceleration. The twin
/// fitted with `--effect axis-coupling` (fixture; see its description) reads the spindle angle
/// and the X acceleration from the bus and removes the spindle's error that the twin without
/// the term leaves; in QEMU as on the host.
#[test]
fn the_axis_coupling_term_removes_the_spindle_error_in_the_cut() {
    let _serial = sts_hil_tests::serial();
    let effects = ["axis-coupling:x_um_per_mps2=1.2,spindle_um=0.08,spindle_phase_deg=30".parse().unwrap()];
    let without_term = cut(&mut SimCoprocessor::boot(&[]), &effects, &model());
    let with_hil = cut_in_qemu_as_on_the_host(&effects, &fixture("twin-axis-coupling.json"));
    assert!(
        with_hil.form_error_rms_um < 0.5 * without_term.form_error_rms_um
            && with_hil.form_error_pv_um < 0.7 * without_term.form_error_pv_um,
        "with the term {:.3} um PV / {:.3} um RMS, without {:.3} / {:.3}",
        with_hil.form_error_pv_um,
        with_hil.form_error_rms_um,
        without_term.form_error_pv_um,
        without_term.form_error_rms_um
    );
    assert_eq!(with_hil.fault_count, 0);
}

/// The loop's last step for an effect inside the servo loop: friction (3 N Coulomb, 4.5 N
/// static, Stribeck 200 um/s). The twin fitted with `--effect coulomb-friction` (fixture; see
/// its description) compensates through its servo-axis twin, which the co-processor runs at
/// low priority on the command plus its own correction and learns from; in QEMU as on the
/// host. (The prediction fed forward unchanged left the bare machine's error: 6.5 um PV.)
#[test]
fn the_axis_twin_compensates_friction_in_the_cut() {
    let _serial = sts_hil_tests::serial();
    let effects = ["coulomb-friction:coulomb_n=3,static_n=4.5,stribeck_mps=2e-4".parse().unwrap()];
    let bare = bare_cut(&effects);
    let with_hil = cut_in_qemu_as_on_the_host(&effects, &fixture("twin-friction-axis.json"));
    assert!(
        with_hil.form_error_pv_um < 0.15 * bare.form_error_pv_um,
        "form error {:.3} -> {:.3} um PV",
        bare.form_error_pv_um,
        with_hil.form_error_pv_um
    );
    assert!(with_hil.phase_error_deg.abs() < 1.0, "phase error {:.3} deg", with_hil.phase_error_deg);
    assert_eq!(with_hil.fault_count, 0);
}

/// The friction twin over the speeds a lab cuts at (the core on the host, which the cut above
/// shows equal to QEMU): never worse than the bare machine (5% or 10 nm), and from 5 Hz on the
/// form error falls by at least the reductions below.
#[test]
fn the_friction_twin_compensates_from_5_hz_and_is_never_worse() {
    let effects = ["coulomb-friction:coulomb_n=3,static_n=4.5,stribeck_mps=2e-4".parse().unwrap()];
    let model = fixture("twin-friction-axis.json");
    for (freq_hz, least_reduction_pct) in
        [(2.0, None), (5.0, Some(60.0)), (10.0, Some(75.0)), (20.0, Some(75.0)), (40.0, Some(95.0))]
    {
        let bare = bare_cut_at(freq_hz, &effects);
        let mut sim = SimCoprocessor::boot(&[]);
        let (params, _) = calibrated(&mut sim, &effects);
        let twin = cut_with(&mut SimCoprocessor::boot(&[]), freq_hz, &effects, &model, params);
        let reduction_pct = 100.0 * (1.0 - twin.form_error_pv_um / bare.form_error_pv_um);
        println!(
            "{freq_hz} Hz: {:.3} -> {:.3} um PV ({reduction_pct:.1}%)",
            bare.form_error_pv_um, twin.form_error_pv_um
        );
        let worse_limit_um = (1.05 * bare.form_error_pv_um).max(bare.form_error_pv_um + 0.010);
        assert!(twin.form_error_pv_um <= worse_limit_um, "{freq_hz} Hz: worse than bare: {twin:?}");
        if let Some(least) = least_reduction_pct {
            assert!(reduction_pct >= least, "{freq_hz} Hz: {reduction_pct:.1}% less, not {least}%");
        }
        assert_eq!(twin.fault_count, 0);
    }
}

/// At 10 Hz friction's error is a pulse after each reversal, far up the odd harmonics: the
/// same twin's correction carries them in its `AxisHarmonic` slots (to the 15th here), and the
/// supervisor leaves the correction on to the centre of the cut (it reads no feature; the
/// gate fades out only the formulas). In QEMU as on the host, number for number, over the
/// last 0.2 mm of the cut (10 s of it; the whole cut's figures on the host are in the test
/// above).
#[test]
fn the_axis_twin_compensates_friction_at_low_speed_through_its_higher_harmonics() {
    let _serial = sts_hil_tests::serial();
    let effects: [EffectSpec; 1] = ["coulomb-friction:coulomb_n=3,static_n=4.5,stribeck_mps=2e-4".parse().unwrap()];
    let model = fixture("twin-friction-axis.json");
    let higher =
        model.firmware_program().unwrap().terms.iter().filter(|t| matches!(t, TickTerm::AxisHarmonic { .. })).count();
    assert!(higher >= 4, "the fixture gives {higher} higher harmonics slots");
    let config = TrialConfig { freq_hz: 10.0, r_start_mm: 0.2, r_eval_mm: 0.2, seed: 1, ..TrialConfig::default() };
    let plant = PlantParams::default();
    let bare_params = calibrated_bare(&plant, &effects);
    let bare = run_trial(&mut SimCoprocessor::boot(&[]), &plant, &effects, None, bare_params, &config).unwrap();
    let (params, _) = calibrated(&mut SimCoprocessor::boot(&[]), &effects);
    let with_sim = run_trial(&mut SimCoprocessor::boot(&[]), &plant, &effects, Some(&model), params, &config).unwrap();
    let mut hil = HilCoprocessor::start(sts_hil_tests::twin_config()).expect("the twin firmware boots");
    let with_hil = run_trial(&mut hil, &plant, &effects, Some(&model), params, &config).unwrap();
    hil.shutdown().unwrap();
    assert!(same_cut(&with_sim, &with_hil), "HIL {with_hil:?} differs from sim {with_sim:?}");
    println!(
        "10 Hz, friction, the last 0.2 mm: {:.3} -> {:.3} um PV",
        bare.form_error_pv_um, with_hil.form_error_pv_um
    );
    assert!(
        with_hil.form_error_pv_um < 0.25 * bare.form_error_pv_um,
        "form error {:.3} -> {:.3} um PV",
        bare.form_error_pv_um,
        with_hil.form_error_pv_um
    );
    assert_eq!(with_hil.cut_ticks_held_off, 0, "held off {} ticks", with_hil.cut_ticks_held_off);
    assert_eq!(with_hil.fault_count, 0);
}
