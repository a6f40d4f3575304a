//! The messages of the control protocol.

use serde::{Deserialize, Serialize};

use crate::counters::Counters;
use crate::features::FeatureConfig;
use crate::feedforward::{FeedforwardParams, ParamError};
use crate::program::{Program, ProgramError};
use crate::supervisor::{SupervisorParamError, SupervisorParams, SupervisorState};

/// A message with the sequence number its answer carries back.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Envelope<T> {
    /// Chosen by the host; the firmware answers with the same number.
    pub seq: u16,
    /// The message.
    pub body: T,
}

/// Host to firmware.
// A message is decoded into a stack buffer in the firmware (no heap to box the large
// program upload into), so the variants' sizes differ by design.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Request {
    /// Answered by [`Response::Pong`] with the same nonce. The handshake: this variant and
    /// the answer's first two fields keep their place in every protocol version, so that a
    /// host can always tell which version a firmware speaks.
    Ping {
        /// Echoed back.
        nonce: u32,
    },
    /// Answered by [`Response::Status`].
    GetStatus,
    /// Validates and stages a twin program; with `activate` it takes effect at the next
    /// model update. A rejected program leaves the staged and active ones as they were.
    UploadProgram {
        /// The program.
        program: Program,
        /// Activate at once.
        activate: bool,
    },
    /// Activates the staged program.
    ActivateStaged,
    /// Removes the active program: the prediction ramps to zero.
    ClearProgram,
    /// Sets the feedforward parameters; rejected ones leave the old in force.
    SetParams(FeedforwardParams),
    /// Switches compensation on or off (the output ramps, never steps).
    SetEnabled(bool),
    /// Writes the parameters in force to the persistent config store.
    SaveConfig,
    /// Sets every counter to zero.
    ResetCounters,
    /// Sets the feature extraction (window, accelerometer scale, sample rate). The window
    /// restarts empty, so no model update happens until it is full again.
    SetFeatureConfig(FeatureConfig),
    /// Sets the supervisor's thresholds; rejected ones leave the old in force. Clears a trip.
    SetSupervisor(SupervisorParams),
}

/// Firmware to host.
#[allow(clippy::large_enum_variant)] // as `Request`: no heap in the firmware
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Response {
    /// Answer to [`Request::Ping`].
    Pong {
        /// The request's nonce.
        nonce: u32,
        /// The firmware's [`super::PROTOCOL_VERSION`].
        protocol_version: u16,
    },
    /// Answer to [`Request::GetStatus`].
    Status(Status),
    /// The request was carried out.
    Ack,
    /// The request was refused; nothing changed.
    Rejected(Rejection),
}

/// Why a request was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Rejection {
    /// The uploaded program is malformed.
    Program(ProgramError),
    /// The parameters are invalid.
    Params(ParamError),
    /// There is no staged program to activate.
    NoStagedProgram,
    /// The config store could not be written.
    Store,
    /// The feature configuration is invalid (see `FeatureConfig::validate`).
    FeatureConfig,
    /// The supervisor's thresholds are invalid.
    Supervisor(SupervisorParamError),
}

impl core::fmt::Display for Rejection {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Program(e) => write!(f, "the twin program is malformed ({e})"),
            Self::Params(e) => write!(f, "invalid parameter ({e})"),
            Self::NoStagedProgram => f.write_str("no twin is staged"),
            Self::Store => f.write_str("the config store could not be written"),
            Self::FeatureConfig => f.write_str("the feature settings are invalid"),
            Self::Supervisor(e) => write!(f, "invalid supervisor threshold ({e})"),
        }
    }
}

impl core::error::Error for Rejection {}

/// Where the configuration in force came from at boot.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ConfigSource {
    /// The store was empty: safe defaults.
    Defaults,
    /// The store held a valid config.
    Stored,
    /// The store was corrupt (bad magic, version, CRC or content): safe defaults.
    DefaultsAfterCorrupt,
}

/// The firmware's state and counters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Status {
    /// Event counters since boot or the last reset.
    pub counters: Counters,
    /// Compensation is asked for.
    pub enabled: bool,
    /// Gain in force, 0 to 1 (ramps).
    pub gain: f32,
    /// `servo::DEGRADED_*` bits: why the inputs are not trusted now (0: trusted).
    pub degraded: u16,
    /// Id of the active program, if any.
    pub program_id: Option<u32>,
    /// Id of the staged program, if any.
    pub staged_program_id: Option<u32>,
    /// Feedforward parameters in force.
    pub params: FeedforwardParams,
    /// Feature extraction settings in force.
    pub feature_config: FeatureConfig,
    /// Where the boot configuration came from.
    pub config_source: ConfigSource,
    /// Amplitude of the last model output, micrometres.
    pub amp_um: f32,
    /// Phase of the last model output, degrees.
    pub phase_deg: f32,
    /// The features of the last model update (f1..f12).
    pub features: [f32; 12],
    /// The supervisor's thresholds in force.
    pub supervisor_params: SupervisorParams,
    /// The supervisor's state.
    pub supervisor: SupervisorState,
}
