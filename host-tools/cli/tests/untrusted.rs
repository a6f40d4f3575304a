//! A lab's data against an adversarial user: outputs that would overwrite a dataset or an
//! input are refused, a dataset killed part-way through its rewrite stays whole, a mixed or
//! truncated dataset and values no sensor produces are refused naming the file, and no such
//! input panics a command. One small dataset (8 groups, 2 s to make) and its twin serve all.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

fn sts_twin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_sts-twin")).args(args).output().expect("sts-twin runs")
}

fn s(p: &Path) -> &str {
    p.to_str().expect("a UTF-8 path")
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// The command failed with a message (exit code 1, not a panic's 101) holding every `needle`.
#[track_caller]
fn refused(out: &Output, needles: &[&str]) {
    let text = stderr(out);
    assert_eq!(out.status.code(), Some(1), "expected a refusal, got {:?}: {text}", out.status);
    assert!(!text.contains("panicked"), "{text}");
    for needle in needles {
        assert!(text.contains(needle), "{needle:?} not in: {text}");
    }
}

/// Every file of a directory, by name.
fn contents(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir)
        .expect("a directory")
        .map(|e| {
            let e = e.expect("an entry");
            (e.file_name().to_string_lossy().into_owned(), std::fs::read(e.path()).expect("readable"))
        })
        .collect()
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("a directory");
    for (name, bytes) in contents(from) {
        std::fs::write(to.join(name), bytes).expect("written");
    }
}

/// The shared dataset (`data`, 8 groups) and its twin (`twin.json`), made once.
pub struct Fixture {
    _dir: tempfile::TempDir,
    /// The dataset.
    pub data: PathBuf,
    /// Its twin.
    pub twin: PathBuf,
}

/// The shared dataset and twin.
pub fn fixture() -> &'static Fixture {
    static FIXTURE: OnceLock<Fixture> = OnceLock::new();
    FIXTURE.get_or_init(|| {
        let dir = tempfile::tempdir().expect("a temporary directory");
        let data = dir.path().join("data");
        let twin = dir.path().join("twin.json");
        let out = sts_twin(&["measure", "--out", s(&data), "--freqs", "5,10,20,30", "--amps", "1,5", "--quiet"]);
        assert!(out.status.success(), "{}", stderr(&out));
        let out = sts_twin(&["fit", s(&data), "--out", s(&twin), "--epochs", "3", "--quiet"]);
        assert!(out.status.success(), "{}", stderr(&out));
        Fixture { _dir: dir, data, twin }
    })
}

/// A private copy of the shared dataset in `dir`.
fn data_copy(dir: &Path) -> PathBuf {
    let data = dir.join("data");
    copy_dir(&fixture().data, &data);
    data
}

/// A manifest without the rows and checksums (as a lab writes one by hand, or edits a group
/// file and says so): then only the values are checked.
fn forget_checksums(data: &Path) {
    let path = data.join("manifest.json");
    let mut manifest: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    for g in manifest["groups"].as_array_mut().unwrap() {
        let g = g.as_object_mut().unwrap();
        g.remove("rows");
        g.remove("crc32");
    }
    std::fs::write(&path, serde_json::to_string_pretty(&manifest).unwrap()).unwrap();
}

/// Sets `column` at data row `row` (1-based, the header is line 1) of a group file.
fn set_value(file: &Path, row: usize, column: &str, text: &str) {
    let body = std::fs::read_to_string(file).unwrap();
    let mut lines: Vec<String> = body.lines().map(str::to_string).collect();
    let index = lines[0].split(',').position(|c| c == column).unwrap();
    let mut fields: Vec<String> = lines[row].split(',').map(str::to_string).collect();
    fields[index] = text.to_string();
    lines[row] = fields.join(",");
    std::fs::write(file, lines.join("\n") + "\n").unwrap();
}

#[test]
fn a_measurement_killed_part_way_leaves_the_old_dataset_whole() {
    let dir = tempfile::tempdir().unwrap();
    let data = data_copy(dir.path());
    let before = contents(&data);
    // 88 groups take seconds: killed (SIGKILL) once some group files are written.
    let mut child = Command::new(env!("CARGO_BIN_EXE_sts-twin"))
        .args(["measure", "--out", s(&data), "--force", "--seed", "5", "--effect", "coulomb-friction", "--quiet"])
        .args(["--freqs", "5,10,15,20,25,30,35,40", "--amps", "1,2,3,4,5,6,7,8,9,10,11"])
        .spawn()
        .expect("sts-twin runs");
    let started = std::time::Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            panic!("the measurement ended before it was killed ({status})");
        }
        let written_beside = std::fs::read_dir(dir.path()).unwrap().flatten().any(|e| {
            e.file_name().to_string_lossy().starts_with(".data.partial")
                && std::fs::read_dir(e.path()).is_ok_and(|mut d| d.next().is_some())
        });
        if written_beside || contents(&data) != before || started.elapsed().as_secs() > 10 {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.kill().expect("killed");
    child.wait().expect("ended");
    assert!(contents(&data) == before, "the dataset changed under a killed measurement");
    let read = sts_dataset::read(&data).expect("the old dataset reads");
    assert_eq!(read.groups.len(), 8);
    // The next measurement into it removes what the killed one left beside it.
    let left_behind = || {
        std::fs::read_dir(dir.path()).unwrap().flatten().any(|e| e.file_name().to_string_lossy().starts_with(".data."))
    };
    assert!(left_behind(), "the killed measurement left no staging directory to clear");
    let out = Command::new(env!("CARGO_BIN_EXE_sts-twin"))
        .args(["measure", "--out", s(&data), "--force", "--freqs", "10", "--amps", "1", "--quiet"])
        .output()
        .expect("sts-twin runs");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(!left_behind(), "a killed measurement's staging directory outlived the next measurement");
}

