//! Each physical effect leaves its expected signature in the measurement data.
//! Clean and effect runs share seed and noise stream, so their difference is the effect.

use sts_analysis::sine::fit_sine;
use sts_dataset::GroupData;
use sts_emulator::measure::simulate_group;
use sts_emulator::{EffectSpec, MeasureConfig};
use sts_model::Effect;

fn group(freq_hz: f64, amp_um: f64, effects: &[&str]) -> GroupData {
    let config = MeasureConfig {
        freqs_hz: vec![freq_hz],
        amps_um: vec![amp_um],
        effects: effects.iter().map(|e| e.parse().expect("effect")).collect(),
        ..MeasureConfig::default()
    };
    simulate_group(&config, 0).expect("group")
}

/// Indices of the last `secs` seconds (steady state).
fn tail(g: &GroupData, secs: f64) -> Vec<usize> {
    let from = g.len() - (secs * 8000.0) as usize;
    (from..g.len()).collect()
}

fn dynamic_error(g: &GroupData, idx: &[usize]) -> Vec<f64> {
    idx.iter().map(|&i| g.z_tcp_um[i] - g.z_cmd_um[i]).collect()
}

fn times(g: &GroupData, idx: &[usize]) -> Vec<f64> {
    idx.iter().map(|&i| g.t_s[i]).collect()
}

/// Amplitude of harmonic `k` of the dynamic error over the last 4 s, nm.
fn harmonic_nm(g: &GroupData, freq_hz: f64, k: f64) -> f64 {
    let idx = tail(g, 4.0);
    fit_sine(&times(g, &idx), &dynamic_error(g, &idx), freq_hz * k).unwrap().amp * 1e3
}

/// Least-squares slope of y on x (through the means) and R^2.
fn regress(x: &[f64], y: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx).powi(2)).sum();
    let syy: f64 = y.iter().map(|b| (b - my).powi(2)).sum();
    (sxy / sxx, sxy * sxy / (sxx * syy))
}

#[test]
fn coulomb_friction_adds_odd_harmonics_falling_with_amplitude() {
    let clean = group(5.0, 1.0, &[]);
    let small = group(5.0, 1.0, &["coulomb-friction"]);
    let large = group(5.0, 11.0, &["coulomb-friction"]);
    let h3_small = harmonic_nm(&small, 5.0, 3.0);
    let h3_large = harmonic_nm(&large, 5.0, 3.0);
    let h5_small = harmonic_nm(&small, 5.0, 5.0);
    let h2_small = harmonic_nm(&small, 5.0, 2.0);
    assert!(h3_small > 20.0 && h3_small > 50.0 * harmonic_nm(&clean, 5.0, 3.0), "h3 {h3_small} nm");
    assert!(h5_small > 5.0, "h5 {h5_small} nm");
    assert!(h2_small < 0.1 * h3_small, "even harmonic {h2_small} vs odd {h3_small}");
    // Relative to the motion, the odd harmonics fall with amplitude.
    assert!(h3_small / 1.0 > 4.0 * h3_large / 11.0, "h3/A: {h3_small} at 1 um, {h3_large} at 11 um");
}

#[test]
fn presliding_hysteresis_is_a_spring_at_small_amplitude_and_saturates_at_large() {
    let clean_small = group(5.0, 1.0, &[]);
    let small = group(5.0, 1.0, &["presliding-hysteresis"]);
    let clean_large = group(5.0, 11.0, &[]);
    let large = group(5.0, 11.0, &["presliding-hysteresis"]);
    let idx = tail(&small, 4.0);
    let t = times(&small, &idx);
    let diff_small: Vec<f64> =
        dynamic_error(&small, &idx).iter().zip(dynamic_error(&clean_small, &idx)).map(|(a, b)| a - b).collect();
    let diff_large: Vec<f64> =
        dynamic_error(&large, &idx).iter().zip(dynamic_error(&clean_large, &idx)).map(|(a, b)| a - b).collect();
    let h1_small = fit_sine(&t, &diff_small, 5.0).unwrap().amp * 1e3;
    let h3_small = fit_sine(&t, &diff_small, 15.0).unwrap().amp * 1e3;
    let h1_large = fit_sine(&t, &diff_large, 5.0).unwrap().amp * 1e3;
    let h3_large = fit_sine(&t, &diff_large, 15.0).unwrap().amp * 1e3;
    // Small motion stays mostly in presliding: a (hysteretic) spring, mainly the fundamental.
    assert!(h1_small > 20.0 && h3_small < 0.4 * h1_small, "small: h1 {h1_small}, h3 {h3_small} nm");
    // Large motion saturates the Dahl force: friction-like odd harmonics grow.
    assert!(h3_large > 2.5 * h3_small && h3_large > 0.2 * h1_large, "large: h1 {h1_large}, h3 {h3_large} nm");
}

