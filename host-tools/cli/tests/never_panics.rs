//! The readers of untrusted input and the diagnosis under random and mutated input: the
//! dataset reader (group files and manifests), the import's readers (CSV, TSV, MAT v5, HDF5,
//! TDMS: real recordings with bytes flipped, cut or spliced), the model file reader (a real
//! twin's fields replaced by hostile values, or its bytes flipped, then exported) and the
//! diagnosis (a real dataset with values at its channels' bounds). Each gives an error or a
//! result, never a panic.
//!
//! By default a few cases each (CI). `STS_FUZZ_S=600` runs each of the four tests for that
//! many seconds instead (its readers sharing the time) and prints the cases run; all four at
//! once: `STS_FUZZ_S=600 cargo test --profile ci -p sts-twin --test tests -- never_panics::
//! --test-threads 4 --nocapture`.

use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};

/// Runs `test` on values of `strategy`: `cases` of them, or with `STS_FUZZ_S` set, as many as
/// `share` of that many seconds take (a test's loops share its time). A panic fails with the
/// (shrunk) input.
fn fuzz<S: Strategy>(name: &str, cases: u32, share: f64, strategy: S, test: impl Fn(S::Value))
where
    S::Value: std::fmt::Debug,
{
    let seconds: Option<f64> = std::env::var("STS_FUZZ_S").ok().and_then(|s| s.parse::<f64>().ok()).map(|s| s * share);
    let count = AtomicUsize::new(0);
    let started = Instant::now();
    let deadline = seconds.map(|s| started + Duration::from_secs_f64(s));
    loop {
        let batch = if deadline.is_some() { cases.min(32) } else { cases };
        let mut runner = TestRunner::new(Config { cases: batch, failure_persistence: None, ..Config::default() });
        let result = runner.run(&strategy, |value| {
            count.fetch_add(1, Ordering::Relaxed);
            test(value);
            Ok(())
        });
        if let Err(error) = result {
            panic!("{name}: {error}");
        }
        if deadline.is_none_or(|d| Instant::now() >= d) {
            break;
        }
    }
    if seconds.is_some() {
        eprintln!(
            "{name}: {} cases in {:.0} s, no panic",
            count.load(Ordering::Relaxed),
            started.elapsed().as_secs_f64()
        );
    }
}

/// `bytes` with a few bytes replaced, then maybe cut short or with a slice of it repeated.
fn mutated(seed: Vec<u8>) -> impl Strategy<Value = Vec<u8>> {
    let len = seed.len().max(1);
    (
        proptest::collection::vec((0..len, any::<u8>()), 0..8),
        proptest::option::weighted(0.3, 0..len),
        proptest::option::weighted(0.2, (0..len, 0..len, 0..len)),
    )
        .prop_map(move |(flips, cut, splice)| {
            let mut bytes = seed.clone();
            for (at, b) in flips {
                if at < bytes.len() {
                    bytes[at] = b;
                }
            }
            if let Some((from, to, at)) = splice {
                let (from, to) = (from.min(to), from.max(to).min(from + 4096));
                let piece = bytes[from..to].to_vec();
                let at = at.min(bytes.len());
                bytes.splice(at..at, piece);
            }
            if let Some(cut) = cut {
                bytes.truncate(cut);
            }
            bytes
        })
}

/// Text a CSV scanner meets at its edges: numbers huge, tiny, not finite, malformed.
fn field() -> impl Strategy<Value = String> {
    prop_oneof![
        (-1e7f64..1e7).prop_map(|v| v.to_string()),
        Just("1e308".to_string()),
        Just("-1e308".to_string()),
        Just("1e309".to_string()),
        Just("NaN".to_string()),
        Just("inf".to_string()),
        Just("".to_string()),
        Just("9".repeat(400)),
        "[0-9.eE+\\- ]{0,12}",
    ]
}

const HEADER: &str = "t_s,z_cmd_um,z_enc_um,z_tcp_um,acc_mps2";

