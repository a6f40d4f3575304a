//! The default machine reproduces the paper; the dataset is the same bytes for the same seed;
//! the plant file is validated with errors naming the key.

use sts_emulator::measure::{run, run_to_dir};
use sts_emulator::paper::{format_table, paper_table};
use sts_emulator::{MeasureConfig, PlantParams, DEFAULT_PLANT_TOML};

#[test]
fn default_machine_reproduces_the_paper() {
    let rows = paper_table(&MeasureConfig::default()).unwrap();
    let table = format_table(&rows, false);
    for row in &rows {
        assert!(row.passes(), "out of tolerance:\n{table}");
    }
    assert_eq!(rows.iter().filter(|r| r.tolerance != sts_emulator::paper::Tolerance::None).count(), 8);
}

fn small_config(seed: u64) -> MeasureConfig {
    MeasureConfig {
        seed,
        freqs_hz: vec![5.0, 40.0],
        amps_um: vec![1.0, 11.0],
        duration_s: 1.0,
        effects: vec![
            "thermal-drift".parse().unwrap(),
            "coulomb-friction".parse().unwrap(),
            "axis-coupling:spindle_um=0.05".parse().unwrap(),
        ],
        ..MeasureConfig::default()
    }
}

fn dir_bytes(dir: &std::path::Path) -> Vec<(String, Vec<u8>)> {
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            (e.file_name().to_string_lossy().into_owned(), std::fs::read(e.path()).unwrap())
        })
        .collect();
    files.sort();
    files
}

#[test]
fn same_seed_same_bytes_whatever_the_threads() {
    let a = tempfile::tempdir().unwrap();
    let b = tempfile::tempdir().unwrap();
    let c = tempfile::tempdir().unwrap();
    let written = run_to_dir(&small_config(7), a.path(), &|_| {}).unwrap();
    let one_thread = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    one_thread.install(|| run_to_dir(&small_config(7), b.path(), &|_| {})).unwrap();
    run_to_dir(&small_config(8), c.path(), &|_| {}).unwrap();
    let (fa, fb, fc) = (dir_bytes(a.path()), dir_bytes(b.path()), dir_bytes(c.path()));
    assert_eq!(fa.len(), 5);
    assert_eq!(fa, fb, "same seed: same bytes");
    assert_ne!(fa[0].1, fc[0].1, "another seed: other noise");
    // In memory and written agree (within the writer's decimals).
    let mem = run(&small_config(7), &|_| {}).unwrap();
    let back = sts_dataset::read(a.path()).unwrap();
    assert_eq!(back.manifest, written);
    // The file's manifest adds each group file's rows and checksum.
    let unchecked: Vec<sts_dataset::GroupInfo> =
        written.groups.iter().map(|g| sts_dataset::GroupInfo { rows: None, crc32: None, ..g.clone() }).collect();
    assert_eq!(unchecked, mem.manifest.groups);
    assert!(written.groups.iter().all(|g| g.rows == Some(8000) && g.crc32.is_some()));
    for (x, y) in back.groups[3].z_tcp_um.iter().zip(&mem.groups[3].z_tcp_um) {
        assert!((x - y).abs() < 1e-5);
    }
    // The manifest does not name the effects used.
    let manifest = String::from_utf8(fa.iter().find(|f| f.0 == "manifest.json").unwrap().1.clone()).unwrap();
    for name in sts_model::Effect::ALL.map(sts_model::Effect::name) {
        assert!(!manifest.contains(name) && !manifest.contains(&name.replace('-', "_")), "{manifest}");
    }
}

#[test]
fn default_plant_file_is_the_default() {
    assert_eq!(PlantParams::from_toml_str(DEFAULT_PLANT_TOML).unwrap(), PlantParams::default());
    // Keys left out keep their defaults.
    let p = PlantParams::from_toml_str("[slide]\nmass_kg = 50.0\n").unwrap();
    assert_eq!(p.slide.mass_kg, 50.0);
    assert_eq!(p.servo, PlantParams::default().servo);
}

#[test]
fn bad_plant_values_name_the_key() {
    let err = |text: &str| PlantParams::from_toml_str(text).unwrap_err().to_string();
    assert!(err("[slide]\nmass_kg = -45.0\n").contains("`slide.mass_kg` = -45"));
    assert!(err("[structure]\nmode_damping = 1.2\n").contains("`structure.mode_damping`"));
    assert!(err("[structure]\nmode_damping = -0.1\n").contains("`structure.mode_damping`"));
    let unknown = err("[slide]\nmass = 45.0\n");
    assert!(unknown.contains("unknown field `mass`"), "{unknown}");
    let section = err("[slides]\nmass_kg = 45.0\n");
    assert!(section.contains("unknown field `slides`"), "{section}");
    let wrong_type = err("[servo]\nsubsteps = \"four\"\n");
    assert!(wrong_type.contains("substeps") || wrong_type.contains("invalid type"), "{wrong_type}");
    assert!(err("[accelerometer]\nlowpass_hz = 5000.0\n").contains("`accelerometer.lowpass_hz`"));
}

#[test]
fn accelerometer_range_resolves_small_and_holds_large_signals() {
    let p = PlantParams::default();
    // 40 Hz x 11 um with the mode's amplification, and 80 Hz, stay inside the range.
    let a40 = (2.0 * std::f64::consts::PI * 40.0_f64).powi(2) * 11e-6;
    assert!(p.acc_range_mps2() > 20.0 * a40);
    let a80 = (2.0 * std::f64::consts::PI * 80.0_f64).powi(2) * 11e-6;
    assert!(p.acc_range_mps2() > 8.0 * a80);
    // The LSB is below the 5 Hz x 1 um acceleration and about the noise.
    let a5 = (2.0 * std::f64::consts::PI * 5.0_f64).powi(2) * 1e-6;
    assert!(p.acc_mps2_per_lsb() < 2.0 * a5);
}

#[test]
fn lead_in_records_steady_motion_only() {
    let peak = |v: &[f64]| v.iter().fold(0.0f64, |m, a| m.max(a.abs()));
    let make = |lead_in_s: f64| MeasureConfig {
        freqs_hz: vec![40.0],
        amps_um: vec![11.0],
        duration_s: 2.0,
        lead_in_s,
        ..MeasureConfig::default()
    };
    let from_rest = sts_emulator::measure::simulate_group(&make(0.0), 0).unwrap();
    let running = sts_emulator::measure::simulate_group(&make(1.0), 0).unwrap();
    let (head, tail) = (0..800, 8000..16000);
    // From rest, the start (a velocity step) gives an acceleration spike well above the
    // steady peak; with a lead-in the first samples look like the rest.
    assert!(peak(&from_rest.acc_mps2[head.clone()]) > 1.5 * peak(&from_rest.acc_mps2[tail.clone()]));
    assert!(peak(&running.acc_mps2[head]) < 1.1 * peak(&running.acc_mps2[tail]));
    // Same command either way: starts at zero phase at t_s = 0.
    assert_eq!(from_rest.z_cmd_um, running.z_cmd_um);
    let groups = make(1.0).groups();
    assert_eq!(groups[0].start_s, 1.0);
}