#[test]
fn structural_mode_rings_at_its_frequency() {
    let spec = "structural-mode:freq_hz=180,damping=0.03,tcp_gain=0.8";
    let clean = group(40.0, 5.0, &[]);
    let with = group(40.0, 5.0, &[spec]);
    // The start of the group (a velocity step) rings the mode: look at the first 0.15 s.
    let idx: Vec<usize> = (0..1200).collect();
    let t = times(&clean, &idx);
    let ring =
        |g: &GroupData| fit_sine(&t, &idx.iter().map(|&i| g.acc_mps2[i]).collect::<Vec<_>>(), 180.0).unwrap().amp;
    assert!(ring(&with) > 4.0 * ring(&clean), "ringing {} vs {}", ring(&with), ring(&clean));
    // In steady state the mode amplifies the 40 Hz dynamic error.
    let (a, b) = (harmonic_nm(&with, 40.0, 1.0), harmonic_nm(&clean, 40.0, 1.0));
    assert!(a > b + 100.0, "40 Hz DE {a} vs {b} nm");
}

#[test]
fn loop_delay_shifts_phase_growing_with_frequency() {
    // Extra delay in the loop lowers its phase margin: the closed-loop resonance (~75 Hz)
    // sharpens, which shifts the phase of the response more and more towards it while the
    // amplitudes below 40 Hz hardly change.
    let figures = |f: f64, effects: &[&str]| {
        let g = group(f, 5.0, effects);
        sts_emulator::analysis::group_figures(&g, f, 4.0, 6.0).unwrap()
    };
    let (c10, d10) = (figures(10.0, &[]), figures(10.0, &["loop-delay"]));
    let (c40, d40) = (figures(40.0, &[]), figures(40.0, &["loop-delay"]));
    let shift10 = (d10.tcp_lag_deg - c10.tcp_lag_deg).abs();
    let shift40 = (d40.tcp_lag_deg - c40.tcp_lag_deg).abs();
    assert!(shift40 > 0.8, "phase shift at 40 Hz {shift40} deg");
    assert!(shift40 > 20.0 * shift10, "phase shift {shift10} deg at 10 Hz, {shift40} deg at 40 Hz");
    assert!((d40.tcp_amp_um / c40.tcp_amp_um - 1.0).abs() < 0.01, "amplitude {} vs {}", d40.tcp_amp_um, c40.tcp_amp_um);
}

#[test]
fn setpoint_delay_makes_the_whole_response_late() {
    // The command reaches the loop late, the loop unchanged: the response keeps its
    // amplitude and lags by 360 f tau degrees more at every frequency (half a tick of delay
    // interpolated between ticks, 312.5 us).
    let figures = |f: f64, effects: &[&str]| {
        let g = group(f, 5.0, effects);
        sts_emulator::analysis::group_figures(&g, f, 4.0, 6.0).unwrap()
    };
    for f in [5.0, 20.0, 40.0] {
        let (c, d) = (figures(f, &[]), figures(f, &["setpoint-delay:delay_us=312.5"]));
        let shift = d.tcp_lag_deg - c.tcp_lag_deg;
        let want = 360.0 * f * 312.5e-6;
        assert!((shift - want).abs() < 0.01 * want + 0.01, "{f} Hz: lag {shift} deg, want {want}");
        assert!(
            (d.tcp_amp_um / c.tcp_amp_um - 1.0).abs() < 2e-4,
            "{f} Hz: amplitude {} vs {}",
            d.tcp_amp_um,
            c.tcp_amp_um
        );
    }
}

#[test]
fn thermal_drift_makes_mean_error_trend_with_start_s() {
    let spec: EffectSpec = "thermal-drift:rise_k=1,tau_s=600,um_per_k=1".parse().unwrap();
    let config = MeasureConfig { effects: vec![spec], ..MeasureConfig::default() };
    let clean = MeasureConfig::default();
    let groups = config.groups();
    let mut means = Vec::new();
    for index in [0usize, 33, 66, 98] {
        let g = simulate_group(&config, index).unwrap();
        let c = simulate_group(&clean, index).unwrap();
        let mean = |g: &GroupData| g.dynamic_error_um().iter().sum::<f64>() / g.len() as f64;
        let start = groups[index].start_s;
        let expected = 1.0 - (-(start + 3.0) / 600.0).exp();
        assert!((mean(&g) - mean(&c) - expected).abs() < 0.05 * expected.max(0.02) + 0.01, "group {index}");
        assert!(mean(&c).abs() < 0.05, "clean mean error {}", mean(&c));
        let temp = g.temp_c.as_ref().unwrap();
        let temp_mean = temp.iter().sum::<f64>() / temp.len() as f64;
        means.push((start, mean(&g), temp_mean));
    }
    for w in means.windows(2) {
        assert!(w[1].1 > w[0].1 + 0.05, "mean error must rise with start_s: {means:?}");
        assert!(w[1].2 > w[0].2 + 0.05, "temperature must rise with start_s: {means:?}");
    }
}

