//! Round trip, and one test per kind of bad input: each error names file, line and column.

use std::path::Path;
use sts_dataset::{read, write, Dataset, DatasetError, GroupData, GroupInfo, Manifest};

fn sample_dataset(optional: bool) -> Dataset {
    let mut groups = Vec::new();
    let mut infos = Vec::new();
    for g in 0..3 {
        let n = 100 + g;
        let mut data = GroupData::with_len(n);
        for i in 0..n {
            let t = i as f64 / 8000.0;
            data.t_s[i] = t;
            data.z_cmd_um[i] = (g as f64 + 1.0) * (2.0 * std::f64::consts::PI * 5.0 * t).sin();
            data.z_enc_um[i] = (data.z_cmd_um[i] * 1000.0).round() / 1000.0;
            data.z_tcp_um[i] = data.z_cmd_um[i] * 1.01 - 0.003;
            data.acc_mps2[i] = -0.00059814 * (i as f64 - 50.0);
        }
        if optional {
            data.x_mm = Some((0..n).map(|i| 1.0 - i as f64 * 1e-4).collect());
            data.temp_c = Some(vec![20.0; n]);
        }
        groups.push(data);
        infos.push(GroupInfo::new(&format!("g{g:03}.csv"), 5.0, g as f64 + 1.0, 6.0 * g as f64));
    }
    let mut manifest = Manifest::new(8000.0, "test data", infos);
    manifest.acc_mps2_per_lsb = Some(0.00059814);
    Dataset { manifest, groups }
}

/// The sample dataset written, its manifest without rows and checksums (as a lab writes one
/// by hand): the tests below edit its group files to check each error of their values.
fn write_sample(dir: &Path) -> Dataset {
    let dataset = sample_dataset(true);
    write(dir, &dataset).unwrap();
    sts_dataset::write_manifest(dir, &dataset.manifest).unwrap();
    dataset
}

fn replace_in(path: &Path, from: &str, to: &str) {
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.contains(from), "{from:?} not in {}", path.display());
    std::fs::write(path, text.replacen(from, to, 1)).unwrap();
}

fn error_of(dir: &Path) -> (DatasetError, String) {
    let err = read(dir).expect_err("bad input must be rejected");
    let text = err.to_string();
    (err, text)
}

#[test]
fn round_trip_within_rounding() {
    let dir = tempfile::tempdir().unwrap();
    let written = write_sample(dir.path());
    let back = read(dir.path()).unwrap();
    assert_eq!(back.manifest, written.manifest);
    for (a, b) in back.groups.iter().zip(&written.groups) {
        assert_eq!(a.len(), b.len());
        assert!(a.x_mm.is_some() && a.temp_c.is_some() && a.spindle_deg.is_none());
        for (x, y) in a.z_tcp_um.iter().zip(&b.z_tcp_um) {
            assert!((x - y).abs() <= 0.5e-5 + 1e-12);
        }
        for (x, y) in a.acc_mps2.iter().zip(&b.acc_mps2) {
            assert!((x - y).abs() <= 0.5e-7 + 1e-12);
        }
    }
    // Written twice: the same bytes.
    let again = tempfile::tempdir().unwrap();
    write(again.path(), &written).unwrap();
    sts_dataset::write_manifest(again.path(), &written.manifest).unwrap();
    for name in ["manifest.json", "g000.csv", "g002.csv"] {
        assert_eq!(std::fs::read(dir.path().join(name)).unwrap(), std::fs::read(again.path().join(name)).unwrap());
    }
}

#[test]
fn crlf_bom_spaces_any_column_order_are_accepted() {
    let dir = tempfile::tempdir().unwrap();
    write_sample(dir.path());
    let csv = "\u{feff}acc_mps2, t_s ,z_tcp_um,z_enc_um,z_cmd_um\r\n0.1,0,1,2,3\r\n0.2,0.000125,1,2,3\r\n0.3, 0.00025 ,1,2,3\r\n\r\n";
    for g in 0..3 {
        std::fs::write(dir.path().join(format!("g{g:03}.csv")), csv).unwrap();
    }
    let back = read(dir.path()).unwrap();
    assert_eq!(back.groups[0].acc_mps2, vec![0.1, 0.2, 0.3]);
    assert_eq!(back.groups[0].z_cmd_um, vec![3.0; 3]);
    assert!(back.groups[0].x_mm.is_none());
}

