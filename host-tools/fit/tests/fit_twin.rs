//! The default fit on the default emulated measurement test (99 groups, simulated in
//! memory): the held-out figures the twin must reach, determinism across thread counts,
//! the firmware program against the formulas, and the Rust/C exports (compiled with the
//! system's `rustc` and `cc`).

use std::process::Command;
use std::sync::OnceLock;

use rayon::prelude::*;
use sts_analysis::targets::PHASE_MIN_AMP_UM;
use sts_analysis::{feature_config_for, group_samples, GroupSample};
use sts_dataset::Dataset;
use sts_emulator::measure::{simulate_group, MeasureConfig};
use sts_fit::{fit, predict, FitConfig};
use sts_model::ModelFile;

/// The default measurement test (seed 1), without the columns the fit does not read.
fn dataset() -> &'static Dataset {
    static DATA: OnceLock<Dataset> = OnceLock::new();
    DATA.get_or_init(|| {
        let config = MeasureConfig::default();
        let groups = (0..config.groups().len())
            .into_par_iter()
            .map(|i| {
                let mut g = simulate_group(&config, i).expect("the default machine simulates");
                (g.x_mm, g.x_acc_mps2, g.spindle_deg, g.temp_c) = (None, None, None, None);
                g
            })
            .collect();
        Dataset { manifest: config.manifest(), groups }
    })
}

fn samples() -> &'static [GroupSample] {
    static SAMPLES: OnceLock<Vec<GroupSample>> = OnceLock::new();
    SAMPLES.get_or_init(|| group_samples(dataset(), &feature_config_for(dataset(), None)).unwrap())
}

fn model(threads: usize) -> ModelFile {
    let config = FitConfig { seed: 1, threads, ..FitConfig::default() };
    fit(dataset(), "default emulator data, seed 1", &config, &mut |_| {}).unwrap()
}

fn default_model() -> &'static ModelFile {
    static MODEL: OnceLock<ModelFile> = OnceLock::new();
    MODEL.get_or_init(|| model(2))
}

#[test]
fn held_out_figures_meet_the_must_show() {
    let m = default_model();
    let v = &m.validation;
    assert_eq!(v.groups.len(), 99);
    assert!(v.amplitude_r2 >= 0.99, "held-out amplitude R^2 {}", v.amplitude_r2);
    assert!(v.phase_r2 >= 0.97, "held-out phase R^2 {}", v.phase_r2);
    assert!(v.waveform_mae_um < 0.030, "held-out waveform MAE {} um", v.waveform_mae_um);
    // Readable: within the default complexity limit, arithmetic only.
    for f in [&m.amplitude, &m.phase] {
        assert!(f.complexity <= FitConfig::default().max_complexity, "{}", f.formula);
        assert!(
            ["abs", "sqrt", "exp", "log", "tanh", "sin", "**"].iter().all(|op| !f.formula.contains(op)),
            "{}",
            f.formula
        );
        assert!(f.selection.contains("<- selected"), "{}", f.selection);
        assert!(f.front.iter().all(|e| e.r2_cv.is_some()));
    }
    let training = m.training.as_ref().unwrap();
    assert_eq!(training.skip_s, 0.5);
    assert_eq!(training.operators, "+,-,*,/");
}