#[test]
fn outputs_onto_a_dataset_an_input_or_an_existing_file_are_refused() {
    let f = fixture();
    let dir = tempfile::tempdir().unwrap();
    let data = data_copy(dir.path());
    let before = contents(&data);
    let twin = s(&f.twin);
    let manifest = data.join("manifest.json");
    let group = data.join("g003.csv");
    let inside = data.join("t.json");
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["measure", "--out", s(&data), "--freqs", "10", "--amps", "1", "--quiet"], "holds a dataset (--force"),
        (vec!["import", twin, "--out", s(&data), "--quiet"], "holds a dataset (--force"),
        (vec!["import", s(&group), "--out", s(&data), "--quiet", "--force"], "an input of this command"),
        (vec!["fit", s(&data), "--out", s(&manifest), "--force"], "an input of this command"),
        (vec!["compare", s(&data), "--model", twin, "--html", s(&group), "--force"], "an input of this command"),
        (vec!["export", twin, "--to", "c", "--out", s(&manifest), "--force"], "a dataset is written only as a whole"),
        (vec!["export", twin, "--to", "c", "--out", twin, "--force"], "an input of this command"),
        (vec!["explain", s(&data), "--out", s(&inside)], "an input of this command"),
    ];
    for (args, why) in &cases {
        refused(&sts_twin(args), &[why]);
        assert!(contents(&data) == before, "sts-twin {} changed the dataset", args.join(" "));
    }
    // An existing file only with --force, written whole.
    let notes = dir.path().join("notes.h");
    std::fs::write(&notes, "a lab's notes").unwrap();
    refused(&sts_twin(&["export", twin, "--to", "c", "--out", s(&notes)]), &["notes.h", "already exists (--force"]);
    assert_eq!(std::fs::read_to_string(&notes).unwrap(), "a lab's notes");
    let out = sts_twin(&["export", twin, "--to", "c", "--out", s(&notes), "--force"]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(std::fs::read_to_string(&notes).unwrap().contains("#ifndef STS_TWIN_H"));
    let leftovers: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
}

