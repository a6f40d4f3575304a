//! The servo-axis twin of the core (`sts_twin_core::axis`) against the emulated machine's
//! physics: given the machine's own parameters, the twin, fed nothing but the command,
//! reproduces the deviation friction, presliding hysteresis and the encoder's interpolation
//! error cause at the TCP. The deviation is measured exactly: the same seed measured with
//! and without the effect (identical noise), the difference of the probe readings.
//! Identifying the parameters from data is a separate step; this pins the model.

use sts_emulator::{measure::MeasureConfig, EffectSpec, PlantParams};
use sts_twin_core::axis::{AxisModel, AxisParams, AxisState, Friction, Hysteresis, Ripple};

/// The axis twin's parameters of a plant, per kg of its moving mass, with `effect`.
fn axis_of(plant: &PlantParams, effect: &EffectSpec) -> AxisParams {
    let m = plant.slide.mass_kg;
    let s = &plant.servo;
    let per_kg = |x: f64| (x / m) as f32;
    let mut params = AxisParams {
        cmd_delay_ticks: s.command_delay_ticks as u8,
        kp_per_s2: per_kg(s.kp_n_per_um * 1e6),
        ki_per_s3: per_kg(s.ki_n_per_um_s * 1e6),
        kd_per_s: per_kg(s.kd_n_s_per_um * 1e6),
        vff_per_s: per_kg(s.vff_n_s_per_m),
        aff: per_kg(s.aff_kg),
        viscous_per_s: per_kg(plant.slide.viscous_n_s_per_m),
        current_tau_s: (plant.slide.current_loop_tau_us * 1e-6) as f32,
        mode_freq_hz: plant.structure.mode_freq_hz as f32,
        mode_damping: plant.structure.mode_damping as f32,
        mode_tcp_gain: plant.structure.mode_tcp_gain as f32,
        friction: None,
        hysteresis: None,
        ripple: None,
    };
    match effect.name() {
        "coulomb-friction" => {
            params.friction = Some(Friction {
                coulomb_mps2: per_kg(effect.get("coulomb_n")),
                static_mps2: per_kg(effect.get("static_n")),
                stribeck_mps: effect.get("stribeck_mps") as f32,
                smooth_mps: effect.get("smooth_mps") as f32,
            })
        }
        "presliding-hysteresis" => {
            params.hysteresis = Some(Hysteresis { force_mps2: per_kg(effect.get("force_n")), stiffness_per_s2: per_kg(effect.get("stiffness_n_per_um") * 1e6) })
        }
        "force-ripple" => {
            params.ripple = Some(Ripple {
                amp_nm: effect.get("amp_nm") as f32,
                harmonic2_nm: effect.get("harmonic2_nm") as f32,
                turns_per_nm: (4_294_967_296.0 / (effect.get("period_um") * 1000.0)).round() as u32,
                phase_turns: (effect.get("phase_deg") / 360.0 * 4_294_967_296.0).round() as i64 as u32,
            })
        }
        other => panic!("no axis term for {other}"),
    }
    params
}

/// (RMS of the effect's deviation, RMS of the twin's residual), nm, over each group's last second.
fn deviation_and_residual(spec: &str) -> (f64, f64) {
    let effect: EffectSpec = spec.parse().expect("effect");
    let config = MeasureConfig { freqs_hz: vec![5.0, 20.0, 40.0], amps_um: vec![2.0, 6.0, 10.0], duration_s: 3.0, seed: 7, ..MeasureConfig::default() };
    let clean = sts_emulator::measure::run(&config, &|_| {}).expect("clean measurement");
    let with = sts_emulator::measure::run(&MeasureConfig { effects: vec![effect.clone()], ..config.clone() }, &|_| {}).expect("measurement");
    let model = AxisModel::new(&axis_of(&config.plant, &effect)).expect("valid axis parameters");
    let fs = with.manifest.sample_rate_hz as usize;
    let (mut dev2, mut res2, mut n) = (0.0, 0.0, 0usize);
    for (g, c) in with.groups.iter().zip(&clean.groups) {
        let mut state = AxisState::INITIAL;
        let predicted_um: Vec<f64> = g.z_cmd_um.iter().map(|z| model.step(&mut state, (z * 1000.0).round() as i32) as f64 * 1e-6).collect();
        assert_eq!(state.resets, 0, "{spec}: the twin diverged");
        for k in g.len() - fs..g.len() {
            let deviation = g.z_tcp_um[k] - c.z_tcp_um[k];
            dev2 += deviation * deviation;
            res2 += (deviation - predicted_um[k]).powi(2);
            n += 1;
        }
    }
    ((dev2 / n as f64).sqrt() * 1e3, (res2 / n as f64).sqrt() * 1e3)
}

#[test]
fn the_axis_twin_reproduces_friction_hysteresis_and_encoder_error() {
    // (effect, largest residual as a fraction of the deviation). Friction's stiff sticking
    // law integrated at the tick rate is the least exact (the emulator takes 4 sub-steps).
    for (spec, worst_fraction) in [
        ("coulomb-friction:coulomb_n=3,static_n=4.5,stribeck_mps=2e-4", 0.04),
        ("presliding-hysteresis:force_n=2.5,stiffness_n_per_um=3", 0.02),
        ("force-ripple:amp_nm=50,period_um=5.3,harmonic2_nm=8,phase_deg=40", 0.01),
    ] {
        let (deviation_nm, residual_nm) = deviation_and_residual(spec);
        println!("{spec}: deviation {deviation_nm:.1} nm RMS, twin residual {residual_nm:.2} nm ({:.2}%)", 100.0 * residual_nm / deviation_nm);
        assert!(deviation_nm > 30.0, "{spec}: the effect must matter ({deviation_nm:.1} nm)");
        assert!(residual_nm < worst_fraction * deviation_nm, "{spec}: residual {residual_nm:.2} nm of {deviation_nm:.1} nm");
    }
}
