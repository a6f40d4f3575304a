//! The mapping file: which of a recording's channels is the command, the encoder, the probe and
//! the accelerometer (and the optional X, spindle and temperature), in which unit and scale.
//!
//! ```toml
//! sample_rate_hz = 8000          # only where the recording has no time channel
//! acc_mps2_per_lsb = 0.0014966   # the accelerometer ADC's scale, if known (optional)
//!
//! [channels]
//! time = { name = "Time", unit = "s" }
//! command = { name = "z_ref", unit = "mm" }
//! encoder = { name = "z_enc", unit = "mm" }
//! probe = { name = "cap", unit = "V", scale = 2.5 }      # 2.5 um per volt
//! accelerometer = { name = "acc_z", unit = "g" }
//!
//! [segments]                    # how groups are found in one long recording (defaults shown)
//! rest_tolerance_um = 0.001     # the command is at rest while it stays this close to one value
//! min_pause_s = 0.25            # a pause between two groups lasts at least this long
//! ```

use std::path::Path;

use serde::Deserialize;

use crate::ImportError;

/// The whole mapping file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Mapping {
    /// Samples per second, where the recording has no time channel.
    #[serde(default)]
    pub sample_rate_hz: Option<f64>,
    /// The accelerometer ADC's scale as the co-processor will read it, m/s^2 per LSB, if
    /// known (the dataset's `acc_mps2_per_lsb`: the features are computed on its codes).
    #[serde(default)]
    pub acc_mps2_per_lsb: Option<f64>,
    /// The channels.
    pub channels: Channels,
    /// How groups are found.
    #[serde(default)]
    pub segments: Segments,
    /// Groups at given times instead of found from the command.
    #[serde(default)]
    pub schedule: Vec<Scheduled>,
}

/// The recording's channels, by canonical role.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Channels {
    /// Time (optional: without it, `sample_rate_hz` gives the time).
    #[serde(default)]
    pub time: Option<Channel>,
    /// The Z command.
    pub command: Channel,
    /// The Z encoder.
    pub encoder: Channel,
    /// The probe at the tool.
    pub probe: Channel,
    /// The accelerometer near the tool.
    pub accelerometer: Channel,
    /// The X position (optional).
    #[serde(default)]
    pub x_position: Option<Channel>,
    /// The X acceleration (optional).
    #[serde(default)]
    pub x_acceleration: Option<Channel>,
    /// The spindle angle (optional).
    #[serde(default)]
    pub spindle: Option<Channel>,
    /// A temperature (optional).
    #[serde(default)]
    pub temperature: Option<Channel>,
}

/// One channel: its name in the recording, its unit, and a scale and offset applied first
/// (`value * scale + offset` is in `unit`; for `V`, `scale` is the canonical unit per volt).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Channel {
    /// The column's name (its header) in the recording.
    pub name: String,
    /// The unit of `value * scale + offset`.
    pub unit: String,
    /// Multiplies the recorded value first.
    #[serde(default = "one")]
    pub scale: f64,
    /// Added after the scale.
    #[serde(default)]
    pub offset: f64,
}

fn one() -> f64 {
    1.0
}

/// How groups are found in one long recording.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Segments {
    /// The command is at rest while it stays within this of one value, um.
    #[serde(default = "default_rest_tolerance_um")]
    pub rest_tolerance_um: f64,
    /// A pause between two groups lasts at least this long, s.
    #[serde(default = "default_min_pause_s")]
    pub min_pause_s: f64,
}

fn default_rest_tolerance_um() -> f64 {
    0.001
}

fn default_min_pause_s() -> f64 {
    0.25
}

impl Default for Segments {
    fn default() -> Self {
        Self { rest_tolerance_um: default_rest_tolerance_um(), min_pause_s: default_min_pause_s() }
    }
}

/// A group at given times.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scheduled {
    /// Its start in the recording's time, s.
    pub start_s: f64,
    /// Its length, s.
    pub duration_s: f64,
}

