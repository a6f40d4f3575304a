//! The co-processor over a real tty: QEMU's UART as a pseudo-terminal (`-serial pty`), opened
//! with the serial-port code a lab's `sts-twin board --port` uses (`sts_link`): a twin
//! uploaded, parameters set, compensation enabled, all saved, the board rebooted and read
//! back; a failed upload and a reset in the middle of one leave the old twin in force; a line
//! that drops and corrupts frames loses no request; a board that stops answering is named by
//! its port.

use std::path::Path;
use std::time::{Duration, Instant};

use sts_hil::{Hil, HilConfig};
use sts_hil_tests::BusPath;
use sts_link::{Board, LinkError, LinkFaults, RetryPolicy, SerialLink, Transport, DEFAULT_BAUD};
use sts_model::ModelFile;
use sts_twin_core::program::Program;
use sts_twin_core::wire::{encode_frame, ConfigSource, Rejection, Request, Response, Status, MAX_ENCODED_FRAME};

fn boot(bus: &Path) -> Hil {
    Hil::start(HilConfig { bus_path: Some(bus.to_path_buf()), control_pty: true, ..sts_hil_tests::twin_config() })
        .expect("the twin firmware boots in QEMU with its UART on a pseudo-terminal")
}

fn connect(hil: &Hil) -> Board<SerialLink> {
    let pty = hil.control_pty().expect("a pseudo-terminal").to_str().unwrap().to_string();
    let port = SerialLink::open(&pty, DEFAULT_BAUD).expect("the pseudo-terminal opens");
    Board::connect(port, RetryPolicy::default()).expect("the handshake")
}

fn status(board: &mut Board<SerialLink>) -> Status {
    match board.request(Request::GetStatus).unwrap() {
        Response::Status(status) => status,
        other => panic!("GetStatus answered with {other:?}"),
    }
}

fn twin() -> ModelFile {
    ModelFile::read(&Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join("twin-default-machine.json"))
        .expect("the fixture twin")
}

/// What `sts-twin board upload` does: stage, set the features, activate.
fn upload(board: &mut Board<SerialLink>, model: &ModelFile) {
    let program = model.firmware_program().unwrap();
    board.expect_ack(Request::UploadProgram { program, activate: false }).unwrap();
    board.expect_ack(Request::SetFeatureConfig(model.feature_config)).unwrap();
    board.expect_ack(Request::ActivateStaged).unwrap();
}

#[test]
fn a_board_on_a_serial_line_keeps_its_twin_and_settings_across_a_reboot() {
    let _serial = sts_hil_tests::serial();
    let bus = BusPath::new("pty");
    let hil = boot(&bus.0);
    let mut board = connect(&hil);
    let fresh = status(&mut board);
    assert_eq!((fresh.program_id, fresh.config_source), (None, ConfigSource::Defaults));

    let model = twin();
    upload(&mut board, &model);
    let params = sts_twin_core::feedforward::FeedforwardParams { offset_v: 0.0125, k_dv_um_per_v: 2.5, ..fresh.params };
    board.expect_ack(Request::SetParams(params)).unwrap();
    board.expect_ack(Request::SetEnabled(true)).unwrap();
    board.expect_ack(Request::SaveConfig).unwrap();
    let saved = status(&mut board);
    let program_id = model.firmware_program().unwrap().id;
    assert_eq!(saved.program_id, Some(program_id));
    assert!(saved.enabled);

    // A malformed twin is refused and the one in force stays.
    let mut bad = model.firmware_program().unwrap();
    bad.version += 1;
    let answer = board.request(Request::UploadProgram { program: bad, activate: true }).unwrap();
    assert!(matches!(answer, Response::Rejected(Rejection::Program(_))), "{answer:?}");
    assert_eq!(status(&mut board).program_id, Some(program_id));

    drop(board);
    let hil = hil.reboot().expect("the reboot");
    let mut board = connect(&hil);
    let back = status(&mut board);
    assert_eq!(back.config_source, ConfigSource::Stored);
    assert_eq!(back.program_id, Some(program_id), "the saved twin is in force after the reboot");
    assert_eq!(back.params, params);
    assert_eq!(back.feature_config, model.feature_config);
    // Compensation is never on at power-up: the lab enables it when the machine is ready.
    assert!(!back.enabled);
    assert_eq!(back.counters.frame_errors, 0);
    drop(board);
    hil.shutdown().unwrap();
}