#[test]
fn the_dataset_reader_never_panics() {
    let rows = proptest::collection::vec(proptest::collection::vec(field(), 0..7), 0..40);
    let text = (prop_oneof![Just(HEADER.to_string()), "[a-z_,]{0,60}"], rows).prop_map(|(header, rows)| {
        let mut text = header + "\n";
        for (k, row) in rows.iter().enumerate() {
            let mut fields = row.clone();
            if let Some(t) = fields.first_mut()
                && k % 2 == 0
            {
                *t = (k as f64 / 8000.0).to_string();
            }
            text += &fields.join(",");
            text.push('\n');
        }
        text.into_bytes()
    });
    let bytes = prop_oneof![text, proptest::collection::vec(any::<u8>(), 0..600)];
    fuzz("group file", 256, 0.5, bytes, |bytes| {
        let _ = sts_dataset::parse_group_csv(Path::new("g.csv"), &bytes, 8000.0);
    });
    // A manifest mutated beside a real group file, read as a whole dataset.
    let dir = tempfile::tempdir().unwrap();
    let mut group = sts_dataset::GroupData::with_len(20);
    for (k, t) in group.t_s.iter_mut().enumerate() {
        *t = k as f64 / 8000.0;
    }
    let info = sts_dataset::GroupInfo::new("g000.csv", 5.0, 1.0, 0.0);
    let data =
        sts_dataset::Dataset { manifest: sts_dataset::Manifest::new(8000.0, "fuzz", vec![info]), groups: vec![group] };
    sts_dataset::write(&dir.path().join("d"), &data).unwrap();
    let manifest = std::fs::read(dir.path().join("d/manifest.json")).unwrap();
    let d = dir.path().join("d");
    fuzz("manifest", 64, 0.5, mutated(manifest), |bytes| {
        std::fs::write(d.join("manifest.json"), bytes).unwrap();
        let _ = sts_dataset::read(&d);
    });
}

/// A recording of two groups (20 Hz at 5 um, 40 Hz at 2 um) between pauses: (t, cmd, enc,
/// tcp, acc) per row.
fn recording() -> Vec<[f64; 5]> {
    let rate = 8000.0;
    let mut rows = Vec::new();
    let mut t = 0.0;
    let mut push = |n: usize, f: f64, a: f64, rows: &mut Vec<[f64; 5]>| {
        for k in 0..n {
            let s = k as f64 / rate;
            let cmd = a * (2.0 * std::f64::consts::PI * f * s).sin();
            rows.push([t, cmd, cmd * 0.99, cmd * 1.01 + 0.002, -cmd * 1e-3]);
            t += 1.0 / rate;
        }
    };
    for (n, f, a) in [(800, 0.0, 0.0), (2000, 20.0, 5.0), (800, 0.0, 0.0), (2000, 40.0, 2.0), (800, 0.0, 0.0)] {
        push(n, f, a, &mut rows);
    }
    rows
}

const NAMES: [&str; 5] = ["t_s", "z_cmd_um", "z_enc_um", "z_tcp_um", "acc_mps2"];

/// The mapping of a recording whose channels are `prefix` + the dataset's column names.
fn mapping(prefix: &str, time: bool) -> String {
    let mut text = String::new();
    if !time {
        text += "sample_rate_hz = 8000\n";
    }
    text += "[segments]\nmin_pause_s = 0.05\n[channels]\n";
    let roles = ["time", "command", "encoder", "probe", "accelerometer"];
    let units = ["s", "um", "um", "um", "m/s^2"];
    for i in usize::from(!time)..5 {
        text += &format!("{} = {{ name = \"{prefix}{}\", unit = \"{}\" }}\n", roles[i], NAMES[i], units[i]);
    }
    text
}

/// The recording in every format the import reads, as (file name, bytes, mapping); the
/// binary formats written by Python (SciPy, h5py, npTDMS, as the import tests write them).
fn recordings(dir: &Path) -> Vec<(String, Vec<u8>, String)> {
    let rows = recording();
    let mut csv = NAMES.join(",") + "\n";
    for r in &rows {
        csv += &r.iter().map(|v| format!("{v:.7}")).collect::<Vec<_>>().join(",");
        csv.push('\n');
    }
    std::fs::write(dir.join("rec.csv"), &csv).unwrap();
    let script = r#"
import csv, sys
import numpy as np
d = sys.argv[1]
with open(d + "/rec.csv") as f:
    r = list(csv.reader(f))
names = r[0]
data = np.array(r[1:], dtype=float)
import scipy.io
scipy.io.savemat(d + "/rec.mat", {n: data[:, i:i + 1] for i, n in enumerate(names)})
import h5py
with h5py.File(d + "/rec.h5", "w") as h:
    for i, n in enumerate(names):
        h["log/" + n] = data[:, i]
from nptdms import TdmsWriter, ChannelObject
with TdmsWriter(d + "/rec.tdms") as w:
    w.write_segment([ChannelObject("task", n, data[:, i]) for i, n in enumerate(names) if n != "t_s"])
"#;
    let py = std::process::Command::new("python3").args(["-c", script]).arg(dir).output().expect("python3 runs");
    assert!(
        py.status.success(),
        "python3 with SciPy, h5py, npTDMS (scripts/setup-python.sh): {}",
        String::from_utf8_lossy(&py.stderr)
    );
    let read = |name: &str| std::fs::read(dir.join(name)).unwrap();
    vec![
        ("rec.csv".into(), csv.clone().into_bytes(), mapping("", true)),
        ("rec.tsv".into(), csv.replace(',', "\t").into_bytes(), mapping("", true)),
        ("rec.mat".into(), read("rec.mat"), mapping("", true)),
        ("rec.h5".into(), read("rec.h5"), mapping("log/", true)),
        ("rec.tdms".into(), read("rec.tdms"), mapping("task/", false)),
    ]
}

