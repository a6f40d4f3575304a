//! The persistent configuration: what the firmware loads at boot from its config store.
//!
//! Layout of a stored record (little endian): magic `"STSC"` (4 bytes), format version
//! (u16), payload length (u16), the postcard payload, CRC-32/ISO-HDLC of everything before
//! it (4 bytes). A record that fails any check is not used: the firmware runs on safe
//! defaults (compensation off, default parameters) and reports
//! [`ConfigSource::DefaultsAfterCorrupt`](crate::wire::ConfigSource).

use serde::{Deserialize, Serialize};

use crate::features::{DefaultFeatureState, FeatureConfig};
use crate::feedforward::FeedforwardParams;
use crate::program::Program;
use crate::supervisor::SupervisorParams;
use crate::wire::frame_crc32;

/// Magic bytes at the start of a record.
pub const CONFIG_MAGIC: [u8; 4] = *b"STSC";
/// Format version of the record (2: the feedforward parameters carry the analogue-path table;
/// 3: the table holds ten points with their gains and amplitude, and the supervisor's
/// thresholds are stored beside the parameters; 4: the feature settings and the active twin
/// program too, so that a board keeps its twin across a power cycle).
pub const CONFIG_VERSION: u16 = 4;
/// Largest record, bytes: the header, the parameters (a full analogue-path table), the
/// supervisor's thresholds, the feature settings and the largest program a control frame
/// carries.
pub const MAX_CONFIG_BYTES: usize = 1024;

/// What the firmware keeps across power cycles.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PersistentConfig {
    /// Feedforward parameters, including the calibrated offset and K_dv.
    pub params: FeedforwardParams,
    /// The supervisor's thresholds in force when the record was saved (a lab's own, kept
    /// across a power cycle; the defaults where none were set).
    pub supervisor: SupervisorParams,
    /// The feature extraction's settings in force (the twin's window and scale).
    pub feature_config: FeatureConfig,
    /// The active twin program, if one was in force.
    pub program: Option<Program>,
}

/// Why a stored record was not used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ConfigError {
    /// The store is blank (erased or all zero): not an error, just no config.
    Blank,
    /// The magic bytes are wrong.
    Magic,
    /// The format version is not [`CONFIG_VERSION`].
    Version,
    /// The length field is impossible.
    Length,
    /// The CRC does not match.
    Crc,
    /// The payload does not decode.
    Decode,
    /// The payload decodes but its parameters are invalid.
    Invalid,
    /// The record does not fit the buffer (encoding only).
    BufferTooSmall,
}

impl core::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Blank => write!(f, "the config store is blank"),
            Self::Magic => write!(f, "config record has the wrong magic bytes"),
            Self::Version => write!(f, "config record format is not version {CONFIG_VERSION}"),
            Self::Length => write!(f, "config record length is impossible"),
            Self::Crc => write!(f, "config record CRC mismatch"),
            Self::Decode => write!(f, "config record payload does not decode"),
            Self::Invalid => write!(f, "config record parameters are invalid"),
            Self::BufferTooSmall => write!(f, "config record does not fit the buffer"),
        }
    }
}

impl core::error::Error for ConfigError {}

