//! Platform: no QEMU ever outlives its harness. A child process (this test binary, re-run
//! with an environment variable) starts the firmware and then dies in various ways; its
//! QEMU must be gone within a bounded time, on the Arm boards and on RISC-V. Also the timeout
//! path in-process.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use sts_hil::board::qemu::QemuBoard;
use sts_hil::{bench_inputs, live_qemu_pids, Hil, HilConfig, HilError};

const MODE_ENV: &str = "STS_HIL_ORPHAN_CHILD_MODE";
const GONE_WITHIN: Duration = Duration::from_secs(5);

/// Not a test of its own: the child's body when run with `MODE_ENV` set.
#[test]
fn orphan_child() {
    let _serial = sts_hil_tests::serial();
    let Ok(mode) = std::env::var(MODE_ENV) else { return };
    // `MODE-riscv`: the twin on QEMU RISC-V virt (another QEMU program) instead of the Arm bring-up.
    let (mode, config) = match mode.strip_suffix("-riscv") {
        Some(mode) => (mode.to_string(), HilConfig { board: QemuBoard::RiscvVirt, ..sts_hil_tests::twin_config() }),
        None => (mode, sts_hil_tests::bringup_config()),
    };
    let mut hil = Hil::start(config).expect("child boots the firmware");
    for input in bench_inputs(10) {
        hil.step(input).unwrap();
    }
    println!("QEMU_PID={}", hil.qemu_pid());
    match mode.as_str() {
        "panic" => panic!("the harness panics with QEMU running"),
        _ => std::thread::sleep(Duration::from_secs(120)),
    }
}

/// Starts the child in `mode`; returns it and its QEMU's pid.
fn child(mode: &str) -> (Child, u32) {
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args(["--exact", "platform_orphans::orphan_child", "--nocapture", "--test-threads=1"])
        .env(MODE_ENV, mode)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            // libtest may print "test orphan_child ... " before it on the same line.
            if let Some(pid) = line.split("QEMU_PID=").nth(1) {
                let _ = tx.send(pid.trim().parse::<u32>().unwrap());
            }
        }
    });
    match rx.recv_timeout(Duration::from_secs(120)) {
        Ok(pid) => (child, pid),
        Err(_) => {
            let _ = child.kill();
            let _ = child.wait();
            panic!("the child did not report its QEMU");
        }
    }
}

/// True while `pid` is a live (not zombie) QEMU.
fn qemu_alive(pid: u32) -> bool {
    let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else { return false };
    let state = stat.rsplit(')').next().and_then(|s| s.split_whitespace().next()).unwrap_or("");
    let cmdline = std::fs::read(format!("/proc/{pid}/cmdline")).unwrap_or_default();
    state != "Z" && state != "X" && String::from_utf8_lossy(&cmdline).contains("qemu-system")
}

/// Sends `signal` (a name such as `STOP`) with the system's `kill`.
fn send_signal(pid: u32, signal: &str) {
    let ok = Command::new("kill").args(["-s", signal, &pid.to_string()]).status().map(|s| s.success()).unwrap_or(false);
    assert!(ok, "kill -s {signal} {pid}");
}

/// Waits (bounded) until every thread of `pid` is in the stopped state.
fn wait_stopped(pid: u32) {
    let state = |stat: &str| stat.rsplit(')').next().and_then(|s| s.split_whitespace().next()).map(str::to_owned);
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let tasks = std::fs::read_dir(format!("/proc/{pid}/task")).unwrap();
        let all_stopped = tasks.flatten().all(|t| {
            let stat = std::fs::read_to_string(t.path().join("stat")).unwrap_or_default();
            matches!(state(&stat).as_deref(), Some("T") | Some("t"))
        });
        if all_stopped {
            return;
        }
        assert!(Instant::now() < deadline, "QEMU {pid} did not stop");
        std::thread::sleep(Duration::from_millis(1));
    }
}

fn assert_gone(pid: u32) {
    let deadline = Instant::now() + GONE_WITHIN;
    while qemu_alive(pid) {
        if Instant::now() >= deadline {
            send_signal(pid, "KILL");
            panic!("QEMU {pid} survived its harness");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn assert_no_bus_file_of(child_pid: u32) {
    let prefix = format!("sts-twin-bus-{child_pid}-");
    if let Ok(dir) = std::fs::read_dir("/dev/shm") {
        for entry in dir.flatten() {
            assert!(!entry.file_name().to_string_lossy().starts_with(&prefix), "left behind: {:?}", entry.path());
        }
    }
}

#[test]
fn sigkill_of_the_harness_process_takes_qemu_down() {
    let _serial = sts_hil_tests::serial();
    let (mut child, qemu) = child("sleep");
    assert!(qemu_alive(qemu));
    child.kill().unwrap(); // SIGKILL: no destructor, no handler runs
    child.wait().unwrap();
    assert_gone(qemu);
    assert_no_bus_file_of(child.id());
}

#[test]
fn a_panicking_harness_takes_qemu_down() {
    let _serial = sts_hil_tests::serial();
    let (mut child, qemu) = child("panic");
    let status = child.wait().unwrap();
    assert!(!status.success());
    assert_gone(qemu);
}

#[test]
fn sigint_and_sigterm_to_the_harness_take_qemu_down() {
    let _serial = sts_hil_tests::serial();
    for (signal, number) in [("INT", 2), ("TERM", 15)] {
        let (mut child, qemu) = child("sleep");
        send_signal(child.id(), signal);
        let status = child.wait().unwrap();
        assert_eq!(status.code(), Some(128 + number), "the handler exits with 128 + signal");
        assert_gone(qemu);
    }
}

/// The same exits with `qemu-system-riscv32`: SIGKILL, a panic and SIGTERM.
#[test]
fn every_exit_of_a_risc_v_harness_takes_its_qemu_down() {
    let _serial = sts_hil_tests::serial();
    let (mut harness, qemu) = child("sleep-riscv");
    harness.kill().unwrap();
    harness.wait().unwrap();
    assert_gone(qemu);
    assert_no_bus_file_of(harness.id());
    let (mut harness, qemu) = child("panic-riscv");
    assert!(!harness.wait().unwrap().success());
    assert_gone(qemu);
    let (mut harness, qemu) = child("sleep-riscv");
    send_signal(harness.id(), "TERM");
    assert_eq!(harness.wait().unwrap().code(), Some(128 + 15), "the handler exits with 128 + signal");
    assert_gone(qemu);
}

#[test]
fn a_tick_timeout_errors_out_and_drop_takes_qemu_down() {
    let _serial = sts_hil_tests::serial();
    let config = HilConfig { tick_timeout: Duration::from_millis(500), ..sts_hil_tests::bringup_config() };
    let mut hil = Hil::start(config).expect("boot");
    let qemu = hil.qemu_pid();
    // Freeze QEMU: the next tick can never complete. The stop reaches a thread running on
    // another core a moment later; wait until every thread is stopped.
    send_signal(qemu, "STOP");
    wait_stopped(qemu);
    let started = Instant::now();
    let err = hil.step(Default::default()).unwrap_err();
    assert!(matches!(err, HilError::Timeout { .. }), "{err}");
    assert!(started.elapsed() < Duration::from_secs(5));
    drop(hil);
    assert_gone(qemu);
    assert!(!live_qemu_pids().contains(&qemu));
}
