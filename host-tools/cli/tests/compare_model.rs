//! `compare`: predictions are the firmware program's, scores match the definitions, the JSON
//! has its fields, and the CLI reports bad input instead of panicking.

use std::f64::consts::PI;
use std::process::Command;

use sts_assess::compare::compare;
use sts_emulator::MeasureConfig;
use sts_fit::{fit, FitConfig};
use sts_model::replay::{predict_group, program_output};

fn small(seed: u64, effects: Vec<sts_emulator::EffectSpec>) -> sts_dataset::Dataset {
    let config = MeasureConfig {
        freqs_hz: vec![5.0, 20.0, 40.0],
        amps_um: vec![2.0, 6.0, 10.0],
        duration_s: 5.5,
        seed,
        effects,
        ..MeasureConfig::default()
    };
    sts_emulator::measure::run(&config, &|_| {}).unwrap()
}

#[test]
fn compare_scores_the_firmware_prediction() {
    let data = small(3, Vec::new());
    let model = fit(&data, "compare test", &FitConfig { max_epochs: 6, folds: 3, ..FitConfig::default() }, &mut |_| {})
        .unwrap();
    let (c, waves) = compare(&data, &model).unwrap();
    assert_eq!(c.groups.len(), 9);
    // The synthesised waveform is amp * sin(theta + phase) from the program's registers.
    let program = model.firmware_program().unwrap();
    let fc = {
        let mut f = model.feature_config;
        f.sample_rate_hz = 8000.0;
        f
    };
    let samples =
        sts_analysis::group_samples_skipping(&data, &fc, model.training.as_ref().map_or(0.5, |t| t.skip_s)).unwrap();
    for s in &samples {
        let (out, ok) = program_output(&program, s);
        assert!(ok);
        let (pred, _) = predict_group(&program, s, &data.groups[s.index], 8000.0);
        for k in (0..pred.len()).step_by(997) {
            let theta = 2.0 * PI * s.targets.freq_hz * data.groups[s.index].t_s[k] + s.targets.cmd.phase_rad;
            let want = f64::from(out.amp_um()) * (theta + f64::from(out.phase_deg()).to_radians()).sin();
            assert!((pred[k] - want).abs() < 2e-4, "group {} sample {k}: {} vs {want}", s.index, pred[k]);
        }
    }
    // waveform_rms_um is the RMS over every group's last second of measured minus predicted.
    let (mut sq, mut n) = (0.0, 0usize);
    for w in &waves {
        for (m, p) in w.measured_um.iter().zip(&w.predicted_um) {
            sq += (m - p) * (m - p);
            n += 1;
        }
    }
    assert!(((sq / n as f64).sqrt() - c.waveform_rms_um).abs() < 1e-12);
    assert!(c.waveform_rms_um < 0.05, "a model on its own clean data: {} um", c.waveform_rms_um);
    assert!(c.amplitude_r2 > 0.99);

    // A drifting machine: the same model's error rises, mostly as the residual's mean.
    let drifting = small(4, vec!["thermal-drift:rise_k=1.5,tau_s=60,um_per_k=1".parse().unwrap()]);
    let (d, _) = compare(&drifting, &model).unwrap();
    assert!(d.waveform_rms_um > 5.0 * c.waveform_rms_um);
    let late = d.groups.last().unwrap();
    assert!(late.residual_mean_um > 0.5, "mean residual of the last group {}", late.residual_mean_um);

    // The CLI's JSON.
    let dir = std::env::temp_dir().join(format!("sts-twin-compare-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    sts_dataset::write(&dir.join("data"), &data).unwrap();
    model.write(&dir.join("model.json")).unwrap();
    let bin = env!("CARGO_BIN_EXE_sts-twin");
    let out = Command::new(bin)
        .args(["compare"])
        .arg(dir.join("data"))
        .arg("--model")
        .arg(dir.join("model.json"))
        .arg("--json")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for key in ["waveform_rms_um", "amplitude_r2", "phase_r2"] {
        assert!(v[key].is_number(), "JSON lacks {key}");
    }
    assert_eq!(v["groups"].as_array().unwrap().len(), 9);
    assert!((v["waveform_rms_um"].as_f64().unwrap() - c.waveform_rms_um).abs() < 1e-6);

    // A reader that closes the pipe early (`| head -1`): a quiet, successful exit, no panic.
    let mut child = Command::new(bin)
        .args(["compare"])
        .arg(dir.join("data"))
        .arg("--model")
        .arg(dir.join("model.json"))
        .arg("--json")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success() && !stderr.contains("panicked"), "closed stdout: {:?}, {stderr}", out.status);

    // Bad input: a clear error, no panic.
    let out = Command::new(bin)
        .args(["compare"])
        .arg(dir.join("data"))
        .arg("--model")
        .arg(dir.join("missing.json"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("missing.json"));
    let _ = std::fs::remove_dir_all(&dir);
}