/// A twin program that validates, with its own id.
fn other_program(id: u32) -> Program {
    let mut program = sts_twin_core::program::paper_program();
    program.id = id;
    program
}

#[test]
fn a_reset_in_the_middle_of_an_upload_leaves_the_old_twin_in_force() {
    let _serial = sts_hil_tests::serial();
    let bus = BusPath::new("pty-reset");
    let hil = boot(&bus.0);
    let mut board = connect(&hil);
    board.expect_ack(Request::UploadProgram { program: other_program(7), activate: true }).unwrap();
    board.expect_ack(Request::SaveConfig).unwrap();

    // Half of a new upload's frame, then the board resets.
    let mut frame = [0u8; MAX_ENCODED_FRAME];
    let len =
        encode_frame(900, &Request::UploadProgram { program: other_program(8), activate: true }, &mut frame).unwrap();
    board.transport().write_all(&frame[..len / 2]).unwrap();
    drop(board);
    let hil = hil.reboot().expect("the reboot");
    let mut board = connect(&hil);
    let back = status(&mut board);
    assert_eq!((back.program_id, back.config_source), (Some(7), ConfigSource::Stored));
    drop(board);
    hil.shutdown().unwrap();
}

#[test]
fn a_line_that_drops_and_corrupts_frames_loses_no_request() {
    let _serial = sts_hil_tests::serial();
    let bus = BusPath::new("pty-noise");
    let hil = boot(&bus.0);
    let faults = LinkFaults { drop_probability: 0.15, corrupt_probability: 0.10 };
    let mut board = connect(&hil).with_faults(faults, faults, 11);
    for k in 0..30u32 {
        // Line noise between frames: bytes that are no frame at all.
        if k % 5 == 0 {
            board.transport().write_all(&[0x55, 0xAA, 0x13, 0x37, 0x00, 0xFF, 0x00]).unwrap();
        }
        board.expect_ack(Request::UploadProgram { program: other_program(100 + k), activate: true }).unwrap();
        assert_eq!(status(&mut board).program_id, Some(100 + k));
    }
    let stats = board.stats();
    assert_eq!(stats.requests, 60 + 1);
    assert!(stats.attempts > stats.requests + 5, "the faults cost retries: {stats:?}");
    drop(board);
    let mut clean = connect(&hil);
    let counters = status(&mut clean).counters;
    assert!(counters.frame_errors >= 6, "the noise and the corrupted frames are counted: {counters:?}");
    drop(clean);
    hil.shutdown().unwrap();
}

#[test]
fn a_board_that_stops_answering_is_named_by_its_port_and_a_second_opener_is_told_it_is_busy() {
    let _serial = sts_hil_tests::serial();
    let bus = BusPath::new("pty-silent");
    let hil = boot(&bus.0);
    let pty = hil.control_pty().unwrap().to_str().unwrap().to_string();
    // QEMU notices a pseudo-terminal's opener within a second; the handshake's retries span it.
    let mut board = connect(&hil);
    board.set_policy(RetryPolicy {
        first_timeout: Duration::from_millis(50),
        max_timeout: Duration::from_millis(200),
        attempts: 4,
    });

    let busy = SerialLink::open(&pty, DEFAULT_BAUD).err().expect("a second opener is refused");
    assert!(matches!(busy, LinkError::Busy { .. }), "{busy}");
    assert!(busy.to_string().contains(&pty), "{busy}");

    // The board's processor stops (a debugger halt, a crash with the UART dead).
    let pid = hil.qemu_pid().to_string();
    assert!(std::process::Command::new("kill").args(["-STOP", &pid]).status().unwrap().success());
    let started = Instant::now();
    let silent = board.request(Request::GetStatus).expect_err("no answer");
    let waited = started.elapsed();
    assert!(std::process::Command::new("kill").args(["-CONT", &pid]).status().unwrap().success());
    assert!(matches!(silent, LinkError::NoAnswer { attempts: 4, .. }), "{silent}");
    assert!(silent.to_string().contains(&pty) && silent.to_string().contains("GetStatus"), "{silent}");
    assert!(waited < Duration::from_secs(5), "gave up after {waited:?}");
    // Running again, it answers.
    assert!(matches!(board.request(Request::GetStatus).unwrap(), Response::Status(_)));

    let missing = SerialLink::open("/dev/sts-twin-no-such-port", DEFAULT_BAUD).err().unwrap();
    assert!(matches!(missing, LinkError::Missing { .. }), "{missing}");
    drop(board);
    hil.shutdown().unwrap();
}
