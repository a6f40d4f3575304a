//! `calibrate-offset` end to end with the firmware in QEMU: the offset measured through the
//! firmware, stored in its config store, reloaded after a reboot on the same bus file, and
//! switching compensation on at rest moving the axis by less than one motion pulse (by more
//! without the calibration); a corrupt store boots on safe defaults and is reported.

use std::path::Path;

use sts_hil_tests::BusPath;

use sts_hil::board::qemu::{CONFIG_OFFSET, CONFIG_SLOT_BYTES};
use sts_hil::HilConfig;
use sts_rig::calibrate::{
    calibrate, enable_check, Board, BootState, CalibrationConfig, HilBoard, Machine, PlantParams, RestRig,
};
use sts_rig::trial::stored_params;
use sts_rig::{expect_ack, Coprocessor, SimCoprocessor};
use sts_twin_core::feedforward::FeedforwardParams;
use sts_twin_core::wire::{frame_crc32, ConfigSource, Request};

fn boot(bus: &Path) -> HilBoard {
    HilBoard::start(HilConfig { bus_path: Some(bus.to_path_buf()), ..sts_hil_tests::twin_config() })
        .expect("the twin firmware boots in QEMU")
}

/// The board's A/B config store (see `sts_twin_board::config`): 32-byte header (magic,
/// generation, length, CRC of generation, length and blob), then the blob.
const RECORD_MAGIC: u32 = 0x4353_5453;
const HEADER_BYTES: usize = 32;

fn word(bytes: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap())
}

/// The byte offset in the bus file of the newest slot holding a record, and its blob length.
fn newest_slot(file: &[u8]) -> (usize, usize) {
    (0..2)
        .map(|slot| CONFIG_OFFSET + slot * CONFIG_SLOT_BYTES)
        .filter(|&at| word(file, at) == RECORD_MAGIC)
        .max_by_key(|&at| word(file, at + 4))
        .map(|at| (at, word(file, at + 8) as usize))
        .expect("the firmware wrote a record into its config store")
}

/// Flips one bit of the stored config record's payload; with `reseal` the store's own CRC
/// is recomputed, so that only the record's inner checks (its CRC) can catch it.
fn corrupt_store(bus: &Path, reseal: bool) {
    let mut file = std::fs::read(bus).unwrap();
    let (at, len) = newest_slot(&file);
    let blob = at + HEADER_BYTES;
    assert!(len > 12, "record of {len} bytes");
    file[blob + 10] ^= 0x20;
    if reseal {
        let mut sealed = Vec::new();
        sealed.extend_from_slice(&file[at + 4..at + 12]);
        sealed.extend_from_slice(&file[blob..blob + len]);
        file[at + 12..at + 16].copy_from_slice(&frame_crc32(&sealed).to_le_bytes());
    }
    std::fs::write(bus, &file).unwrap();
}

/// Calibrates in QEMU (the same steps as the command with short settings), reboots, then
/// switches compensation on at rest; the host core gives the same report bit for bit.
#[test]
fn calibration_in_qemu_is_stored_reloaded_and_enabling_moves_less_than_a_pulse() {
    let _serial = sts_hil_tests::serial();
    let bus = BusPath::new("calibrate");
    let plant = PlantParams::default();
    let config = CalibrationConfig::quick();
    let mut board = boot(&bus.0);
    let report = calibrate(&mut board, &plant, &[], 3, &config, &mut |_| {}).expect("the calibration runs");
    assert!(report.verified, "{report}");
    assert_eq!(report.boot_config_source, ConfigSource::Defaults, "a fresh bus file has an empty store");
    assert_eq!(report.config_source, ConfigSource::Stored, "{report}");
    assert!((report.offset_v - plant.interface.offset_v).abs() < 2e-4, "{report}");
    assert_eq!(report.offset.uncalibrated_pulses, 24.0, "{report}");
    assert!((report.k_dv_um_per_v - 2.0).abs() < 0.02, "{report}");
    assert_eq!(report.enable.added_pulses_max, 0, "{report}");
    assert!(report.enable.tcp_true_move_nm.abs() < plant.interface.pulse_nm, "{report}");

    // The host core, driven the same way, measures and stores the same, bit for bit.
    let mut sim = SimCoprocessor::boot(&[]);
    let sim_report = calibrate(&mut sim, &plant, &[], 3, &config, &mut |_| {}).unwrap();
    assert_eq!(sim_report.params, report.params);
    assert_eq!(sim_report.offset, report.offset);
    assert_eq!(sim_report.kdv, report.kdv);
    assert_eq!(sim_report.path, report.path);
    assert_eq!(sim_report.enable, report.enable);

    // Without the calibrated offset the same switch-on moves the axis by the interface's
    // 12 mV: 24 pulses of 1 nm.
    let uncalibrated = FeedforwardParams { offset_v: 0.0, ..report.params };
    expect_ack("params", board.request(Request::SetParams(uncalibrated)).unwrap()).unwrap();
    let mut machine = Machine::new(&plant, &[], 3).unwrap();
    let mut rig = RestRig::new(&mut board, &mut machine, 10.0, 0);
    let check =
        enable_check(&mut rig, plant.interface.pulse_nm, uncalibrated.enable_ramp_ticks, &config.enable).unwrap();
    assert_eq!(check.added_pulses_max, 24, "{check:?}");
    assert!(check.tcp_true_move_nm > 20.0 * plant.interface.pulse_nm, "{check:?}");
    assert!(!check.passed());

    // A cut later (`machine --bus`) boots on the same file and uses what was stored.
    board.reboot().unwrap();
    assert_eq!(stored_params(&mut board).unwrap(), report.params);
    board.shutdown().unwrap();
}

