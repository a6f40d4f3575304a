//! `sts-twin board --port` as a lab runs it, against the twin firmware in QEMU with its UART
//! on a pseudo-terminal (`-serial pty`): status, upload, params, enable, save, a reboot and
//! the status read back; a missing port, a busy one and a twin the board refuses get clear
//! errors that name the port, and the refused twin changes nothing; `machine` on the RISC-V
//! board cuts as on the Cortex-M4F.
//! Needs the firmware ELF (`cargo xtask firmware`).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use sts_hil::{Hil, HilConfig};

fn sts_twin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_sts-twin")).args(args).output().expect("sts-twin runs")
}

fn ok(args: &[&str]) -> String {
    let out = sts_twin(args);
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(out.status.success(), "sts-twin {args:?} failed:\n{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    stdout
}

fn failing(args: &[&str]) -> String {
    let out = sts_twin(args);
    assert!(!out.status.success(), "sts-twin {args:?} should fail");
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(!stderr.contains("panicked"), "{stderr}");
    stderr
}

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../hil-tests/fixtures").join(name)
}

/// A bus file in the temporary directory (the board's flash across the reboot), removed at
/// the end.
struct BusFile(PathBuf);

impl Drop for BusFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// One board at a time: two boards stepping at once each share the cores with the other's
/// QEMU, and in a CI run the calibration's ticks then came too slowly for its settling check
/// (30 s for 200 ms of ticks).
fn one_board_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static BOARD: std::sync::Mutex<()> = std::sync::Mutex::new(());
    BOARD.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

fn boot(bus: &Path) -> Hil {
    Hil::start(HilConfig { bus_path: Some(bus.to_path_buf()), control_pty: true, ..HilConfig::default() })
        .expect("the twin firmware boots in QEMU (build it with `cargo xtask firmware`)")
}

