//! `export`: the C header compiled with the system's `cc` and evaluated on every group of a
//! dataset (within 1e-6 of the host's double prediction in double, 1e-4 in float), the SymPy
//! module and the MATLAB expressions evaluated by Python against the same prediction, LaTeX's
//! shape, and the per-tick terms named as not exported.

use std::f64::consts::PI;
use std::io::Write as _;
use std::path::Path;
use std::process::{Command, Stdio};

use sts_emulator::MeasureConfig;
use sts_fit::effects::prepare;
use sts_fit::{fit, FitConfig};
use sts_model::ModelFile;

/// The paper's 99 groups, each as long as the feature window needs.
fn dataset() -> sts_dataset::Dataset {
    let config = MeasureConfig { duration_s: 5.5, seed: 21, ..MeasureConfig::default() };
    sts_emulator::measure::run(&config, &|_| {}).expect("measurement")
}

fn quick() -> FitConfig {
    FitConfig { max_epochs: 8, ..FitConfig::default() }
}

fn sts_twin(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_sts-twin")).args(args).output().expect("sts-twin runs")
}

fn path(p: &Path) -> &str {
    p.to_str().expect("a UTF-8 path")
}

/// Per group: the features (as the firmware computes them) and five command phases in
/// [0, 2 pi); and the host's double prediction at each: amplitude, phase, Eq. 4.
struct Case {
    features: [f64; 12],
    theta_rad: f64,
    amp_um: f64,
    phase_deg: f64,
    error_um: f64,
}

fn host_cases(data: &sts_dataset::Dataset, model: &ModelFile) -> Vec<Case> {
    let mut fc = model.feature_config;
    fc.sample_rate_hz = data.manifest.sample_rate_hz as f32;
    let skip_s = model.training.as_ref().map_or(sts_analysis::DEFAULT_SKIP_S, |t| t.skip_s);
    let samples = sts_analysis::group_samples_skipping(data, &fc, skip_s).expect("features");
    assert_eq!(samples.len(), data.groups.len(), "every group has features");
    let mut cases = Vec::new();
    for s in &samples {
        let features: [f64; 12] = std::array::from_fn(|i| f64::from(s.features[i]));
        let amp_um = model.amplitude.expr.eval_row(&features);
        let phase_deg = model.phase.expr.eval_row(&features);
        for k in 0..5 {
            let theta_rad = 2.0 * PI * (f64::from(k) + 0.37) / 5.0;
            let error_um = amp_um * (theta_rad + phase_deg * PI / 180.0).sin();
            cases.push(Case { features, theta_rad, amp_um, phase_deg, error_um });
        }
    }
    cases
}

const DRIVER: &str = r#"#include <stdio.h>
#include "twin.h"
int main(void)
{
    double f[12], theta;
    while (1) {
        float g[12];
        int i;
        for (i = 0; i < 12; i++) {
            if (scanf("%lf", &f[i]) != 1) return 0;
            g[i] = (float)f[i];
        }
        if (scanf("%lf", &theta) != 1) return 1;
        printf("%.17g %.17g %.17g %.9g %.9g %.9g\n", sts_twin_amp_um(f), sts_twin_phase_deg(f),
               sts_twin_error_um(f, theta), (double)sts_twin_amp_um_f(g), (double)sts_twin_phase_deg_f(g),
               (double)sts_twin_error_um_f(g, (float)theta));
    }
}
"#;

fn rows(cases: &[Case]) -> String {
    let mut text = String::new();
    for c in cases {
        for f in c.features {
            text.push_str(&format!("{f:?} "));
        }
        text.push_str(&format!("{:?}\n", c.theta_rad));
    }
    text
}

/// `|a - b|` relative to `scale` (the quantity's own size, at least `floor`).
fn relative(a: f64, b: f64, scale: f64, floor: f64) -> f64 {
    (a - b).abs() / scale.abs().max(floor)
}