#[test]
fn a_mixed_or_truncated_dataset_is_refused_by_every_reader() {
    let f = fixture();
    let dir = tempfile::tempdir().unwrap();
    // Group 3 from another run of the same shape (another seed): only the checksum tells.
    let other = dir.path().join("other");
    let out =
        sts_twin(&["measure", "--out", s(&other), "--freqs", "5,10,20,30", "--amps", "1,5", "--seed", "9", "--quiet"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let mixed = dir.path().join("mixed");
    copy_dir(&f.data, &mixed);
    std::fs::copy(other.join("g003.csv"), mixed.join("g003.csv")).unwrap();
    // Group 5 cut short, as a copy interrupted.
    let cut = dir.path().join("cut");
    copy_dir(&f.data, &cut);
    let bytes = std::fs::read(cut.join("g005.csv")).unwrap();
    let end = bytes[..bytes.len() / 2].iter().rposition(|&b| b == b'\n').unwrap() + 1;
    std::fs::write(cut.join("g005.csv"), &bytes[..end]).unwrap();
    let twin = s(&f.twin);
    for (data, file) in [(&mixed, "g003.csv"), (&cut, "g005.csv")] {
        let d = s(data);
        let dest = dir.path().join("t.json");
        for args in [
            vec!["fit", d, "--out", s(&dest), "--epochs", "1", "--quiet"],
            vec!["compare", d, "--model", twin],
            vec!["diagnose", d, "--model", twin],
        ] {
            refused(&sts_twin(&args), &[file, "not the file the manifest describes"]);
        }
    }
    let text = stderr(&sts_twin(&["diagnose", s(&cut), "--model", twin]));
    assert!(text.contains("data rows where the manifest says 48000"), "{text}");
}

#[test]
fn values_no_sensor_produces_are_refused_with_file_line_and_column() {
    let f = fixture();
    let dir = tempfile::tempdir().unwrap();
    let twin = s(&f.twin);
    for (column, at) in [("z_tcp_um", "g003.csv:47999:"), ("acc_mps2", "g003.csv:47999:")] {
        let data = dir.path().join(column);
        copy_dir(&f.data, &data);
        forget_checksums(&data);
        set_value(&data.join("g003.csv"), 47998, column, "1e308");
        let d = s(&data);
        let dest = dir.path().join(format!("{column}.json"));
        for args in [
            vec!["fit", d, "--out", s(&dest), "--epochs", "1", "--quiet"],
            vec!["compare", d, "--model", twin],
            vec!["diagnose", d, "--model", twin],
            vec!["explain", d, "--out", s(&dest), "--epochs", "1", "--max-effects", "1"],
        ] {
            refused(&sts_twin(&args), &[at, column, "1e308 is beyond what the sensor can produce"]);
        }
    }
    // Not finite, and beyond the temperature's bound.
    let data = dir.path().join("nan");
    copy_dir(&f.data, &data);
    forget_checksums(&data);
    set_value(&data.join("g001.csv"), 10, "z_enc_um", "NaN");
    set_value(&data.join("g002.csv"), 10, "temp_c", "-300");
    refused(&sts_twin(&["diagnose", s(&data), "--model", twin]), &["g001.csv:11:", "z_enc_um", "not a finite number"]);
    set_value(&data.join("g001.csv"), 10, "z_enc_um", "0.5");
    refused(&sts_twin(&["diagnose", s(&data), "--model", twin]), &["g002.csv:11:", "temp_c", "-3e2 is beyond"]);
}

#[test]
fn a_recording_with_an_impossible_value_or_a_doubled_column_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec.csv");
    let row = |k: usize, probe: &str| format!("{},0,0,{probe},0\n", k as f64 / 8000.0);
    let mut text = String::from("t_s,z_cmd_um,z_enc_um,z_tcp_um,acc_mps2\n");
    for k in 0..20 {
        text += &row(k, if k == 7 { "1e308" } else { "0" });
    }
    std::fs::write(&rec, &text).unwrap();
    let out = dir.path().join("data");
    refused(&sts_twin(&["import", s(&rec), "--out", s(&out), "--quiet"]), &["rec.csv:9", "z_tcp_um", "beyond"]);
    assert!(!out.exists(), "a refused import left {}", out.display());
    std::fs::write(&rec, text.replacen("z_tcp_um,acc_mps2", "z_tcp_um,z_tcp_um", 1)).unwrap();
    refused(
        &sts_twin(&["import", s(&rec), "--out", s(&out), "--quiet"]),
        &["rec.csv:1", "names it 2 times (columns 4, 5)"],
    );
    let map = dir.path().join("map.toml");
    let mapping = "sample_rate_hz = -8000\n[channels]\ntime = { name = \"t_s\", unit = \"s\" }\ncommand = { name = \"z_cmd_um\", unit = \"um\" }\nencoder = { name = \"z_enc_um\", unit = \"um\" }\nprobe = { name = \"z_tcp_um\", unit = \"um\" }\naccelerometer = { name = \"acc_mps2\", unit = \"m/s^2\" }\n";
    std::fs::write(&map, mapping).unwrap();
    refused(
        &sts_twin(&["import", s(&rec), "--out", s(&out), "--map", s(&map), "--quiet"]),
        &["sample_rate_hz: must be a positive"],
    );
    let help = String::from_utf8(sts_twin(&["import", "--help"]).stdout).unwrap();
    for format in ["CSV", "TSV", "MATLAB", "TDMS", "HDF5"] {
        assert!(help.contains(format), "`import --help` does not name {format}");
    }
}

#[test]
fn a_model_file_with_an_unknown_effect_or_a_huge_string_is_refused() {
    let f = fixture();
    let dir = tempfile::tempdir().unwrap();
    let mut model: serde_json::Value = serde_json::from_slice(&std::fs::read(&f.twin).unwrap()).unwrap();
    let path = dir.path().join("m.json");
    model["effects"] = serde_json::json!([{"effect": "warp-drive", "params": [], "terms": 0, "note": ""}]);
    std::fs::write(&path, serde_json::to_string(&model).unwrap()).unwrap();
    refused(&sts_twin(&["compare", s(&f.data), "--model", s(&path)]), &["m.json", "effects[0].effect", "warp-drive"]);
    model.as_object_mut().unwrap().remove("effects");
    model["description"] = serde_json::Value::String("x".repeat(1 << 20));
    std::fs::write(&path, serde_json::to_string(&model).unwrap()).unwrap();
    let html = dir.path().join("r.html");
    refused(&sts_twin(&["compare", s(&f.data), "--model", s(&path), "--html", s(&html)]), &["m.json", "`description`"]);
    assert!(!html.exists());
    // A constant beyond float in the C header's float functions.
    let mut m = sts_model::ModelFile::read(&f.twin).unwrap();
    m.amplitude.expr = sts_symreg::Expr::Const(1e39);
    let error = sts_model::export::export(&m, sts_model::export::ExportLanguage::C, "t", "o").unwrap_err();
    assert!(error.to_string().contains("overflows the float functions"), "{error}");
}

#[test]
fn an_operating_system_error_is_said_once() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("afile");
    std::fs::write(&file, "").unwrap();
    let out = sts_twin(&["measure", "--out", s(&file.join("x")), "--freqs", "10", "--amps", "1", "--quiet"]);
    let text = stderr(&out);
    assert_eq!(text.matches("os error").count(), 1, "{text}");
}