#[test]
fn a_lab_uploads_sets_enables_and_saves_a_twin_on_a_board_on_a_serial_port() {
    let _board = one_board_at_a_time();
    let bus = BusFile(std::env::temp_dir().join(format!("sts-twin-board-cli-{}.bus", std::process::id())));
    let hil = boot(&bus.0);
    let pty = hil.control_pty().unwrap().to_str().unwrap().to_string();
    let port = ["--port", pty.as_str()];
    let with = |action: &[&str]| -> Vec<String> { action.iter().chain(&port).map(|s| s.to_string()).collect() };
    let run = |action: &[&str]| ok(&with(action).iter().map(String::as_str).collect::<Vec<_>>());
    let fail = |action: &[&str]| failing(&with(action).iter().map(String::as_str).collect::<Vec<_>>());

    let fresh = run(&["board", "status"]);
    assert!(
        fresh.contains("config: the co-processor found no calibration in its config store")
            && fresh.contains("no twin model is active"),
        "{fresh}"
    );

    let twin = fixture("twin-default-machine.json");
    let uploaded = run(&["board", "upload", twin.to_str().unwrap()]);
    assert!(uploaded.contains("active on serial port") && uploaded.contains(&pty), "{uploaded}");
    let params = run(&["board", "params", "--offset-v", "-0.0125", "--k-dv-um-per-v", "2.5"]);
    assert!(params.contains("K_dv 2.5 um/V") && params.contains("offset -0.0125 V"), "{params}");
    // The analogue-path table from a lab's CSV file; a malformed one names its line and
    // changes nothing.
    let table = std::env::temp_dir().join(format!("sts-twin-path-{}.csv", std::process::id()));
    std::fs::write(&table, "# measured by hand\nfreq_hz,gain,phase_deg\n10,1.0,-1.5\n40,0.98,-6.0\n80,,-12.5\n")
        .unwrap();
    let shown = run(&["board", "params", "--path", table.to_str().unwrap(), "--path-amp-um", "8"]);
    assert!(shown.contains("analogue path (3 points, measured with a 8 um sine)"), "{shown}");
    assert!(shown.contains("40.0 Hz  gain 0.9800, phase -6.000 deg") && shown.contains("gain not measured"), "{shown}");
    std::fs::write(&table, "freq_hz,gain,phase_deg\n10,1.0,-1.5\n40,0.98,minus six\n").unwrap();
    let bad = fail(&["board", "params", "--path", table.to_str().unwrap()]);
    assert!(bad.contains("sts-twin-path-") && bad.contains("line: 3"), "{bad}");
    std::fs::write(&table, "freq_hz,gain,phase_deg\n40,1.0,-1.5\n10,1.0,-6\n").unwrap();
    let unordered = fail(&["board", "params", "--path", table.to_str().unwrap()]);
    assert!(unordered.contains("strictly increasing"), "{unordered}");
    let _ = std::fs::remove_file(&table);
    assert!(run(&["board", "params"]).contains("analogue path (3 points"), "the bad tables changed nothing");
    assert!(run(&["board", "enable"]).contains("compensation enabled"));
    let saved = run(&["board", "save"]);
    assert!(saved.starts_with("saved:"), "{saved}");
    let watched = run(&["board", "watch", "--hz", "20", "--count", "3"]);
    assert_eq!(watched.lines().count(), 4, "a header and three lines: {watched}");
    assert!(watched.lines().nth(1).unwrap().contains(" on "), "{watched}");
    // The columns line up under the header, whatever the supervisor's state says.
    let ticks_end = watched.lines().next().unwrap().find("ticks").unwrap() + "ticks".len();
    for line in watched.lines().skip(1) {
        let (head, tail) = line.split_at(ticks_end);
        assert!(head.ends_with(|c: char| c.is_ascii_digit()) && tail.starts_with("  "), "{watched}");
    }

    // Refused: parameters out of range, and a twin that is not a twin. Nothing changes.
    let refused = fail(&["board", "params", "--k-dv-um-per-v", "0"]);
    assert!(refused.contains(&pty) && refused.contains("refused the parameters"), "{refused}");
    let not_a_twin = std::env::temp_dir().join(format!("sts-twin-not-a-twin-{}.json", std::process::id()));
    std::fs::write(&not_a_twin, "{\"format\": \"sts-twin model\"}").unwrap();
    let bad = fail(&["board", "upload", not_a_twin.to_str().unwrap()]);
    let _ = std::fs::remove_file(&not_a_twin);
    assert!(bad.contains("sts-twin-not-a-twin"), "names the file: {bad}");

    // Busy while another program holds the port.
    let holder = sts_link::SerialLink::open(&pty, sts_link::DEFAULT_BAUD).unwrap();
    let busy = fail(&["board", "status"]);
    assert!(busy.contains(&pty) && busy.contains("busy"), "{busy}");
    drop(holder);

    let hil = hil.reboot().expect("the reboot");
    let pty = hil.control_pty().unwrap().to_str().unwrap().to_string();
    let back = ok(&["board", "status", "--port", &pty]);
    assert!(back.contains("config: the co-processor loaded its stored calibration"), "{back}");
    assert!(back.contains("K_dv 2.5 um/V") && back.contains("offset -0.0125 V"), "{back}");
    assert!(back.contains("compensation: disabled") && !back.contains("program none"), "{back}");
    assert!(back.contains("analogue path (3 points"), "{back}");
    hil.shutdown().unwrap();

    let missing = failing(&["board", "status", "--port", "/dev/sts-twin-no-such-port"]);
    assert!(missing.contains("/dev/sts-twin-no-such-port: no such serial port"), "{missing}");
    let no_port = failing(&["board", "status"]);
    assert!(no_port.contains("--port DEV"), "{no_port}");
}