/// The firmware saves a calibration; one bit of the record flipped in the bus file, it boots
/// on safe defaults and says so (and counts it); bit rot the store itself catches leaves no
/// valid record, also on safe defaults.
#[test]
fn a_corrupt_config_store_boots_on_safe_defaults_and_is_reported() {
    let _serial = sts_hil_tests::serial();
    let bus = BusPath::new("corrupt");
    let calibrated = FeedforwardParams {
        offset_v: 0.0119,
        k_dv_um_per_v: 2.0,
        k_vc_pulses_per_v: 2000.0,
        ..FeedforwardParams::default()
    };
    let mut board = boot(&bus.0);
    expect_ack("params", board.request(Request::SetParams(calibrated)).unwrap()).unwrap();
    expect_ack("save", board.request(Request::SaveConfig).unwrap()).unwrap();
    board.reboot().unwrap();
    let state = BootState::read(&mut board).unwrap();
    assert_eq!(state.config_source, ConfigSource::Stored, "{state}");
    assert_eq!(state.params, calibrated);
    board.shutdown().unwrap();

    // The record's own CRC catches the flip.
    corrupt_store(&bus.0, true);
    let mut board = boot(&bus.0);
    let state = BootState::read(&mut board).unwrap();
    assert_eq!(state.config_source, ConfigSource::DefaultsAfterCorrupt, "{state}");
    assert_eq!(state.params, FeedforwardParams::default());
    assert!(!state.enabled);
    let text = state.to_string();
    assert!(text.contains("CORRUPT") && text.contains("safe defaults"), "{text}");
    let status = sts_rig::calibrate::rest::status(&mut board).unwrap();
    assert_eq!(status.counters.config_store_errors, 1);
    board.shutdown().unwrap();

    // Restore a valid record, then flip a bit without resealing: the A/B store's CRC
    // rejects the slot and there is no other record.
    let mut board = boot(&bus.0);
    expect_ack("params", board.request(Request::SetParams(calibrated)).unwrap()).unwrap();
    expect_ack("save", board.request(Request::SaveConfig).unwrap()).unwrap();
    board.shutdown().unwrap();
    let file = std::fs::read(&bus.0).unwrap();
    // Both slots now hold a record (the corrupt one and the new one): clear the older so
    // that the store has nothing to fall back to.
    let (newest, _) = newest_slot(&file);
    let older = if newest == CONFIG_OFFSET { CONFIG_OFFSET + CONFIG_SLOT_BYTES } else { CONFIG_OFFSET };
    let mut file = file;
    file[older..older + HEADER_BYTES].fill(0xFF);
    std::fs::write(&bus.0, &file).unwrap();
    corrupt_store(&bus.0, false);
    let mut board = boot(&bus.0);
    let state = BootState::read(&mut board).unwrap();
    assert_ne!(state.config_source, ConfigSource::Stored, "{state}");
    assert_eq!(state.params, FeedforwardParams::default());
    assert!(!state.enabled);
    // A cut asked to use the stored calibration refuses, and says what to run.
    let refused = stored_params(&mut board).unwrap_err().to_string();
    assert!(refused.contains("without a stored calibration") && refused.contains("calibrate-offset"), "{refused}");
    board.shutdown().unwrap();
}