#[test]
fn same_seed_gives_the_same_model_file_for_any_thread_count() {
    let dir = std::env::temp_dir().join(format!("sts-twin-fit-determinism-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (a, b) = (dir.join("threads2.json"), dir.join("threads1.json"));
    default_model().write(&a).unwrap();
    model(1).write(&b).unwrap();
    let (a_bytes, b_bytes) = (std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    assert!(a_bytes == b_bytes, "model files differ between 2 threads and 1 thread");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The firmware evaluates the program in f32; the formulas are f64. On every training group
/// they agree within 1e-6 of the amplitude scale (the largest measured amplitude, here
/// 1e-5 um) and 1e-4 degrees, far below the model's own error (measured: 3e-8 and 6e-6).
#[test]
fn firmware_program_agrees_with_the_formulas() {
    let m = default_model();
    let program = m.firmware_program().unwrap();
    let amp_scale = samples().iter().map(|s| s.targets.de_amp_um).fold(0.0, f64::max);
    let (mut worst_amp, mut worst_phase) = (0.0f64, 0.0f64);
    for s in samples() {
        let row: Vec<f64> = s.features.iter().map(|&f| f64::from(f)).collect();
        let (amp32, phase32) = predict(&program, s);
        let (amp64, phase64) = (m.amplitude.expr.eval_row(&row), m.phase.expr.eval_row(&row));
        worst_amp = worst_amp.max((amp32 - amp64).abs() / amp_scale);
        if s.targets.de_amp_um >= PHASE_MIN_AMP_UM {
            worst_phase = worst_phase.max((phase32 - phase64).abs());
        }
    }
    assert!(worst_amp <= 1e-6, "amplitude: f32 program vs f64 formula differ by {worst_amp:e} of the scale");
    assert!(worst_phase <= 1e-4, "phase: f32 program vs f64 formula differ by {worst_phase} deg");
}

/// Every tenth training group's features, as source literals.
fn probe_rows() -> Vec<Vec<f64>> {
    samples().iter().step_by(10).map(|s| s.features.iter().map(|&f| f64::from(f)).collect()).collect()
}

fn check_printed(stdout: &[u8], m: &ModelFile, rows: &[Vec<f64>]) {
    let text = String::from_utf8_lossy(stdout);
    let values: Vec<f64> = text.split_whitespace().map(|v| v.parse().unwrap()).collect();
    assert_eq!(values.len(), 2 * rows.len(), "{text}");
    for (row, pair) in rows.iter().zip(values.chunks(2)) {
        for (value, expr) in pair.iter().zip([&m.amplitude.expr, &m.phase.expr]) {
            let want = expr.eval_row(row);
            assert!((value - want).abs() <= 1e-12 * (1.0 + want.abs()), "exported {value}, formula {want}");
        }
    }
}

fn scratch(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("sts-twin-fit-export-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d.join(name)
}

#[test]
fn rust_export_compiles_and_computes_the_formulas() {
    let m = default_model();
    let rows = probe_rows();
    let mut src = String::from("#![deny(warnings)]\n");
    src.push_str(&m.rust_source("test data"));
    src.push_str("fn main() {\n");
    for r in &rows {
        let lits: Vec<String> = r.iter().map(|v| format!("{v:?}_f64")).collect();
        src.push_str(&format!(
            "    let x = [{}];\n    println!(\"{{:?}} {{:?}}\", dynamic_error_amp_um(&x), dynamic_error_phase_deg(&x));\n",
            lits.join(", ")
        ));
    }
    src.push_str("}\n");
    let (rs, bin) = (scratch("twin.rs"), scratch("twin_rs"));
    std::fs::write(&rs, &src).unwrap();
    let rustc = std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into());
    let status = Command::new(rustc)
        .arg("--edition=2021")
        .arg(&rs)
        .arg("-o")
        .arg(&bin)
        .status()
        .expect("rustc is needed for this test");
    assert!(status.success(), "rustc failed on:\n{src}");
    check_printed(&Command::new(&bin).output().unwrap().stdout, m, &rows);
}

#[test]
fn c_export_compiles_and_computes_the_formulas() {
    let m = default_model();
    let rows = probe_rows();
    let mut src = m.c_source("test data");
    src.push_str("#include <stdio.h>\nint main(void) {\n");
    for r in &rows {
        let lits: Vec<String> = r.iter().map(|v| format!("{v:?}")).collect();
        src.push_str(&format!(
            "    {{ const double x[12] = {{ {} }}; printf(\"%.17g %.17g\\n\", dynamic_error_amp_um(x), dynamic_error_phase_deg(x)); }}\n",
            lits.join(", ")
        ));
    }
    src.push_str("    return 0;\n}\n");
    let (c, bin) = (scratch("twin.c"), scratch("twin_c"));
    std::fs::write(&c, &src).unwrap();
    let status = Command::new("cc")
        .args(["-std=c99", "-Wall", "-Wextra", "-Werror"])
        .arg(&c)
        .arg("-lm")
        .arg("-o")
        .arg(&bin)
        .status()
        .expect("a C compiler (cc) is needed for this test");
    assert!(status.success(), "cc failed on:\n{src}");
    check_printed(&Command::new(&bin).output().unwrap().stdout, m, &rows);
}