/// `calibrate-offset --port` with the lab's instruments as commands. The instruments are
/// emulated from the board's own DAC output, which the test publishes to a file while it
/// steps the board's ticks: a controller that reads 0.9 V per DAC volt plus 12.3 mV, and an
/// axis that moves the tool 2.25 um per volt read.
#[test]
fn calibrate_offset_on_a_serial_port_stores_what_the_labs_instruments_read() {
    let _board = one_board_at_a_time();
    let bus = BusFile(std::env::temp_dir().join(format!("sts-twin-board-cal-{}.bus", std::process::id())));
    let dac_file = BusFile(std::env::temp_dir().join(format!("sts-twin-board-cal-{}.dac", std::process::id())));
    let publish = |code: i16| {
        let tmp = dac_file.0.with_extension("tmp");
        std::fs::write(&tmp, format!("{code}\n")).unwrap();
        std::fs::rename(&tmp, &dac_file.0).unwrap();
    };
    publish(0);
    let mut hil = boot(&bus.0);
    let pty = hil.control_pty().unwrap().to_str().unwrap().to_string();
    let read_v = "0.9 * $1 * 10 / 32767 + 0.0123";
    let reading = format!("awk '{{ printf \"%.6f\\n\", {read_v} }}' {}", dac_file.0.display());
    let probe = format!("awk '{{ printf \"%.6f\\n\", 2.25 * ({read_v}) }}' {}", dac_file.0.display());
    let mut child = Command::new(env!("CARGO_BIN_EXE_sts-twin"))
        .args(["calibrate-offset", "--port", &pty, "--json", "--feedforward-on-cmd", "true"])
        .args(["--controller-reading-cmd", &reading, "--probe-cmd", &probe])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let started = std::time::Instant::now();
    let mut k = 0u32;
    while child.try_wait().unwrap().is_none() {
        assert!(started.elapsed() < std::time::Duration::from_secs(120), "calibrate-offset --port did not end");
        let output = hil.step(sts_twin_core::bus::InputSlot { tick: k, ..Default::default() }).unwrap();
        publish(output.dac_code);
        k += 1;
    }
    let out = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let offset_v = report["offset_v"].as_f64().unwrap();
    let k_dv = report["k_dv_um_per_v"].as_f64().unwrap();
    let code_v = 10.0 / 32767.0;
    assert!((offset_v - 0.0123 / 0.9).abs() < 2.0 * code_v, "offset {offset_v} V");
    assert!((k_dv - 2.25 * 0.9).abs() < 0.01 * 2.025, "K_dv {k_dv} um/V");

    let hil = hil.reboot().expect("the reboot");
    let pty = hil.control_pty().unwrap().to_str().unwrap().to_string();
    let back = ok(&["board", "status", "--port", &pty]);
    assert!(
        back.contains("config: the co-processor loaded its stored calibration")
            && back.contains(&format!("offset {} V", offset_v as f32)),
        "{back}"
    );
    hil.shutdown().unwrap();
}

/// `sts-twin machine --board riscv-virt --freq 40 --twin T` as a lab types it: the RISC-V
/// firmware (its own image, software floating point) cuts as the Cortex-M4F's does, the form
/// error and the phase equal bit for bit, each after its own calibration.
#[test]
fn machine_on_risc_v_prints_the_cortex_m4fs_form_error_and_phase() {
    let _board = one_board_at_a_time();
    let twin = fixture("twin-default-machine.json");
    let cut = |board: &str| -> serde_json::Value {
        let stdout = ok(&["machine", "--board", board, "--freq", "40", "--twin", twin.to_str().unwrap(), "--json"]);
        serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("--board {board}: {e}:\n{stdout}"))
    };
    let (m4f, riscv) = (cut("mps2-an386"), cut("riscv-virt"));
    for field in ["form_error_pv_um", "phase_error_deg"] {
        let (a, b) = (m4f[field].as_f64().unwrap(), riscv[field].as_f64().unwrap());
        assert_eq!(a.to_bits(), b.to_bits(), "{field}: Cortex-M4F {a}, RISC-V {b}");
    }
    assert!(m4f["form_error_pv_um"].as_f64().unwrap() < 0.2, "{m4f}");
    assert_eq!(riscv["fault_count"], 0, "{riscv}");
}
