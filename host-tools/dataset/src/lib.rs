#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

mod error;
pub mod output;
mod read;
mod write;

pub use error::DatasetError;
pub use read::{group_checksum, parse_group_csv, read, read_manifest};
pub use write::{format_group_csv, write, write_group, write_manifest};

use serde::{Deserialize, Serialize};

/// The value of the manifest's `format` field this crate reads and writes.
pub const FORMAT: &str = "sts-twin-dataset/1";

/// The manifest's file name inside a dataset directory.
pub const MANIFEST_FILE: &str = "manifest.json";

/// The five columns every group file has.
pub const REQUIRED_COLUMNS: [Column; 5] = [Column::TS, Column::ZCmdUm, Column::ZEncUm, Column::ZTcpUm, Column::AccMps2];

/// The optional columns a group file may have (used by the tools when present).
pub const OPTIONAL_COLUMNS: [Column; 4] = [Column::XMm, Column::XAccMps2, Column::SpindleDeg, Column::TempC];

/// The dataset manifest (`manifest.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Always [`FORMAT`].
    pub format: String,
    /// Sample rate of every group file, Hz (the time step is `1 / sample_rate_hz`).
    pub sample_rate_hz: f64,
    /// Free text: machine, date, conditions.
    #[serde(default)]
    pub description: String,
    /// Accelerometer ADC scale, m/s^2 per LSB, when the lab knows it (optional): the
    /// `acc_mps2` column then holds integer multiples of it and tools may recover ADC codes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub acc_mps2_per_lsb: Option<f64>,
    /// The groups, in measurement order.
    pub groups: Vec<GroupInfo>,
}

impl Manifest {
    /// A manifest in [`FORMAT`] with no ADC scale.
    pub fn new(sample_rate_hz: f64, description: &str, groups: Vec<GroupInfo>) -> Self {
        Self {
            format: FORMAT.to_string(),
            sample_rate_hz,
            description: description.to_string(),
            acc_mps2_per_lsb: None,
            groups,
        }
    }
}

/// One group of the measurement test: a sinusoidal Z command `amp_um * sin(2 pi freq_hz t)`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroupInfo {
    /// The group's CSV file name, relative to the dataset directory (no path separators).
    pub file: String,
    /// Command frequency, Hz.
    pub freq_hz: f64,
    /// Command amplitude, um.
    pub amp_um: f64,
    /// Machine time at the group's start, s.
    pub start_s: f64,
    /// Data rows of the group file, as written (absent in manifests written before it was
    /// recorded, or by hand: then not checked).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rows: Option<usize>,
    /// CRC-32 of the group file's bytes, 8 hex digits, as written ([`group_checksum`]):
    /// the reader refuses a file that is not the one the manifest describes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub crc32: Option<String>,
}

impl GroupInfo {
    /// A group not yet written (no row count or checksum).
    pub fn new(file: &str, freq_hz: f64, amp_um: f64, start_s: f64) -> Self {
        Self { file: file.to_string(), freq_hz, amp_um, start_s, rows: None, crc32: None }
    }
}

/// A column of a group file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Column {
    /// `t_s`: time since the group's start, s.
    TS,
    /// `z_cmd_um`: Z position command, um.
    ZCmdUm,
    /// `z_enc_um`: Z encoder reading, um.
    ZEncUm,
    /// `z_tcp_um`: tool centre point position (capacitance probe), um.
    ZTcpUm,
    /// `acc_mps2`: accelerometer near the TCP, m/s^2.
    AccMps2,
    /// `x_mm`: X slide position, mm (optional).
    XMm,
    /// `x_acc_mps2`: X slide acceleration, m/s^2 (optional).
    XAccMps2,
    /// `spindle_deg`: spindle (C axis) angle, degrees (optional).
    SpindleDeg,
    /// `temp_c`: machine temperature, degrees Celsius (optional).
    TempC,
}

impl Column {
    /// All columns, required first, in the canonical order of the writer.
    pub const ALL: [Column; 9] = [
        Column::TS,
        Column::ZCmdUm,
        Column::ZEncUm,
        Column::ZTcpUm,
        Column::AccMps2,
        Column::XMm,
        Column::XAccMps2,
        Column::SpindleDeg,
        Column::TempC,
    ];

