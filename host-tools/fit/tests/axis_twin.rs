//! The servo-axis twin of the core (`sts_twin_core::axis`) against the emulated machine's
//! physics: given the machine's own parameters, the twin, fed nothing but the command,
//! reproduces the machine's dynamic error, and the part friction, presliding hysteresis and
//! the encoder's interpolation error add to it. That part is measured exactly: the same seed
//! measured with and without the effect (identical noise), the difference of the probe
//! readings. Identifying the parameters from data is a separate step; this pins the model.

use sts_emulator::{measure::MeasureConfig, EffectSpec, PlantParams};
use sts_twin_core::axis::{AxisModel, AxisParams, AxisState, Friction, Hysteresis, Ripple, StructuralMode};

/// The axis twin's parameters of a plant, per kg of its moving mass, with `effect`.
fn axis_of(plant: &PlantParams, effect: Option<&EffectSpec>) -> AxisParams {
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
        second_mode: None,
    };
    let Some(effect) = effect else { return params };
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
            params.hysteresis = Some(Hysteresis {
                force_mps2: per_kg(effect.get("force_n")),
                stiffness_per_s2: per_kg(effect.get("stiffness_n_per_um") * 1e6),
            })
        }
        "force-ripple" => {
            params.ripple = Some(Ripple {
                amp_nm: effect.get("amp_nm") as f32,
                harmonic2_nm: effect.get("harmonic2_nm") as f32,
                turns_per_nm: (4_294_967_296.0 / (effect.get("period_um") * 1000.0)).round() as u32,
                phase_turns: (effect.get("phase_deg") / 360.0 * 4_294_967_296.0).round() as i64 as u32,
            })
        }
        "structural-mode" => {
            params.second_mode = Some(StructuralMode {
                freq_hz: effect.get("freq_hz") as f32,
                damping: effect.get("damping") as f32,
                tcp_gain: effect.get("tcp_gain") as f32,
            })
        }
        other => panic!("no axis term for {other}"),
    }
    params
}

/// The twin's output over a group's command, um.
fn twin_um(model: &AxisModel, cmd_um: &[f64]) -> Vec<f64> {
    let mut state = AxisState::INITIAL;
    let out = cmd_um.iter().map(|z| f64::from(model.step(&mut state, (z * 1000.0).round() as i32)) * 1e-6).collect();
    assert_eq!(state.resets, 0, "the twin diverged");
    out
}

/// RMS over each group's last second of `f(group index, sample)`, nm.
fn rms_nm(groups: usize, len: usize, fs: usize, f: impl Fn(usize, usize) -> f64) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for g in 0..groups {
        for k in len - fs..len {
            sum += f(g, k).powi(2);
            n += 1;
        }
    }
    (sum / n as f64).sqrt() * 1e3
}

/// (the effect's part of the error, the twin's residual on it, the machine without the
/// effect: its dynamic error, the twin's residual on it), RMS nm over each group's last second.
fn effect_and_residuals(spec: &str) -> [f64; 4] {
    let effect: EffectSpec = spec.parse().expect("effect");
    let config = MeasureConfig {
        freqs_hz: vec![5.0, 20.0, 40.0],
        amps_um: vec![2.0, 6.0, 10.0],
        duration_s: 3.0,
        seed: 7,
        ..MeasureConfig::default()
    };
    let clean = sts_emulator::measure::run(&config, &|_| {}).expect("clean measurement");
    let with = sts_emulator::measure::run(&MeasureConfig { effects: vec![effect.clone()], ..config.clone() }, &|_| {})
        .expect("measurement");
    let linear = AxisModel::new(&axis_of(&config.plant, None)).expect("valid axis parameters");
    let nonlinear = AxisModel::new(&axis_of(&config.plant, Some(&effect))).expect("valid axis parameters");
    let fs = with.manifest.sample_rate_hz as usize;
    let len = with.groups[0].len();
    let twin_linear: Vec<Vec<f64>> = clean.groups.iter().map(|g| twin_um(&linear, &g.z_cmd_um)).collect();
    let twin_nonlinear: Vec<Vec<f64>> = with.groups.iter().map(|g| twin_um(&nonlinear, &g.z_cmd_um)).collect();
    let (w, c) = (&with.groups, &clean.groups);
    let part = |g: usize, k: usize| w[g].z_tcp_um[k] - c[g].z_tcp_um[k];
    [
        rms_nm(w.len(), len, fs, part),
        rms_nm(w.len(), len, fs, |g, k| part(g, k) - (twin_nonlinear[g][k] - twin_linear[g][k])),
        rms_nm(w.len(), len, fs, |g, k| c[g].z_tcp_um[k] - c[g].z_cmd_um[k]),
        rms_nm(w.len(), len, fs, |g, k| c[g].z_tcp_um[k] - c[g].z_cmd_um[k] - twin_linear[g][k]),
    ]
}

#[test]
fn the_axis_twin_reproduces_the_machine_and_its_friction_hysteresis_encoder_error_and_second_mode() {
    // (effect, largest residual as a fraction of the effect's part). Friction's stiff
    // sticking law at the tick rate (the emulator takes 4 sub-steps) and the twin's
    // tanh-like smoothed sign are the least exact.
    for (spec, worst_fraction) in [
        ("coulomb-friction:coulomb_n=3,static_n=4.5,stribeck_mps=2e-4", 0.05),
        ("presliding-hysteresis:force_n=2.5,stiffness_n_per_um=3", 0.02),
        ("force-ripple:amp_nm=50,period_um=5.3,harmonic2_nm=8,phase_deg=40", 0.01),
        // A second mode, driven like the first by the slide's acceleration.
        ("structural-mode:freq_hz=210,damping=0.03,tcp_gain=0.9", 0.01),
    ] {
        let [part_nm, residual_nm, clean_nm, clean_residual_nm] = effect_and_residuals(spec);
        println!(
            "{spec}: the effect's part {part_nm:.1} nm RMS, twin residual {residual_nm:.2} nm ({:.2}%)",
            100.0 * residual_nm / part_nm
        );
        println!("    without it: dynamic error {clean_nm:.1} nm RMS, twin residual {clean_residual_nm:.2} nm (probe noise 5 nm)");
        assert!(part_nm > 30.0, "{spec}: the effect must matter ({part_nm:.1} nm)");
        assert!(residual_nm < worst_fraction * part_nm, "{spec}: residual {residual_nm:.2} nm of {part_nm:.1} nm");
        // The linear machine: down to the probe's noise and the encoder's nanometre.
        assert!(clean_nm > 200.0 && clean_residual_nm < 6.0, "{clean_nm:.1} nm, residual {clean_residual_nm:.2} nm");
    }
}
