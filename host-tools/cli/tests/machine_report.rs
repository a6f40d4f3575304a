//! `machine --sim --twin`: a sound cut says so. At the centre of a bicuspid cut the stroke
//! shrinks to nothing and the supervisor's gate fades compensation out, as designed; the
//! report gives the share of the cut's ticks it held off and states the gate as the state it
//! is, not as a fault.

use std::process::Command;

#[test]
fn a_sound_cut_reports_no_faults_and_the_gate_at_the_centre_apart() {
    let twin = concat!(env!("CARGO_MANIFEST_DIR"), "/../../hil-tests/fixtures/twin-default-machine.json");
    let out = Command::new(env!("CARGO_BIN_EXE_sts-twin"))
        .args(["machine", "--sim", "--freq", "40", "--twin", twin])
        .output()
        .expect("run sts-twin");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "machine failed: {stderr}");
    let summary = stdout
        .lines()
        .find_map(|l| l.strip_prefix("compensation over the cut's ticks: on "))
        .unwrap_or_else(|| panic!("no compensation summary:\n{stdout}"));
    let on_pct: f64 = summary.split('%').next().and_then(|v| v.parse().ok()).expect("a share");
    assert!(on_pct >= 95.0, "{summary}");
    assert!(summary.contains("held off") && summary.contains("the gate"), "{summary}");
    assert!(stderr.contains("co-processor (sim): no faults in "), "{stderr}");
    assert!(!stderr.lines().any(|l| l.starts_with("  - ")), "a fault listed: {stderr}");
    let gate = stderr.lines().find(|l| l.starts_with("co-processor (sim) now: ")).expect("the gate's state");
    assert!(gate.contains("supervisor's gate") && gate.contains("mostly noise at 40.0 Hz"), "{gate}");
}
