//! The loop on measurements that did not come from our emulator: a two-mass slide under a
//! cascaded servo with LuGre friction (`foreign`), exported as a lab would (its own CSV
//! writer, column order, line ends and grid: 7 frequencies x 5 amplitudes, 35 groups), driven
//! through the `sts-twin` command as a user drives it: fit the clean machine, then for each
//! changed machine compare, diagnose, fit with the verdict, and see the error fall.
//!
//! Prints the table recorded in BENCHMARKS.md ("The loop on a foreign machine").

mod foreign;

use foreign::{Foreign, Lugre};
use std::path::{Path, PathBuf};
use std::process::Command;

const FREQS_HZ: [f64; 7] = [2.0, 6.0, 12.0, 20.0, 28.0, 34.0, 40.0];
const AMPS_UM: [f64; 5] = [1.5, 3.0, 5.0, 7.5, 10.0];
const DURATION_S: f64 = 6.0;

/// Runs `sts-twin ARGS`, which must succeed; its standard output as JSON when `--json` is
/// among the arguments.
fn sts_twin(args: &[&str]) -> serde_json::Value {
    let out = Command::new(env!("CARGO_BIN_EXE_sts-twin")).args(args).output().unwrap();
    assert!(out.status.success(), "sts-twin {}: {}", args.join(" "), String::from_utf8_lossy(&out.stderr));
    if args.contains(&"--json") {
        serde_json::from_slice(&out.stdout).unwrap()
    } else {
        serde_json::Value::Null
    }
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The model file's held-out waveform RMS, um.
fn held_out_rms_um(model: &Path) -> f64 {
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(model).unwrap()).unwrap();
    v["validation"]["waveform_rms_um"].as_f64().unwrap()
}

struct Case {
    name: &'static str,
    machine: Foreign,
    seed: u64,
    /// Verdicts that name the change (LuGre friction is presliding and sliding friction both).
    verdicts: &'static [&'static str],
}

#[test]
fn the_loop_works_on_a_machine_that_is_not_the_emulator() {
    let dir: PathBuf = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("foreign-machine-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let clean = Foreign::default();
    let lugre = Lugre { coulomb_n: 3.0, static_n: 4.0, stribeck_mps: 3e-4, sigma0_n_per_m: 1.5e6, sigma1_ns_per_m: 300.0 };
    let cases = [
        Case { name: "lugre-friction", machine: Foreign { friction: Some(lugre), ..clean }, seed: 3, verdicts: &["presliding-hysteresis", "coulomb-friction"] },
        // Four ticks more between encoder and force (500 us).
        Case { name: "delay", machine: Foreign { delay_ticks: 5, ..clean }, seed: 4, verdicts: &["loop-delay"] },
        Case { name: "probe-gain", machine: Foreign { probe_gain: 0.95, ..clean }, seed: 5, verdicts: &["sensor-gain"] },
    ];
    let mut runs: Vec<(&str, Foreign, u64)> = vec![("clean", clean, 1), ("clean-again", clean, 2)];
    runs.extend(cases.iter().map(|c| (c.name, c.machine, c.seed)));
    std::thread::scope(|s| {
        for (name, machine, seed) in &runs {
            let d = dir.join(name);
            s.spawn(move || machine.measure(&d, &FREQS_HZ, &AMPS_UM, DURATION_S, *seed));
        }
    });

    // The clean machine's twin.
    let m0 = dir.join("twin.json");
    sts_twin(&["fit", path(&dir.join("clean")), "--out", path(&m0), "--quiet"]);
    let clean_rms_um = held_out_rms_um(&m0);
    let again = sts_twin(&["compare", path(&dir.join("clean-again")), "--model", path(&m0), "--json"]);
    let verdict = sts_twin(&["diagnose", path(&dir.join("clean-again")), "--model", path(&m0), "--json"]);
    println!(
        "clean machine: twin's held-out RMS {:.1} nm; on a second measurement {:.1} nm (amplitude R^2 {:.5}), verdict {}",
        clean_rms_um * 1e3,
        again["waveform_rms_um"].as_f64().unwrap() * 1e3,
        again["amplitude_r2"].as_f64().unwrap(),
        verdict["verdict"]
    );
    assert!(clean_rms_um < 0.05, "the clean twin's held-out RMS {clean_rms_um} um");
    assert!(again["amplitude_r2"].as_f64().unwrap() > 0.99);
    assert_eq!(verdict["verdict"], "none", "clean data: {}", verdict["summary"]);

    let mut failures = Vec::new();
    for case in &cases {
        let data = dir.join(case.name);
        let before_um = sts_twin(&["compare", path(&data), "--model", path(&m0), "--json"])["waveform_rms_um"].as_f64().unwrap();
        let d = sts_twin(&["diagnose", path(&data), "--model", path(&m0), "--json"]);
        let verdict = d["verdict"].as_str().unwrap().to_string();
        let refit = dir.join(format!("twin-{}.json", case.name));
        let after_um = if verdict == "none" {
            f64::NAN
        } else {
            sts_twin(&["fit", path(&data), "--effect", &verdict, "--out", path(&refit), "--quiet"]);
            held_out_rms_um(&refit)
        };
        let fall = 1.0 - after_um / before_um;
        println!(
            "{:<15} twin of the clean machine {:>6.1} nm; verdict {verdict} ({:.0}% explained, p = {:.1e}; then {}); refit held-out {:>5.1} nm: fall {:.0}%, {:.2}x clean",
            case.name,
            before_um * 1e3,
            d["ranking"][0]["explained_fraction"].as_f64().unwrap() * 100.0,
            d["ranking"][0]["p_value"].as_f64().unwrap(),
            d["ranking"][1]["effect"],
            after_um * 1e3,
            fall * 100.0,
            after_um / clean_rms_um
        );
        if !case.verdicts.contains(&verdict.as_str()) {
            failures.push(format!("{}: verdict {verdict}, expected one of {:?}: {}", case.name, case.verdicts, d["summary"]));
        } else if fall.is_nan() || fall < 0.5 {
            failures.push(format!("{}: the refit's error fell {:.0}% only", case.name, fall * 100.0));
        }
        if case.name == "probe-gain" {
            let gain = d["ranking"][0]["params"]["probe_gain"].as_f64().unwrap_or(f64::NAN);
            if gain.is_nan() || (gain - 0.95).abs() >= 0.005 {
                failures.push(format!("probe-gain: estimated {gain}, true 0.95"));
            }
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    assert!(failures.is_empty(), "{failures:#?}");
}