impl PersistentConfig {
    /// Writes the record into `out`; returns its length.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, ConfigError> {
        if out.len() < 12 {
            return Err(ConfigError::BufferTooSmall);
        }
        let payload_len = {
            let (_, rest) = out.split_at_mut(8);
            postcard::to_slice(self, rest).map_err(|_| ConfigError::BufferTooSmall)?.len()
        };
        let end = 8 + payload_len;
        if out.len() < end + 4 {
            return Err(ConfigError::BufferTooSmall);
        }
        out[..4].copy_from_slice(&CONFIG_MAGIC);
        out[4..6].copy_from_slice(&CONFIG_VERSION.to_le_bytes());
        out[6..8].copy_from_slice(&(payload_len as u16).to_le_bytes());
        let crc = frame_crc32(&out[..end]);
        out[end..end + 4].copy_from_slice(&crc.to_le_bytes());
        Ok(end + 4)
    }

    /// Reads and checks a record.
    pub fn decode(bytes: &[u8]) -> Result<Self, ConfigError> {
        if bytes.iter().take(12).all(|&b| b == 0) || bytes.iter().take(12).all(|&b| b == 0xff) {
            return Err(ConfigError::Blank);
        }
        if bytes.len() < 12 {
            return Err(ConfigError::Length);
        }
        if bytes[..4] != CONFIG_MAGIC {
            return Err(ConfigError::Magic);
        }
        if u16::from_le_bytes([bytes[4], bytes[5]]) != CONFIG_VERSION {
            return Err(ConfigError::Version);
        }
        let payload_len = u16::from_le_bytes([bytes[6], bytes[7]]) as usize;
        let end = 8 + payload_len;
        if end + 4 > bytes.len() || end + 4 > MAX_CONFIG_BYTES {
            return Err(ConfigError::Length);
        }
        let stored = u32::from_le_bytes([bytes[end], bytes[end + 1], bytes[end + 2], bytes[end + 3]]);
        if frame_crc32(&bytes[..end]) != stored {
            return Err(ConfigError::Crc);
        }
        let config: Self = match postcard::take_from_bytes(&bytes[8..end]) {
            Ok((config, [])) => config,
            _ => return Err(ConfigError::Decode),
        };
        config.params.validate().map_err(|_| ConfigError::Invalid)?;
        config.supervisor.validate().map_err(|_| ConfigError::Invalid)?;
        config.feature_config.validate(DefaultFeatureState::CAPACITY_SAMPLES).map_err(|_| ConfigError::Invalid)?;
        if let Some(program) = &config.program {
            program.validate().map_err(|_| ConfigError::Invalid)?;
        }
        Ok(config)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_record_round_trips_and_every_corruption_is_caught() {
        let config = PersistentConfig {
            params: FeedforwardParams { offset_v: 0.0123, ..Default::default() },
            supervisor: SupervisorParams { worse_ratio: 1.3, ..SupervisorParams::DEFAULT },
            feature_config: FeatureConfig { window_samples: 800, ..FeatureConfig::DEFAULT },
            program: Some(crate::program::paper_program()),
        };
        let mut buf = [0u8; MAX_CONFIG_BYTES];
        let len = config.encode(&mut buf).unwrap();
        assert_eq!(PersistentConfig::decode(&buf[..len]), Ok(config.clone()));
        assert_eq!(PersistentConfig::decode(&[0u8; 64]), Err(ConfigError::Blank));
        for byte in 0..len {
            let mut bad = buf;
            bad[byte] ^= 0x04;
            assert!(PersistentConfig::decode(&bad).is_err(), "flip in byte {byte} not caught");
        }
        assert_eq!(PersistentConfig::decode(&buf[..len - 1]), Err(ConfigError::Length));
        let invalid = PersistentConfig {
            params: FeedforwardParams { k_dv_um_per_v: 0.0, ..Default::default() },
            supervisor: SupervisorParams::DEFAULT,
            feature_config: FeatureConfig::DEFAULT,
            program: None,
        };
        let len = invalid.encode(&mut buf).unwrap();
        assert_eq!(PersistentConfig::decode(&buf[..len]), Err(ConfigError::Invalid));
        let bad_supervisor = PersistentConfig {
            params: FeedforwardParams::default(),
            supervisor: SupervisorParams { worse_ratio: 0.5, ..SupervisorParams::DEFAULT },
            feature_config: FeatureConfig::DEFAULT,
            program: None,
        };
        let len = bad_supervisor.encode(&mut buf).unwrap();
        assert_eq!(PersistentConfig::decode(&buf[..len]), Err(ConfigError::Invalid));
        // A stored program that does not validate is not loaded.
        let mut bad_program = crate::program::paper_program();
        bad_program.version += 1;
        let len = PersistentConfig { program: Some(bad_program), ..config.clone() }.encode(&mut buf).unwrap();
        assert_eq!(PersistentConfig::decode(&buf[..len]), Err(ConfigError::Invalid));
        let bad_window = FeatureConfig { window_samples: 0, ..FeatureConfig::DEFAULT };
        let len = PersistentConfig { feature_config: bad_window, ..config }.encode(&mut buf).unwrap();
        assert_eq!(PersistentConfig::decode(&buf[..len]), Err(ConfigError::Invalid));
    }

    /// The largest record round trips: a full analogue-path table and the largest program a
    /// control frame carries.
    #[test]
    fn the_largest_program_a_frame_carries_fits_a_record() {
        use crate::wire::{encode_frame, Request, MAX_ENCODED_FRAME};
        let mut program = crate::program::paper_program();
        let mut frame = [0u8; MAX_ENCODED_FRAME];
        // Grow the program by constants until an upload no longer fits a frame.
        while program.consts.push(1.0e-3 * program.consts.len() as f32).is_ok() {
            let upload = Request::UploadProgram { program: program.clone(), activate: true };
            if encode_frame(1, &upload, &mut frame).is_err() {
                program.consts.pop();
                break;
            }
        }
        let points: [(f32, f32, f32); crate::analogue_path::PATH_POINTS] =
            core::array::from_fn(|i| (5.0 * (i + 1) as f32, 1.0 + 0.5 * i as f32, -1.5 * i as f32));
        let path = crate::analogue_path::AnaloguePath::from_responses(8.0, &points).unwrap();
        let config = PersistentConfig {
            params: FeedforwardParams { analogue_path: path, ..Default::default() },
            supervisor: SupervisorParams::DEFAULT,
            feature_config: FeatureConfig::DEFAULT,
            program: Some(program),
        };
        let mut buf = [0u8; MAX_CONFIG_BYTES];
        let len = config.encode(&mut buf).expect("the largest record fits");
        assert!(len <= MAX_CONFIG_BYTES);
        assert_eq!(PersistentConfig::decode(&buf[..len]).map(|c| c.program), Ok(config.program));
    }
}