#[test]
fn the_import_readers_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    for (name, seed, map) in recordings(dir.path()) {
        let map_path = dir.path().join(format!("{name}.toml"));
        let mapping = sts_import::mapping::Mapping::parse(&map_path, &map).unwrap();
        let path = dir.path().join(format!("fuzz-{name}"));
        let out = dir.path().join(format!("out-{name}"));
        // The seed itself imports: the mutations start from a recording the readers accept.
        std::fs::write(&path, &seed).unwrap();
        let imported = sts_import::import(std::slice::from_ref(&path), &mapping, &map_path, &out, &mut |_, _| {})
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(imported.groups.len(), 2, "{name}");
        std::fs::remove_dir_all(&out).unwrap();
        fuzz(&format!("import {name}"), 24, 0.2, mutated(seed), |bytes| {
            std::fs::write(&path, bytes).unwrap();
            if sts_import::import(std::slice::from_ref(&path), &mapping, &map_path, &out, &mut |_, _| {}).is_ok() {
                std::fs::remove_dir_all(&out).unwrap();
            }
        });
    }
}

/// Paths to every leaf of a JSON value (JSON pointers).
fn leaves(value: &serde_json::Value, at: String, out: &mut Vec<String>) {
    match value {
        serde_json::Value::Array(items) => {
            for (i, v) in items.iter().enumerate() {
                leaves(v, format!("{at}/{i}"), out);
            }
        }
        serde_json::Value::Object(map) => {
            for (k, v) in map {
                leaves(v, format!("{at}/{k}"), out);
            }
        }
        _ => out.push(at),
    }
}

fn hostile() -> impl Strategy<Value = serde_json::Value> {
    use serde_json::json;
    prop_oneof![
        Just(json!(1e308)),
        Just(json!(-1e308)),
        Just(json!(1e39)),
        Just(json!(-1)),
        Just(json!(0)),
        Just(json!(u64::MAX)),
        Just(json!(null)),
        Just(json!([])),
        Just(json!({})),
        Just(json!("warp-drive")),
        Just(json!("x".repeat(100_000))),
        any::<f64>().prop_map(|v| json!(v)),
        any::<i64>().prop_map(|v| json!(v)),
        "\\PC{0,20}".prop_map(|s| json!(s)),
    ]
}

#[test]
fn the_model_file_reader_and_export_never_panic() {
    let text = std::fs::read_to_string(&super::untrusted::fixture().twin).unwrap();
    let value: serde_json::Value = serde_json::from_str(&text).unwrap();
    let mut paths = Vec::new();
    leaves(&value, String::new(), &mut paths);
    let n = paths.len();
    let replaced = proptest::collection::vec((0..n, hostile()), 1..4).prop_map(move |edits| {
        let mut v = value.clone();
        for (i, new) in edits {
            if let Some(slot) = v.pointer_mut(&paths[i]) {
                *slot = new;
            }
        }
        serde_json::to_string_pretty(&v).unwrap().into_bytes()
    });
    let model_text = prop_oneof![3 => replaced, 1 => mutated(text.into_bytes())];
    fuzz("model file", 128, 1.0, model_text, |bytes| {
        let Ok(text) = String::from_utf8(bytes) else { return };
        if let Ok(model) = sts_model::ModelFile::from_json(&text) {
            for language in ["c", "matlab", "sympy", "latex"] {
                let _ = sts_model::export::export(&model, language.parse().unwrap(), "t", "fuzz");
            }
        }
    });
}

#[test]
fn the_diagnosis_never_panics_on_values_at_the_bounds() {
    let f = super::untrusted::fixture();
    let data = sts_dataset::read(&f.data).unwrap();
    let model = sts_model::ModelFile::read(&f.twin).unwrap();
    let groups = data.groups.len();
    let rows = data.groups[0].len();
    let edit = (0..groups, 0..rows, 0usize..4, prop_oneof![Just(1e6), Just(-1e6), Just(1e5), Just(0.0), -1e3f64..1e3]);
    fuzz("diagnosis", 2, 1.0, proptest::collection::vec(edit, 1..4), |edits| {
        let mut d = data.clone();
        for (g, r, c, v) in edits {
            let group = &mut d.groups[g];
            let column = match c {
                0 => &mut group.z_tcp_um,
                1 => &mut group.z_enc_um,
                2 => &mut group.z_cmd_um,
                _ => &mut group.acc_mps2,
            };
            // acc_mps2's bound is 1e5.
            column[r] = if c == 3 { v.clamp(-1e5, 1e5) } else { v };
        }
        let _ = sts_assess::diagnose::diagnose(&d, &model);
    });
}