#[test]
fn malformed_manifest_json_names_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    write_sample(dir.path());
    replace_in(&dir.path().join("manifest.json"), "\"sample_rate_hz\": 8000.0,", "\"sample_rate_hz\": 8000.0,,");
    let (err, text) = error_of(dir.path());
    assert!(matches!(err, DatasetError::Manifest { line: 3, .. }), "{text}");
    assert!(text.contains("manifest.json:3:"), "{text}");
}

#[test]
fn manifest_bad_fields_are_named() {
    let cases = [
        ("\"sts-twin-dataset/1\"", "\"sts-twin-dataset/2\"", "format"),
        ("\"sample_rate_hz\": 8000.0", "\"sample_rate_hz\": -8000.0", "positive"),
        ("\"freq_hz\": 5.0", "\"freq_hz\": \"five\"", "invalid type"),
        ("\"amp_um\": 1.0", "\"amplitude_um\": 1.0", "unknown field `amplitude_um`"),
        ("\"file\": \"g001.csv\"", "\"file\": \"../g001.csv\"", "plain file name"),
        ("\"file\": \"g001.csv\"", "\"file\": \"g000.csv\"", "listed twice"),
        ("\"start_s\": 0.0", "\"start_s_\": 0.0", "unknown field"),
    ];
    for (from, to, expect) in cases {
        let dir = tempfile::tempdir().unwrap();
        write_sample(dir.path());
        replace_in(&dir.path().join("manifest.json"), from, to);
        let (err, text) = error_of(dir.path());
        assert!(matches!(err, DatasetError::Manifest { line, column, .. } if line > 1 && column > 0), "{text}");
        assert!(text.contains(expect), "{to}: {text}");
    }
}

#[test]
fn missing_manifest_and_empty_groups() {
    let dir = tempfile::tempdir().unwrap();
    let (_, text) = error_of(dir.path());
    assert!(text.contains("manifest.json") && text.contains("not found"), "{text}");
    std::fs::write(
        dir.path().join("manifest.json"),
        "{\"format\": \"sts-twin-dataset/1\", \"sample_rate_hz\": 8000,\n \"groups\": []}",
    )
    .unwrap();
    let (_, text) = error_of(dir.path());
    assert!(text.contains("manifest.json:2:2") && text.contains("empty"), "{text}");
}

#[test]
fn missing_group_file() {
    let dir = tempfile::tempdir().unwrap();
    write_sample(dir.path());
    std::fs::remove_file(dir.path().join("g001.csv")).unwrap();
    let (err, text) = error_of(dir.path());
    assert!(matches!(err, DatasetError::MissingFile { group: 1, .. }), "{text}");
    assert!(text.contains("g001.csv"), "{text}");
}

#[test]
fn bad_headers() {
    let cases = [
        (
            "t_s,z_cmd_um,z_enc_um,z_tcp_um,acc_mps2,x_mm",
            "t_s,z_cmd_um,z_enc_um,z_tcp_um,acc_mps2,x_m",
            "unknown column \"x_m\"",
            41,
        ),
        (
            "t_s,z_cmd_um,z_enc_um,z_tcp_um,acc_mps2,x_mm",
            "t_s,z_cmd_um,z_enc_um,z_tcp_um,x_mm,x_mm",
            "appears twice",
            37,
        ),
        (
            "t_s,z_cmd_um,z_enc_um,z_tcp_um,acc_mps2,x_mm",
            "t_s,z_cmd_um,z_enc_um,z_tcp_um,x_mm",
            "required column `acc_mps2` missing",
            43,
        ),
    ];
    for (from, to, expect, column) in cases {
        let dir = tempfile::tempdir().unwrap();
        write_sample(dir.path());
        replace_in(&dir.path().join("g002.csv"), from, to);
        let (err, text) = error_of(dir.path());
        assert!(matches!(&err, DatasetError::BadHeader { line: 1, column: c, .. } if *c == column), "{text}");
        assert!(text.contains("g002.csv:1:") && text.contains(expect), "{text}");
    }
    let dir = tempfile::tempdir().unwrap();
    write_sample(dir.path());
    std::fs::write(dir.path().join("g000.csv"), "").unwrap();
    let (_, text) = error_of(dir.path());
    assert!(text.contains("g000.csv:1:1") && text.contains("empty file"), "{text}");
}