#[test]
fn force_ripple_error_is_periodic_in_position() {
    let spec = "force-ripple:amp_nm=30,period_um=4";
    let clean = group(1.0, 11.0, &[]);
    let with = group(1.0, 11.0, &[spec]);
    let idx = tail(&with, 4.0);
    let diff: Vec<f64> = idx.iter().map(|&i| with.z_tcp_um[i] - clean.z_tcp_um[i]).collect();
    let phase: Vec<f64> = idx.iter().map(|&i| 2.0 * std::f64::consts::PI * with.z_cmd_um[i] / 4.0).collect();
    // Regress on sin(phase): the TCP moves by minus the interpolation error.
    let sin: Vec<f64> = phase.iter().map(|p| p.sin()).collect();
    let (slope, r2) = regress(&sin, &diff);
    assert!((slope * 1e3 + 30.0).abs() < 6.0, "ripple amplitude {} nm", -slope * 1e3);
    assert!(r2 > 0.8, "position-periodic fit r2 {r2}");
}

#[test]
fn axis_coupling_follows_x_acceleration() {
    let spec = "axis-coupling:x_um_per_mps2=1.2";
    let clean = group(20.0, 5.0, &[]);
    let with = group(20.0, 5.0, &[spec]);
    let idx = tail(&with, 5.0);
    let diff: Vec<f64> = idx.iter().map(|&i| with.z_tcp_um[i] - clean.z_tcp_um[i]).collect();
    let x_acc: Vec<f64> = idx.iter().map(|&i| with.x_acc_mps2.as_ref().unwrap()[i]).collect();
    let (slope, r2) = regress(&x_acc, &diff);
    assert!((slope - 1.2).abs() < 0.03, "slope {slope} um per m/s^2");
    assert!(r2 > 0.99, "r2 {r2}");
}

#[test]
fn sensor_gain_scales_the_sensor() {
    let clean = group(1.0, 5.0, &[]);
    let probe = group(1.0, 5.0, &["sensor-gain:acc_gain=1,probe_gain=1.1"]);
    // A probe scale error shows as an in-phase error proportional to the motion, even at 1 Hz.
    let extra = harmonic_nm(&probe, 1.0, 1.0) - harmonic_nm(&clean, 1.0, 1.0);
    assert!((extra - 500.0).abs() < 25.0, "probe scale error {extra} nm");
    let clean40 = group(40.0, 5.0, &[]);
    let acc = group(40.0, 5.0, &["sensor-gain:acc_gain=0.92"]);
    let rms = |g: &GroupData| (g.acc_mps2.iter().map(|a| a * a).sum::<f64>() / g.len() as f64).sqrt();
    assert!((rms(&acc) / rms(&clean40) - 0.92).abs() < 0.01);
    // The TCP itself is untouched by an accelerometer scale error.
    assert_eq!(acc.z_tcp_um, clean40.z_tcp_um);
}

#[test]
fn names_parse_and_errors_are_clear() {
    for (kind, name) in Effect::ALL.iter().map(|e| (e, e.name())) {
        let spec: EffectSpec = name.parse().unwrap();
        assert_eq!(spec.kind(), *kind);
        let back: EffectSpec = spec.to_string().parse().unwrap();
        assert_eq!(back, spec);
    }
    let err = |s: &str| s.parse::<EffectSpec>().unwrap_err().to_string();
    assert!(err("friction").contains("unknown effect \"friction\""));
    assert!(err("loop-delay:delay=3").contains("unknown parameter `delay`"));
    assert!(
        err("loop-delay:delay_us=abc").contains("`delay_us`")
            && err("loop-delay:delay_us=abc").contains("not a number")
    );
    assert!(err("loop-delay:delay_us=-5").contains("out of range"));
    assert!(err("structural-mode:damping=1.5").contains("`damping`"));
    assert!(err("loop-delay:delay_us").contains("key=value"));
    assert!(err("loop-delay:delay_us=1,delay_us=2").contains("given twice"));
    let dup = [EffectSpec::new(Effect::LoopDelay), EffectSpec::new(Effect::LoopDelay)];
    let e = sts_emulator::Machine::new(&Default::default(), &dup, 1).unwrap_err().to_string();
    assert!(e.contains("given twice"), "{e}");
}

#[test]
fn random_draws_are_seeded_and_in_range() {
    use rand::SeedableRng;
    for effect in Effect::ALL {
        let mut a = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let mut b = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let x = EffectSpec::random(effect, &mut a).unwrap();
        let y = EffectSpec::random(effect, &mut b).unwrap();
        assert_eq!(x, y);
        let z = EffectSpec::random(effect, &mut a).unwrap();
        assert_ne!(x, z, "{effect}: two draws differ");
        // Each draw builds a machine.
        sts_emulator::Machine::new(&Default::default(), &[z], 1).unwrap();
    }
}
