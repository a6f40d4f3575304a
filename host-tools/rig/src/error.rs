//! Errors of the closed loop, the co-processor, the calibration and the trials.

use sts_emulator::MachineError;
use sts_hil::HilError;
use sts_model::ModelError;
use sts_twin_core::analogue_path::{PathError, PATH_POINTS};
use sts_twin_core::feedforward::{FeedforwardParams, ParamError};
use sts_twin_core::program::ProgramError;
use sts_twin_core::wire::{ConfigSource, FrameError, Request, Response};

/// Why the rig could not run the co-processor, calibrate it or run a trial.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RigError {
    /// The HIL harness failed (QEMU, the bus, the control link).
    #[error(transparent)]
    Hil(#[from] HilError),
    /// The firmware could not be started under QEMU.
    #[error("cannot start the firmware under QEMU")]
    Start(#[source] HilError),
    /// QEMU could not be stopped cleanly.
    #[error("stopping QEMU")]
    Stop(#[source] HilError),
    /// The firmware could not be rebooted under QEMU.
    #[error("rebooting the firmware under QEMU")]
    Reboot(#[source] HilError),
    /// The lab calibration cannot go on.
    #[error("the calibration cannot go on: {reason}")]
    LabSettings {
        /// Why.
        reason: &'static str,
    },
    /// A lab instrument (the operator, or the lab's command) gave no usable reading.
    #[error("{instrument}: {detail}")]
    Instrument {
        /// Which reading, and from where.
        instrument: String,
        /// What went wrong.
        detail: String,
    },
    /// The control link to a board on a serial port failed.
    #[error(transparent)]
    Link(#[from] sts_link::LinkError),
    /// A board on a serial port runs its own ticks.
    #[error("{port}: a board on a serial port runs its servo ticks on its own timer; the host cannot step it (use the firmware in QEMU for a simulated cut)")]
    NotTickable {
        /// The port.
        port: String,
    },
    /// The board is not running: an earlier reboot failed.
    #[error("the co-processor is not running ({reason})")]
    NotRunning {
        /// What happened before.
        reason: &'static str,
    },
    /// The emulated machine could not be built.
    #[error(transparent)]
    Machine(#[from] MachineError),
    /// The model's firmware program could not be decoded.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// A request does not fit a control frame.
    #[error("cannot encode {request:?}: {error}")]
    Encode {
        /// The request.
        request: Box<Request>,
        /// Why (part of the message).
        error: FrameError,
    },
    /// The firmware did not answer a request.
    #[error("the firmware sent no answer to {request:?} (sequence {seq})")]
    NoAnswer {
        /// The request.
        request: Box<Request>,
        /// Its sequence number.
        seq: u16,
    },
    /// No answer to a request over the lossy link, however often it was sent.
    #[error("no answer to {request:?} after {attempts} attempts over the lossy link")]
    NoAnswerLossy {
        /// The request.
        request: Box<Request>,
        /// The attempts made.
        attempts: u32,
    },
    /// The co-processor did not acknowledge a request.
    #[error("the co-processor refused {what}: {response:?}")]
    Refused {
        /// What was asked.
        what: String,
        /// Its response.
        response: Box<Response>,
    },
    /// The co-processor answered a request with something else than asked for.
    #[error("the co-processor answered {request} with {response:?}")]
    Unexpected {
        /// The request ("its status request", "SaveConfig").
        request: &'static str,
        /// Its response.
        response: Box<Response>,
    },
    /// The co-processor booted without a stored calibration.
    #[error("the co-processor booted without a stored calibration ({config_source:?}); calibrate first: sts-twin calibrate-offset --bus FILE")]
    NotCalibrated {
        /// Where its configuration came from.
        config_source: ConfigSource,
    },
    /// No point of a trial's cut lies within the evaluated radius.
    #[error("no point of the cut lies within r <= {r_eval_mm} mm")]
    NoCutPoints {
        /// The evaluated radius, mm.
        r_eval_mm: f64,
    },
    /// The enable check's times are not positive.
    #[error("the enable check's settling and window times must be positive")]
    EnableTimes,
    /// Too few K_dv voltages.
    #[error("the K_dv fit needs at least three voltages, not {count}")]
    KdvVoltageCount {
        /// The voltages given.
        count: usize,
    },
    /// A K_dv voltage beyond the DAC's range about the offset.
    #[error("a K_dv voltage of {volts} V is beyond the DAC's range about the offset ({limit_v:.3} V)")]
    KdvVoltageRange {
        /// The voltage.
        volts: f64,
        /// The largest allowed, V.
        limit_v: f64,
    },
    /// The K_dv times are not positive.
    #[error("the K_dv settling and averaging times must be positive")]
    KdvTimes,
    /// The K_dv voltages do not determine the fit.
    #[error("the K_dv voltages cannot separate slope, offset and drift: use at least three distinct voltages, not in time order")]
    KdvSingular,
    /// The axis did not follow the analogue input.
    #[error("the axis hardly moved with the analogue input ({k_dv_um_per_v:.5} um/V, span {span_um:.4} um, residual {residual_um:.4} um): is the controller's analogue feedforward on?")]
    AxisDidNotMove {
        /// The fitted K_dv, um/V.
        k_dv_um_per_v: f64,
        /// The probe's span over the voltages, um.
        span_um: f64,
        /// The fit's RMS residual, um.
        residual_um: f64,
    },
    /// Too few offset fit voltages.
    #[error("the offset fit needs at least two DAC voltages, not {count}")]
    OffsetVoltageCount {
        /// The voltages given.
        count: usize,
    },
    /// An offset fit voltage beyond half the DAC's full scale.
    #[error("an offset fit voltage of {volts} V is beyond half the DAC's full scale ({limit_v} V)")]
    OffsetVoltageRange {
        /// The voltage.
        volts: f64,
        /// The largest allowed, V.
        limit_v: f64,
    },
    /// The DAC did not settle.
    #[error("the DAC did not settle at {dac_v:.4} V within {settle_ticks} ticks (slew limit {slew_v_per_tick} V per tick): lengthen the settling")]
    DacNotSettled {
        /// The voltage asked for.
        dac_v: f64,
        /// The settling ticks.
        settle_ticks: u32,
        /// The co-processor's slew limit, V per tick.
        slew_v_per_tick: f32,
    },
    /// The offset fit's voltages do not determine it.
    #[error("the offset fit's DAC voltages are not distinct")]
    OffsetSingular,
    /// The controller's reading does not follow the DAC.
    #[error("the controller's reading hardly follows the DAC ({gain:.4} V per V): is the co-processor's output wired to the controller's analogue input?")]
    ReadingDoesNotFollow {
        /// The fitted gain, V per V.
        gain: f64,
    },
    /// The interface's offset cannot be nulled with the DAC.
    #[error("the interface's offset ({intercept_v:.4} V) is beyond the DAC's range")]
    OffsetBeyondRange {
        /// The offset, V.
        intercept_v: f64,
    },
    /// The co-processor wrote another DAC code than asked for.
    #[error("asked the co-processor for DAC code {asked}, it wrote {wrote}")]
    DacCodeMismatch {
        /// The code asked for.
        asked: i32,
        /// The code written.
        wrote: i16,
    },
    /// No DAC code was tried around the null.
    #[error("no DAC code to try")]
    NoDacCode,
    /// The analogue path's settings (checked before the first measurement) are not valid.
    #[error("the analogue path is measured at 1 to {PATH_POINTS} frequencies, increasing, each above 0 and below {nyquist_hz} Hz, not {freqs_hz:?}")]
    PathFrequencies {
        /// The frequencies given, Hz.
        freqs_hz: Vec<f64>,
        /// The highest allowed, Hz.
        nyquist_hz: f64,
    },
    /// The analogue path's amplitude or measuring time is not positive.
    #[error("the analogue path's amplitude and measuring time must be positive")]
    PathSettings,
    /// Too few or too many analogue path frequencies.
    #[error("the analogue path is measured at 1 to {PATH_POINTS} frequencies, not {count}")]
    PathFrequencyCount {
        /// The frequencies given.
        count: usize,
    },
    /// An analogue path frequency that cannot be measured.
    #[error("cannot measure the analogue path at {freq_hz} Hz")]
    PathFrequency {
        /// The frequency, Hz.
        freq_hz: f64,
    },
    /// The analogue path's calibration program could not be built.
    #[error("the calibration program: {error:?}")]
    PathProgram {
        /// Why (part of the message).
        error: ProgramError,
    },
    /// A sine could not be fitted to the analogue path's samples.
    #[error("cannot fit a sine to {points} points (too few, or not spread over the period)")]
    SineFit {
        /// The samples.
        points: usize,
    },
    /// The co-processor's output was too small at an analogue path frequency.
    #[error("at {freq_hz} Hz the co-processor asked for {asked_um:.3} um instead of {expected_um:.3} um: is its output enabled and its program running?")]
    OutputTooSmall {
        /// The frequency, Hz.
        freq_hz: f64,
        /// The amplitude it asked for, um.
        asked_um: f64,
        /// The amplitude of the calibration program, um.
        expected_um: f64,
    },
    /// The measured analogue path is not a table the firmware accepts.
    #[error("the measured analogue path is not a valid table: {error}")]
    PathTable {
        /// Why (part of the message).
        error: PathError,
    },
    /// The starting feedforward parameters are not valid.
    #[error("the starting parameters: {error}")]
    StartingParams {
        /// Why (part of the message).
        error: ParamError,
    },
    /// The measured feedforward parameters are not valid.
    #[error("the measured parameters are not valid ({error}): {params:?}")]
    MeasuredParams {
        /// Why (part of the message).
        error: ParamError,
        /// The parameters.
        params: Box<FeedforwardParams>,
    },
}

#[cfg(test)]
mod tests {
    use super::*;
    use sts_twin_core::wire::Rejection;

    /// The message and its causes, as the sts-twin command prints an error (`{:#}`).
    fn chain(error: &dyn std::error::Error) -> String {
        std::iter::successors(Some(error), |e| e.source()).map(|e| e.to_string()).collect::<Vec<_>>().join(": ")
    }

    #[test]
    fn messages_name_what_was_asked_and_the_answer() {
        let refused = RigError::Refused {
            what: "the twin program".into(),
            response: Box::new(Response::Rejected(Rejection::NoStagedProgram)),
        };
        assert_eq!(refused.to_string(), "the co-processor refused the twin program: Rejected(NoStagedProgram)");
        let unexpected = RigError::Unexpected { request: "SaveConfig", response: Box::new(Response::Ack) };
        assert_eq!(unexpected.to_string(), "the co-processor answered SaveConfig with Ack");
        let not_calibrated = RigError::NotCalibrated { config_source: ConfigSource::DefaultsAfterCorrupt };
        assert_eq!(
            not_calibrated.to_string(),
            "the co-processor booted without a stored calibration (DefaultsAfterCorrupt); calibrate first: sts-twin calibrate-offset --bus FILE"
        );
        let no_answer = RigError::NoAnswer { request: Box::new(Request::GetStatus), seq: 7 };
        assert_eq!(no_answer.to_string(), "the firmware sent no answer to GetStatus (sequence 7)");
    }

    #[test]
    fn a_harness_error_is_the_cause_of_its_context() {
        let missing = || HilError::QemuMissing {
            program: "qemu-system-arm".into(),
            arch: "Arm",
            package: "qemu-system-arm",
            env: "STS_TWIN_QEMU",
        };
        assert_eq!(
            chain(&RigError::Start(missing())),
            "cannot start the firmware under QEMU: `qemu-system-arm` not found: install QEMU for Arm (Debian/Ubuntu: `sudo apt-get install qemu-system-arm`) or point STS_TWIN_QEMU at it"
        );
        // Without context the harness's error reads as it is.
        assert_eq!(chain(&RigError::from(missing())), missing().to_string());
    }
}
