//! Emulator speed: simulated samples per second on one core, and wall time of the full
//! 99-group measurement test (in memory, and written to disk).
//!
//! Run: `cargo bench -p sts-emulator --bench throughput`
use std::time::Instant;

/// CPU time of this thread, s (unaffected by other processes competing for the cores).
fn thread_cpu_s() -> f64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes into the timespec we own.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}
use sts_emulator::measure::{run, run_to_dir, simulate_group};
use sts_emulator::{EffectSpec, Machine, MeasureConfig, PlantParams, StepInput};

/// CPU time of the whole process (all threads), s.
fn process_cpu_s() -> f64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes into the timespec we own.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

fn single_core(effects: &[EffectSpec], label: &str) {
    let params = PlantParams::default();
    let mut machine = Machine::new(&params, effects, 1).expect("machine");
    let n = 4_000_000usize;
    let w = 2.0 * std::f64::consts::PI * 40.0 / 8000.0;
    let start = Instant::now();
    let cpu0 = thread_cpu_s();
    let mut sink = 0.0;
    for k in 0..n {
        let out = machine.step(&StepInput {
            z_cmd_um: 5.0 * (w * k as f64).sin(),
            x_mm: 5.0,
            spindle_deg: 0.0,
            analog_in_v: 0.0,
            analog_enabled: false,
        });
        sink += out.z_tcp_um;
    }
    let secs = start.elapsed().as_secs_f64();
    let cpu = thread_cpu_s() - cpu0;
    println!(
        "one core, Machine::step, {label}: {:.2} M samples per CPU second ({:.2} M/s wall; {n} samples, substeps {}) [{sink:.1}]",
        n as f64 / cpu / 1e6,
        n as f64 / secs / 1e6,
        machine.substeps()
    );
}

fn main() {
    single_core(&[], "default machine");
    if std::env::args().any(|a| a == "--quick") {
        return;
    }
    for effect in sts_model::Effect::ALL {
        single_core(&[EffectSpec::new(effect)], effect.name());
    }

    let config = MeasureConfig::default();
    let cpu0 = thread_cpu_s();
    let group = simulate_group(&config, 50).expect("group");
    let cpu = thread_cpu_s() - cpu0;
    println!(
        "one core, one group with all dataset columns: {:.2} M samples per CPU second",
        group.len() as f64 / cpu / 1e6
    );

    let threads = rayon::current_num_threads();
    let start = Instant::now();
    let cpu0 = process_cpu_s();
    let dataset = run(&config, &|_| {}).expect("measure");
    let secs = start.elapsed().as_secs_f64();
    let cpu = process_cpu_s() - cpu0;
    println!(
        "full measurement test in memory ({} groups, {} samples, {threads} threads): {secs:.3} s wall, {cpu:.3} s CPU",
        dataset.groups.len(),
        dataset.total_samples()
    );
    drop(dataset);

    let dir = tempfile::tempdir().expect("tempdir");
    let start = Instant::now();
    let cpu0 = process_cpu_s();
    run_to_dir(&config, dir.path(), &|_| {}).expect("measure to dir");
    let secs = start.elapsed().as_secs_f64();
    let cpu = process_cpu_s() - cpu0;
    let bytes: u64 =
        std::fs::read_dir(dir.path()).expect("dir").filter_map(|e| e.ok()?.metadata().ok()).map(|m| m.len()).sum();
    println!(
        "full measurement test written to disk ({threads} threads): {secs:.3} s wall, {cpu:.3} s CPU, {:.0} MB",
        bytes as f64 / 1e6
    );

    let start = Instant::now();
    let cpu0 = process_cpu_s();
    let back = sts_dataset::read(dir.path()).expect("read");
    let secs = start.elapsed().as_secs_f64();
    let cpu = process_cpu_s() - cpu0;
    println!(
        "reading it back with sts_dataset::read: {secs:.3} s wall, {cpu:.3} s CPU ({} samples)",
        back.total_samples()
    );
}