    /// The header name of the column.
    pub fn name(self) -> &'static str {
        match self {
            Column::TS => "t_s",
            Column::ZCmdUm => "z_cmd_um",
            Column::ZEncUm => "z_enc_um",
            Column::ZTcpUm => "z_tcp_um",
            Column::AccMps2 => "acc_mps2",
            Column::XMm => "x_mm",
            Column::XAccMps2 => "x_acc_mps2",
            Column::SpindleDeg => "spindle_deg",
            Column::TempC => "temp_c",
        }
    }

    /// The column with this header name.
    pub fn from_name(name: &str) -> Option<Column> {
        Column::ALL.into_iter().find(|c| c.name() == name)
    }

    /// Whether every group file must have this column.
    pub fn is_required(self) -> bool {
        REQUIRED_COLUMNS.contains(&self)
    }

    /// The values a sensor of this channel can produce, inclusive, in the column's unit:
    /// anything beyond (or not finite) is refused at read time. Wide on purpose: they catch
    /// corrupt or mis-scaled data (1e308 um), never a real machine's.
    pub fn physical_bounds(self) -> (f64, f64) {
        match self {
            // time since the group's start: up to about 11 days
            Column::TS => (-1e6, 1e6),
            // Z positions: within 1 m of the origin
            Column::ZCmdUm | Column::ZEncUm | Column::ZTcpUm => (-1e6, 1e6),
            // accelerations: 10,000 g, beyond any accelerometer on a machine tool
            Column::AccMps2 | Column::XAccMps2 => (-1e5, 1e5),
            // X slide: within 100 m of the origin
            Column::XMm => (-1e5, 1e5),
            // spindle angle, possibly unwrapped: 10^9 turns
            Column::SpindleDeg => (-3.6e11, 3.6e11),
            // machine temperature: absolute zero to 1000 C
            Column::TempC => (-273.15, 1000.0),
        }
    }

    /// Decimal places the writer uses: at or below each signal's resolution, so a written
    /// dataset is compact and reads back within rounding.
    pub fn write_decimals(self) -> usize {
        match self {
            Column::TS => 7,
            Column::ZCmdUm | Column::ZEncUm | Column::ZTcpUm => 5,
            Column::AccMps2 | Column::XAccMps2 => 7,
            Column::XMm => 6,
            Column::SpindleDeg => 4,
            Column::TempC => 5,
        }
    }
}

/// The samples of one group, one vector per column (all of the same length).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct GroupData {
    /// Time since the group's start, s.
    pub t_s: Vec<f64>,
    /// Z position command, um.
    pub z_cmd_um: Vec<f64>,
    /// Z encoder reading, um.
    pub z_enc_um: Vec<f64>,
    /// TCP position measured by the capacitance probe, um.
    pub z_tcp_um: Vec<f64>,
    /// Accelerometer near the TCP, m/s^2.
    pub acc_mps2: Vec<f64>,
    /// X slide position, mm.
    pub x_mm: Option<Vec<f64>>,
    /// X slide acceleration, m/s^2.
    pub x_acc_mps2: Option<Vec<f64>>,
    /// Spindle angle, degrees.
    pub spindle_deg: Option<Vec<f64>>,
    /// Machine temperature, degrees Celsius.
    pub temp_c: Option<Vec<f64>>,
}

impl GroupData {
    /// A group of `len` zero samples with only the required columns.
    pub fn with_len(len: usize) -> Self {
        Self {
            t_s: vec![0.0; len],
            z_cmd_um: vec![0.0; len],
            z_enc_um: vec![0.0; len],
            z_tcp_um: vec![0.0; len],
            acc_mps2: vec![0.0; len],
            ..Self::default()
        }
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t_s.len()
    }

    /// Whether the group has no samples.
    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }

    /// The samples of a column, `None` for an absent optional column.
    pub fn column(&self, column: Column) -> Option<&[f64]> {
        match column {
            Column::TS => Some(&self.t_s),
            Column::ZCmdUm => Some(&self.z_cmd_um),
            Column::ZEncUm => Some(&self.z_enc_um),
            Column::ZTcpUm => Some(&self.z_tcp_um),
            Column::AccMps2 => Some(&self.acc_mps2),
            Column::XMm => self.x_mm.as_deref(),
            Column::XAccMps2 => self.x_acc_mps2.as_deref(),
            Column::SpindleDeg => self.spindle_deg.as_deref(),
            Column::TempC => self.temp_c.as_deref(),
        }
    }

    /// The column's storage, created (empty) when absent.
    pub(crate) fn column_mut(&mut self, column: Column) -> &mut Vec<f64> {
        match column {
            Column::TS => &mut self.t_s,
            Column::ZCmdUm => &mut self.z_cmd_um,
            Column::ZEncUm => &mut self.z_enc_um,
            Column::ZTcpUm => &mut self.z_tcp_um,
            Column::AccMps2 => &mut self.acc_mps2,
            Column::XMm => self.x_mm.get_or_insert_with(Vec::new),
            Column::XAccMps2 => self.x_acc_mps2.get_or_insert_with(Vec::new),
            Column::SpindleDeg => self.spindle_deg.get_or_insert_with(Vec::new),
            Column::TempC => self.temp_c.get_or_insert_with(Vec::new),
        }
    }

    /// The columns present, in canonical order.
    pub fn present_columns(&self) -> Vec<Column> {
        Column::ALL.into_iter().filter(|c| self.column(*c).is_some()).collect()
    }

    /// Dynamic error at the TCP, `z_tcp_um - z_cmd_um`, um.
    pub fn dynamic_error_um(&self) -> Vec<f64> {
        self.z_tcp_um.iter().zip(&self.z_cmd_um).map(|(t, c)| t - c).collect()
    }
}

/// A whole dataset: the manifest and each group's samples, in manifest order.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    /// The manifest.
    pub manifest: Manifest,
    /// One entry per `manifest.groups` entry, same order.
    pub groups: Vec<GroupData>,
}

impl Dataset {
    /// Total number of samples over all groups.
    pub fn total_samples(&self) -> usize {
        self.groups.iter().map(GroupData::len).sum()
    }
}