/// Overwrites the group file with a header and the given data rows.
fn with_rows(dir: &Path, rows: &[&str]) -> String {
    write_sample(dir);
    let mut text = String::from("t_s,z_cmd_um,z_enc_um,z_tcp_um,acc_mps2\n");
    for row in rows {
        text.push_str(row);
        text.push('\n');
    }
    std::fs::write(dir.join("g001.csv"), text).unwrap();
    read(dir).expect_err("bad rows must be rejected").to_string()
}

#[test]
fn non_numeric_value() {
    let dir = tempfile::tempdir().unwrap();
    let text = with_rows(dir.path(), &["0,1,2,3,4", "0.000125,1,2,abc,4", "0.00025,1,2,3,4"]);
    assert!(text.contains("g001.csv:3:14") && text.contains("`z_tcp_um`") && text.contains("\"abc\""), "{text}");
    let text = with_rows(dir.path(), &["0,1,2,3,4", "0.000125,1,NaN,3,4"]);
    assert!(text.contains("g001.csv:3:12") && text.contains("`z_enc_um`") && text.contains("finite"), "{text}");
    let text = with_rows(dir.path(), &["0,1,2,3,4", "0.000125,1,2,3,inf"]);
    assert!(text.contains("g001.csv:3:16") && text.contains("`acc_mps2`"), "{text}");
}

#[test]
fn missing_value() {
    let dir = tempfile::tempdir().unwrap();
    let text = with_rows(dir.path(), &["0,1,2,3,4", "0.000125,1,2,3"]);
    assert!(text.contains("g001.csv:3:15") && text.contains("`acc_mps2`") && text.contains("missing value"), "{text}");
    let text = with_rows(dir.path(), &["0,1,2,3,4", "0.000125,,2,3,4"]);
    assert!(text.contains("g001.csv:3:10") && text.contains("`z_cmd_um`") && text.contains("missing value"), "{text}");
    let text = with_rows(dir.path(), &["0,1,2,3,4", "", "0.00025,1,2,3,4"]);
    assert!(text.contains("g001.csv:3:1") && text.contains("missing value"), "{text}");
}

#[test]
fn extra_value() {
    let dir = tempfile::tempdir().unwrap();
    let text = with_rows(dir.path(), &["0,1,2,3,4", "0.000125,1,2,3,4,5"]);
    assert!(text.contains("g001.csv:3:18") && text.contains("extra value"), "{text}");
}

#[test]
fn non_uniform_time_step() {
    let dir = tempfile::tempdir().unwrap();
    let text = with_rows(dir.path(), &["0,1,2,3,4", "0.000125,1,2,3,4", "0.0003,1,2,3,4"]);
    assert!(text.contains("g001.csv:4:1") && text.contains("non-uniform time step"), "{text}");
    let text = with_rows(dir.path(), &["0,1,2,3,4", "0,1,2,3,4"]);
    assert!(text.contains("g001.csv:3:1") && text.contains("non-uniform"), "{text}");
}

#[test]
fn too_short_and_garbage_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let text = with_rows(dir.path(), &["0,1,2,3,4"]);
    assert!(text.contains("g001.csv") && text.contains("too few samples"), "{text}");
    // Arbitrary bytes: an error, never a panic.
    let junk: &[&[u8]] = &[
        b"\xff\xfe\x00,,,\n\n",
        b",,,,\n,,,,",
        b"t_s\n1",
        b"\n\n\n",
        b"t_s,z_cmd_um,z_enc_um,z_tcp_um,acc_mps2\n\xff,1,2,3,4\n",
    ];
    for bytes in junk {
        let result = sts_dataset::parse_group_csv(Path::new("junk.csv"), bytes, 8000.0);
        assert!(result.is_err());
    }
}

#[test]
fn writer_rejects_inconsistent_data() {
    let dir = tempfile::tempdir().unwrap();
    let mut dataset = sample_dataset(false);
    dataset.groups[1].z_tcp_um.pop();
    let err = write(dir.path(), &dataset).unwrap_err().to_string();
    assert!(err.contains("g001.csv") && err.contains("z_tcp_um"), "{err}");
    let mut dataset = sample_dataset(false);
    dataset.groups[0].acc_mps2[3] = f64::NAN;
    let err = write(dir.path(), &dataset).unwrap_err().to_string();
    assert!(err.contains("acc_mps2") && err.contains("not finite"), "{err}");
}