#[test]
fn the_c_header_computes_the_hosts_prediction_on_every_group() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("export-c-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let data = dataset();
    let model = fit(&data, "export test", &quick(), &mut |_| {}).expect("fit");
    let model_path = dir.join("twin.json");
    model.write(&model_path).unwrap();

    let out = sts_twin(&["export", path(&model_path), "--to", "c", "--out", path(&dir.join("twin.h"))]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let header = std::fs::read_to_string(dir.join("twin.h")).unwrap();
    assert!(header.contains("no per-tick terms"), "{header}");
    std::fs::write(dir.join("driver.c"), DRIVER).unwrap();
    let cc = Command::new("cc")
        .args(["-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-O2", "-o"])
        .arg(dir.join("driver"))
        .arg(dir.join("driver.c"))
        .arg("-lm")
        .output()
        .expect("cc (a C compiler) runs");
    assert!(cc.status.success(), "the header does not compile:\n{}", String::from_utf8_lossy(&cc.stderr));

    let cases = host_cases(&data, &model);
    let mut child =
        Command::new(dir.join("driver")).stdin(Stdio::piped()).stdout(Stdio::piped()).spawn().expect("the driver runs");
    child.stdin.take().unwrap().write_all(rows(&cases).as_bytes()).unwrap();
    let output = child.wait_with_output().unwrap();
    assert!(output.status.success());
    let lines: Vec<Vec<f64>> = String::from_utf8(output.stdout)
        .unwrap()
        .lines()
        .map(|l| l.split_whitespace().map(|v| v.parse().expect("a number")).collect())
        .collect();
    assert_eq!(lines.len(), cases.len(), "one line per case");
    let (mut worst_double, mut worst_float) = (0.0f64, 0.0f64);
    for (c, v) in cases.iter().zip(&lines) {
        // Amplitude and phase relative to themselves (phase at least a degree); Eq. 4
        // relative to the amplitude (a sine passes through zero).
        let double = [
            relative(v[0], c.amp_um, c.amp_um, 1e-9),
            relative(v[1], c.phase_deg, c.phase_deg, 1.0),
            relative(v[2], c.error_um, c.amp_um, 1e-9),
        ];
        let float = [
            relative(v[3], c.amp_um, c.amp_um, 1e-9),
            relative(v[4], c.phase_deg, c.phase_deg, 1.0),
            relative(v[5], c.error_um, c.amp_um, 1e-9),
        ];
        worst_double = double.iter().copied().fold(worst_double, f64::max);
        worst_float = float.iter().copied().fold(worst_float, f64::max);
    }
    println!(
        "{} groups x 5 phases: worst relative difference from the host, double {worst_double:.2e}, float {worst_float:.2e}",
        data.groups.len()
    );
    assert!(worst_double <= 1e-6, "double: {worst_double:e}");
    assert!(worst_float <= 1e-4, "float: {worst_float:e}");

    // SymPy and the MATLAB expressions, evaluated by Python on the same features.
    for (to, file) in [("sympy", "twin_sympy.py"), ("matlab", "sts_twin.m"), ("latex", "twin.tex")] {
        let out = sts_twin(&["export", path(&model_path), "--to", to, "--out", path(&dir.join(file))]);
        assert!(out.status.success(), "{to}: {}", String::from_utf8_lossy(&out.stderr));
    }
    let latex = std::fs::read_to_string(dir.join("twin.tex")).unwrap();
    assert!(latex.contains("\\begin{align}") && latex.contains("DE(\\theta)"), "{latex}");
    let matlab = std::fs::read_to_string(dir.join("sts_twin.m")).unwrap();
    let line = |prefix: &str| {
        matlab.lines().find_map(|l| l.strip_prefix(prefix)).and_then(|l| l.strip_suffix(';')).expect(prefix).to_string()
    };
    let (matlab_amp, matlab_phase) = (line("amp_um = "), line("phase_deg = "));
    let mut script = format!(
        "import sys, math\nsys.path.insert(0, {dir:?})\nimport twin_sympy as t\nfrom math import exp, log, sin, sqrt, tanh\n\
         power = lambda a, b: a ** b\nworst = [0.0, 0.0]\n",
        dir = path(&dir)
    );
    for c in cases.iter().step_by(5) {
        script.push_str(&format!(
            "feats = {:?}\nf = lambda i: feats[i - 1]\n\
             subs = dict(zip(t.features, feats))\n\
             a, p = float(t.amplitude_um.evalf(30, subs=subs)), float(t.phase_deg.evalf(30, subs=subs))\n\
             worst[0] = max(worst[0], abs(a - {amp:?}) / max(abs({amp:?}), 1e-9), abs(p - {phase:?}) / max(abs({phase:?}), 1.0))\n\
             ma, mp = {matlab_amp}, {matlab_phase}\n\
             worst[1] = max(worst[1], abs(ma - {amp:?}) / max(abs({amp:?}), 1e-9), abs(mp - {phase:?}) / max(abs({phase:?}), 1.0))\n",
            c.features.to_vec(),
            amp = c.amp_um,
            phase = c.phase_deg,
        ));
    }
    script.push_str("print(worst[0], worst[1])\n");
    let py = Command::new("python3").arg("-c").arg(&script).output().expect("python3 runs");
    assert!(
        py.status.success(),
        "python3 with sympy (scripts/setup.sh installs it): {}",
        String::from_utf8_lossy(&py.stderr)
    );
    let worst: Vec<f64> =
        String::from_utf8(py.stdout).unwrap().split_whitespace().map(|v| v.parse().unwrap()).collect();
    println!("SymPy {:.2e}, MATLAB expressions (in Python) {:.2e}", worst[0], worst[1]);
    assert!(worst[0] <= 1e-9 && worst[1] <= 1e-9, "{worst:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn per_tick_terms_are_named_as_not_exported() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("export-terms-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let data = dataset();
    let prepared = prepare(&data, &["thermal-drift".to_string()]).expect("prepare");
    let model = prepared.attach(fit(&prepared.dataset, "export test", &quick(), &mut |_| {}).expect("fit")).unwrap();
    let model_path = dir.join("drift.json");
    model.write(&model_path).unwrap();
    for to in ["c", "matlab", "sympy", "latex"] {
        let out = sts_twin(&["export", path(&model_path), "--to", to]);
        assert!(out.status.success());
        let (text, err) = (String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
        assert!(text.contains("NOT EXPORTED") && text.contains("thermal drift"), "{to}: {text}");
        assert!(err.contains("not exported") && err.contains("thermal-drift"), "{to}: {err}");
    }
    // Bad input: an unknown language, a missing file, a name C cannot take.
    let out = sts_twin(&["export", path(&model_path), "--to", "fortran"]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("c, matlab, sympy or latex"));
    let out = sts_twin(&["export", path(&dir.join("missing.json")), "--to", "c"]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("missing.json"));
    let out = sts_twin(&["export", path(&model_path), "--to", "c", "--name", "2twin"]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("2twin"));
    let _ = std::fs::remove_dir_all(&dir);
}
