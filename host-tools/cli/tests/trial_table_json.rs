//! `trial-table --json` without `--twin` measures and fits a twin first; its stdout must still
//! be the JSON alone (the fit's formulas and the progress go to stderr), so that a script can
//! read it.

use std::process::Command;

#[test]
fn trial_table_json_prints_json_only() {
    let dir =
        std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("trial-table-json-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let twin = dir.join("twin.json");
    let out = Command::new(env!("CARGO_BIN_EXE_sts-twin"))
        .args(["trial-table", "--sim", "--json", "--freqs", "40", "--out"])
        .arg(&twin)
        .output()
        .expect("run sts-twin");
    let _ = std::fs::remove_dir_all(&dir);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "trial-table failed: {stderr}");
    let rows: serde_json::Value =
        serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("stdout is not JSON ({e}):\n{stdout}"));
    let rows = rows.as_array().expect("an array of rows");
    assert_eq!(rows.len(), 1);
    assert_eq!(rows[0]["twin"]["freq_hz"].as_f64(), Some(40.0));
    assert!(rows[0]["reduction_pct"].as_f64().is_some_and(|r| r > 90.0), "{}", rows[0]);
    // What the fit printed went to stderr.
    assert!(stderr.contains("amplitude (um) = "), "{stderr}");
}
