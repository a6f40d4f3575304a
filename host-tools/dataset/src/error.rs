//! Errors of reading and writing a dataset: each names the file, and where it applies the
//! line and column (both 1-based; the column counts characters of the line).

use std::path::PathBuf;

/// Why a dataset could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// The file could not be opened, read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's reason.
        source: std::io::Error,
    },
    /// A group file named in the manifest does not exist.
    #[error("{path}: missing group file (named in the manifest, group {group})")]
    MissingFile {
        /// The missing file.
        path: PathBuf,
        /// Index of the group in the manifest.
        group: usize,
    },
    /// The manifest is not valid JSON, or not a valid manifest.
    #[error("{path}:{line}:{column}: malformed manifest: {message}")]
    Manifest {
        /// The manifest file.
        path: PathBuf,
        /// Line, 1-based (0 when the problem is not at one place).
        line: usize,
        /// Column, 1-based (0 when the problem is not at one place).
        column: usize,
        /// What is wrong.
        message: String,
    },
    /// The header line of a group file is wrong.
    #[error("{path}:{line}:{column}: bad header: {message}")]
    BadHeader {
        /// The group file.
        path: PathBuf,
        /// Line, 1-based.
        line: usize,
        /// Column, 1-based.
        column: usize,
        /// What is wrong.
        message: String,
    },
    /// A field is not a finite number.
    #[error("{path}:{line}:{column}: column `{field}`: not a finite number: {text:?}")]
    BadValue {
        /// The group file.
        path: PathBuf,
        /// Line, 1-based.
        line: usize,
        /// Column, 1-based.
        column: usize,
        /// The column's header name.
        field: String,
        /// The text found.
        text: String,
    },
    /// A value no sensor of the column can produce ([`crate::Column::physical_bounds`]).
    #[error("{path}:{line}:{column}: column `{field}`: {value:e} is beyond what the sensor can produce ({min:e} to {max:e})")]
    OutOfRange {
        /// The group file.
        path: PathBuf,
        /// Line, 1-based.
        line: usize,
        /// Column, 1-based.
        column: usize,
        /// The column's header name.
        field: String,
        /// The value read.
        value: f64,
        /// The column's lower bound.
        min: f64,
        /// The column's upper bound.
        max: f64,
    },
    /// A group file is not the one the manifest describes (other rows or checksum): a
    /// dataset mixed from two runs, or truncated.
    #[error("{path}: not the file the manifest describes (group {group}): {message}")]
    Mismatch {
        /// The group file.
        path: PathBuf,
        /// Index of the group in the manifest.
        group: usize,
        /// What differs.
        message: String,
    },
    /// An output the command may not write (it exists, or is an input).
    #[error("{path}: {message}")]
    Refused {
        /// The output.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// A row has fewer fields than the header.
    #[error("{path}:{line}:{column}: column `{field}`: missing value (row has {found} of {expected} fields)")]
    MissingValue {
        /// The group file.
        path: PathBuf,
        /// Line, 1-based.
        line: usize,
        /// Column, 1-based (just past the row's end).
        column: usize,
        /// The first missing column's header name.
        field: String,
        /// Fields in the row.
        found: usize,
        /// Fields in the header.
        expected: usize,
    },
    /// A row has more fields than the header.
    #[error("{path}:{line}:{column}: extra value: row has more fields than the header's {expected}")]
    ExtraValue {
        /// The group file.
        path: PathBuf,
        /// Line, 1-based.
        line: usize,
        /// Column of the first extra field, 1-based.
        column: usize,
        /// Fields in the header.
        expected: usize,
    },
    /// The time column does not advance by `1 / sample_rate_hz`.
    #[error("{path}:{line}:{column}: column `t_s`: non-uniform time step: {found_s} s after the previous row, expected {expected_s} s (sample_rate_hz)")]
    NonUniformStep {
        /// The group file.
        path: PathBuf,
        /// Line, 1-based.
        line: usize,
        /// Column of `t_s`, 1-based.
        column: usize,
        /// The step found, s.
        found_s: f64,
        /// The step the manifest's sample rate implies, s.
        expected_s: f64,
    },
    /// A group file has fewer than two samples.
    #[error("{path}: too few samples: {rows} data rows, at least 2 needed")]
    TooShort {
        /// The group file.
        path: PathBuf,
        /// Data rows found.
        rows: usize,
    },
    /// Data given to the writer is inconsistent (column lengths, non-finite values, ...).
    #[error("{path}: cannot write: {message}")]
    InvalidData {
        /// The file that was to be written.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}
