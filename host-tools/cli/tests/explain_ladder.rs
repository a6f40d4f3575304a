//! `explain` as a lab runs it: one measurement of a machine with two effects, no twin to
//! start from; the loop names both, the error falls at each rung, and it stops at `none`
//! near the data's floor. The JSON has the promised fields, the HTML the ladder, and bad
//! input is an error that names it.

use std::path::{Path, PathBuf};
use std::process::Command;

use sts_emulator::{EffectSpec, MeasureConfig};

fn sts_twin(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_sts-twin")).args(args).output().unwrap()
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The paper's 99 groups, each only as long as the feature window needs.
fn measure(dir: &Path, effects: Vec<EffectSpec>, seed: u64) {
    let config = MeasureConfig { effects, seed, duration_s: 5.5, ..MeasureConfig::default() };
    let data = sts_emulator::measure::run(&config, &|_| {}).unwrap();
    sts_dataset::write(dir, &data).unwrap();
}

#[test]
fn explain_names_two_effects_one_after_the_other_and_stops_at_the_floor() {
    let dir: PathBuf = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("explain-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let data = dir.join("data");
    let effects = vec!["thermal-drift".parse().unwrap(), "axis-coupling".parse().unwrap()];
    measure(&data, effects, 21);
    let (out, html) = (dir.join("twin.json"), dir.join("ladder.html"));
    let run =
        sts_twin(&["explain", path(&data), "--out", path(&out), "--html", path(&html), "--json", "--epochs", "10"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    // --json: JSON only on stdout; progress on stderr.
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    let steps = v["steps"].as_array().unwrap();
    let mut named: Vec<&str> = steps.iter().map(|s| s["effect"].as_str().unwrap()).collect();
    named.sort_unstable();
    assert_eq!(named, ["axis-coupling", "thermal-drift"], "{v:#}");
    for s in steps {
        let (before, after) =
            (s["waveform_rms_um_before"].as_f64().unwrap(), s["waveform_rms_um_after"].as_f64().unwrap());
        assert!(after < before, "{}: {before} -> {after} um", s["effect"]);
        assert!(s["params"].as_object().is_some_and(|p| !p.is_empty()), "{s:#}");
    }
    assert_eq!(v["verdict"], "none", "{v:#}");
    let start_um = v["start_waveform_rms_um"].as_f64().unwrap();
    let final_um = v["waveform_rms_um"].as_f64().unwrap();
    assert_eq!(final_um, steps.last().unwrap()["waveform_rms_um_after"].as_f64().unwrap());
    // Near the floor: the emulator's probe noise is 5 nm; a clean twin on such data holds ~10 nm.
    assert!(final_um < 0.02 && final_um < 0.1 * start_um, "{start_um} -> {final_um} um");
    // The written twin carries both effects and is a model file the other commands read.
    let model: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let carried: Vec<&str> =
        model["effects"].as_array().unwrap().iter().map(|e| e["effect"].as_str().unwrap()).collect();
    assert_eq!(carried.len(), 2, "{carried:?}");
    let check = sts_twin(&["diagnose", path(&data), "--model", path(&out), "--json"]);
    assert!(check.status.success());
    let d: serde_json::Value = serde_json::from_slice(&check.stdout).unwrap();
    assert_eq!(d["verdict"], "none");
    let page = std::fs::read_to_string(&html).unwrap();
    assert!(page.contains("id=\"ladder\"") && page.contains("+ thermal-drift") && page.contains("id=\"stop\""));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn explain_refuses_bad_input_with_the_path() {
    let dir: PathBuf = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("explain-bad-{}", std::process::id()));
    let missing = dir.join("no-such-dataset");
    let run = sts_twin(&["explain", path(&missing), "--out", path(&dir.join("t.json"))]);
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("no-such-dataset"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}