/// What a canonical column's unit may be, and each unit's factor to it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quantity {
    /// Seconds.
    Time,
    /// Micrometres (Z).
    PositionUm,
    /// Millimetres (X).
    PositionMm,
    /// Metres per second squared.
    Acceleration,
    /// Degrees.
    Angle,
    /// Degrees Celsius.
    Temperature,
}

/// Standard gravity, m/s^2 per g.
pub const G_MPS2: f64 = 9.806_65;

impl Quantity {
    /// The factor from `unit` to this quantity's canonical unit; `V` is 1 (its scale is the
    /// sensor's gain). `None` for a unit of another quantity.
    pub fn factor(self, unit: &str) -> Option<f64> {
        let f = match (self, unit) {
            (_, "V") => 1.0,
            (Quantity::Time, "s") => 1.0,
            (Quantity::Time, "ms") => 1e-3,
            (Quantity::Time, "us") => 1e-6,
            (Quantity::PositionUm | Quantity::PositionMm, u) => {
                let um = match u {
                    "m" => 1e6,
                    "mm" => 1e3,
                    "um" => 1.0,
                    "nm" => 1e-3,
                    _ => return None,
                };
                if self == Quantity::PositionMm {
                    um * 1e-3
                } else {
                    um
                }
            }
            (Quantity::Acceleration, "m/s^2") => 1.0,
            (Quantity::Acceleration, "mm/s^2") => 1e-3,
            (Quantity::Acceleration, "g") => G_MPS2,
            (Quantity::Angle, "deg") => 1.0,
            (Quantity::Angle, "rad") => 180.0 / std::f64::consts::PI,
            (Quantity::Angle, "rev") => 360.0,
            (Quantity::Temperature, "degC") => 1.0,
            _ => return None,
        };
        Some(f)
    }

    /// The units this quantity takes, for error messages.
    pub fn units(self) -> &'static str {
        match self {
            Quantity::Time => "s, ms, us",
            Quantity::PositionUm | Quantity::PositionMm => "m, mm, um, nm, V (with a scale in um per volt)",
            Quantity::Acceleration => "m/s^2, mm/s^2, g, V (with a scale in m/s^2 per volt)",
            Quantity::Angle => "deg, rad, rev",
            Quantity::Temperature => "degC, V (with a scale in degC per volt)",
        }
    }
}

/// A channel resolved against the mapping: its role, the factor from a recorded value to the
/// canonical unit, and the offset.
#[derive(Clone, Debug)]
pub struct Resolved {
    /// The role's key in the mapping file (`command`, ...).
    pub role: &'static str,
    /// The channel.
    pub channel: Channel,
    /// Recorded value to canonical unit: `(value * scale + offset) * factor`.
    pub factor: f64,
}

impl Resolved {
    /// A recorded value in the canonical unit.
    pub fn convert(&self, value: f64) -> f64 {
        (value * self.channel.scale + self.channel.offset) * self.factor
    }
}

