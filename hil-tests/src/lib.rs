//! Shared helpers of the HIL tests.

use sts_hil::{FirmwareVariant, HilConfig};
use sts_twin_core::bus::{InputSlot, IN_FLAG_PHASE_VALID};

/// A harness configuration that boots the bring-up application of the board seam (the
/// platform tests check the platform, not the twin).
pub fn bringup_config() -> HilConfig {
    HilConfig { variant: FirmwareVariant::BringUp, ..HilConfig::default() }
}

/// A harness configuration that boots the twin firmware.
pub fn twin_config() -> HilConfig {
    HilConfig::default()
}

/// A named bus file in the temporary directory, removed when the test ends.
pub struct BusPath(pub std::path::PathBuf);

impl BusPath {
    /// A fresh path whose file name holds `name`.
    pub fn new(name: &str) -> Self {
        let nanos =
            std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0);
        Self(std::env::temp_dir().join(format!("sts-twin-{name}-{}-{nanos}.bus", std::process::id())))
    }
}

impl Drop for BusPath {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// Runs the HIL tests of one test binary one at a time: each boots a QEMU whose guest spins
/// on the bus, and on a 2-core machine several at once starve the host side of the lockstep
/// (a stalled host is, rightly, counted as an underrun by the firmware). Hold the guard for
/// the whole test.
pub fn serial() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

/// Tick `k` of a recorded-like stream: a 40 Hz motion whose amplitude changes (0.3 Hz), with
/// deterministic pseudo-noise on the accelerometer code.
pub fn tone_input(k: u32) -> InputSlot {
    let t = k as f64 / 8000.0;
    let amp = 4000.0 + 2000.0 * (2.0 * std::f64::consts::PI * 0.3 * t).sin();
    let phase = 2.0 * std::f64::consts::PI * 40.0 * t;
    let noise = ((k.wrapping_mul(2_654_435_761) >> 16) % 9) as f64 - 4.0;
    InputSlot {
        tick: k,
        acc_code: (-amp * phase.sin() + noise).round() as i16,
        flags: IN_FLAG_PHASE_VALID,
        cmd_phase_turns: ((40.0 * t).fract() * 4_294_967_296.0) as u64 as u32,
        cmd_pos_nm: (3000.0 * phase.sin()) as i32,
        ..Default::default()
    }
}

/// The twin tests' common set-up: a short feature window, gentle ramps, a simple program.
pub mod twin {
    use sts_rig::{expect_ack, Coprocessor, HilCoprocessor};
    use sts_twin_core::features::FeatureConfig;
    use sts_twin_core::feedforward::FeedforwardParams;
    use sts_twin_core::program::{Program, ProgramBuilder, REG_AMP_UM, REG_PHASE_DEG};
    use sts_twin_core::supervisor::SupervisorParams;
    use sts_twin_core::wire::{Request, Response, Status};

    /// Feature window, samples: 0.25 s keeps model updates frequent in short runs.
    pub const WINDOW: u32 = 2000;
    /// Ticks over which the gain ramps between 0 and 1.
    pub const ENABLE_RAMP_TICKS: u32 = 400;

    /// The feature settings with [`WINDOW`].
    pub fn feature_config() -> FeatureConfig {
        FeatureConfig { window_samples: WINDOW, ..FeatureConfig::DEFAULT }
    }

    /// Feedforward parameters with [`ENABLE_RAMP_TICKS`] and a 0.05 V per tick slew limit.
    pub fn params() -> FeedforwardParams {
        FeedforwardParams {
            enable_ramp_ticks: ENABLE_RAMP_TICKS,
            slew_v_per_tick: 0.05,
            ..FeedforwardParams::default()
        }
    }

    /// amp = gain * RMS (um per m/s^2), phase = -0.2 * f1 degrees.
    pub fn program(id: u32, gain: f32) -> Program {
        let mut b = ProgramBuilder::new();
        b.id(id).constant(gain).feature(4).mul().store(REG_AMP_UM);
        b.constant(-0.2).feature(0).mul().store(REG_PHASE_DEG);
        b.finish().unwrap()
    }

    /// Boots the twin firmware in QEMU.
    pub fn boot() -> HilCoprocessor {
        HilCoprocessor::start(super::twin_config()).expect("the twin firmware boots in QEMU")
    }

    /// Sets the features and parameters above, uploads and activates `program` if given, and
    /// enables compensation. The supervisor is switched off: these streams are open loop
    /// (the accelerometer code does not see the DAC), so there is no machine for it to judge;
    /// `supervisor_hil.rs` tests it in the closed loop.
    pub fn configure(cop: &mut dyn Coprocessor, program: Option<Program>) {
        expect_ack("feature config", cop.request(Request::SetFeatureConfig(feature_config())).unwrap()).unwrap();
        expect_ack("params", cop.request(Request::SetParams(params())).unwrap()).unwrap();
        let off = SupervisorParams { active: false, ..SupervisorParams::default() };
        expect_ack("supervisor off", cop.request(Request::SetSupervisor(off)).unwrap()).unwrap();
        if let Some(program) = program {
            expect_ack("program", cop.request(Request::UploadProgram { program, activate: true }).unwrap()).unwrap();
        }
        expect_ack("enable", cop.request(Request::SetEnabled(true)).unwrap()).unwrap();
    }

    /// The co-processor's status.
    pub fn status(cop: &mut dyn Coprocessor) -> Status {
        match cop.request(Request::GetStatus).unwrap() {
            Response::Status(status) => status,
            other => panic!("unexpected answer {other:?}"),
        }
    }
}