impl Mapping {
    /// Reads and checks a mapping file; errors name the file and the field.
    pub fn read(path: &Path) -> Result<Self, ImportError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| ImportError::Io { path: path.to_path_buf(), source })?;
        Self::parse(path, &text)
    }

    /// Parses and checks a mapping's text (`path` names it in errors).
    pub fn parse(path: &Path, text: &str) -> Result<Self, ImportError> {
        let mapping: Mapping = toml::from_str(text)
            .map_err(|e| ImportError::Mapping { path: path.to_path_buf(), message: e.to_string() })?;
        mapping.resolve(path)?;
        let bad = |field: &str, why: &str| ImportError::Mapping {
            path: path.to_path_buf(),
            message: format!("{field}: {why}"),
        };
        if mapping.sample_rate_hz.is_some_and(|r| !(r.is_finite() && r > 0.0)) {
            return Err(bad("sample_rate_hz", "must be a positive number of samples per second"));
        }
        if mapping.channels.time.is_none() && !mapping.sample_rate_hz.is_some_and(|r| r.is_finite() && r > 0.0) {
            return Err(bad("sample_rate_hz", "needed (a positive number) where there is no [channels] time"));
        }
        if mapping.acc_mps2_per_lsb.is_some_and(|s| !(s.is_finite() && s > 0.0)) {
            return Err(bad("acc_mps2_per_lsb", "must be a positive number of m/s^2 per LSB"));
        }
        if !(mapping.segments.rest_tolerance_um.is_finite() && mapping.segments.rest_tolerance_um > 0.0) {
            return Err(bad("segments.rest_tolerance_um", "must be a positive number of micrometres"));
        }
        if !(mapping.segments.min_pause_s.is_finite() && mapping.segments.min_pause_s > 0.0) {
            return Err(bad("segments.min_pause_s", "must be a positive number of seconds"));
        }
        let mut schedule: Vec<(usize, Scheduled)> = mapping.schedule.iter().copied().enumerate().collect();
        for (i, s) in &schedule {
            if !(s.start_s.is_finite() && s.start_s >= 0.0 && s.duration_s.is_finite() && s.duration_s > 0.0) {
                return Err(bad(&format!("schedule[{i}]"), "start_s must be at least 0 and duration_s positive"));
            }
        }
        schedule.sort_by(|a, b| a.1.start_s.total_cmp(&b.1.start_s));
        for w in schedule.windows(2) {
            let ((i, a), (j, b)) = (w[0], w[1]);
            if a.start_s + a.duration_s > b.start_s {
                return Err(bad(
                    &format!("schedule[{i}] and schedule[{j}]"),
                    &format!(
                        "overlap: {:.4}-{:.4} s and {:.4}-{:.4} s (a sample belongs to one group)",
                        a.start_s,
                        a.start_s + a.duration_s,
                        b.start_s,
                        b.start_s + b.duration_s
                    ),
                ));
            }
        }
        Ok(mapping)
    }

    /// Every mapped channel with its factor, in the order time (if any), command, encoder,
    /// probe, accelerometer, then the optional ones present.
    pub fn resolve(&self, path: &Path) -> Result<Vec<Resolved>, ImportError> {
        let c = &self.channels;
        let roles: [(&'static str, Option<&Channel>, Quantity); 9] = [
            ("time", c.time.as_ref(), Quantity::Time),
            ("command", Some(&c.command), Quantity::PositionUm),
            ("encoder", Some(&c.encoder), Quantity::PositionUm),
            ("probe", Some(&c.probe), Quantity::PositionUm),
            ("accelerometer", Some(&c.accelerometer), Quantity::Acceleration),
            ("x_position", c.x_position.as_ref(), Quantity::PositionMm),
            ("x_acceleration", c.x_acceleration.as_ref(), Quantity::Acceleration),
            ("spindle", c.spindle.as_ref(), Quantity::Angle),
            ("temperature", c.temperature.as_ref(), Quantity::Temperature),
        ];
        let mut out = Vec::new();
        for (role, channel, quantity) in roles {
            let Some(channel) = channel else { continue };
            let factor = quantity.factor(&channel.unit).ok_or_else(|| ImportError::Mapping {
                path: path.to_path_buf(),
                message: format!(
                    "channels.{role}.unit: `{}` is not a unit of this channel (one of {})",
                    channel.unit,
                    quantity.units()
                ),
            })?;
            if !(channel.scale.is_finite() && channel.scale != 0.0 && channel.offset.is_finite()) {
                return Err(ImportError::Mapping {
                    path: path.to_path_buf(),
                    message: format!("channels.{role}: scale must be a non-zero number and offset a number"),
                });
            }
            out.push(Resolved { role, channel: channel.clone(), factor });
        }
        Ok(out)
    }
}
