//! Errors of reading, writing and decoding a model file.

use std::path::PathBuf;

use sts_twin_core::program::ProgramError;

/// Why the text of a model file was rejected.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ModelFileError {
    /// Not JSON, or JSON of the wrong shape (a missing field, a wrong type).
    #[error("{line}:{column}: {message}")]
    Json {
        /// Line, from 1.
        line: usize,
        /// Column, from 1.
        column: usize,
        /// What is wrong.
        message: String,
    },
    /// A field with a bad value.
    #[error("field `{field}` {message}")]
    Field {
        /// The field.
        field: &'static str,
        /// What is wrong.
        message: String,
    },
    /// A field with a bad value, where the field's path is known only on reading
    /// (`effects[2].effect`).
    #[error("field `{field}` {message}")]
    Value {
        /// The field's path.
        field: String,
        /// What is wrong.
        message: String,
    },
    /// The file is larger than any model file ([`crate::MAX_MODEL_FILE_BYTES`]).
    #[error("is larger than {max_bytes} bytes, more than any model file holds")]
    TooLarge {
        /// The bound.
        max_bytes: usize,
    },
}

/// Why a model file could not be read or written, or its program not decoded.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ModelError {
    /// The model file could not be read.
    #[error("cannot read model file {path}")]
    Read {
        /// The model file.
        path: PathBuf,
        /// The operating system's reason.
        #[source]
        source: std::io::Error,
    },
    /// The model file's text was rejected: `FILE:LINE:COLUMN: ...` for JSON, `FILE: field ...`
    /// for a bad field.
    #[error("{}{}{error}", .path.display(), separator(.error))]
    File {
        /// The model file.
        path: PathBuf,
        /// What is wrong with its text (part of the message).
        error: ModelFileError,
    },
    /// The model file could not be written whole, or may not be.
    #[error(transparent)]
    Output(#[from] sts_dataset::DatasetError),
    /// The model could not be encoded as JSON.
    #[error(transparent)]
    Encode(#[from] serde_json::Error),
    /// The model file could not be written.
    #[error("cannot write model file {path}")]
    Write {
        /// The model file.
        path: PathBuf,
        /// The operating system's reason.
        #[source]
        source: std::io::Error,
    },
    /// A formula's constant cannot be written in the export's language.
    #[error("field `{field}.expr`: a constant {message}")]
    Constant {
        /// The formula (`amplitude` or `phase`).
        field: &'static str,
        /// What is wrong.
        message: String,
    },
    /// The program's bytes are not hexadecimal.
    #[error("is not hexadecimal (an even number of 0-9, a-f digits)")]
    NotHex,
    /// The program's bytes do not decode as a program.
    #[error("is not a postcard-encoded program: {error}")]
    NotPostcard {
        /// The decoder's reason (part of the message).
        error: postcard::Error,
    },
    /// Bytes follow the program.
    #[error("has {count} byte{} after the program", if *.count == 1 { "" } else { "s" })]
    TrailingBytes {
        /// How many.
        count: usize,
    },
    /// The program is of another format version (a twin made by another release of sts-twin).
    #[error("holds a program of format version {found}, this release reads version {expected}: fit the twin again with this release")]
    ProgramVersion {
        /// The file's program version.
        found: u16,
        /// [`sts_twin_core::program::PROGRAM_VERSION`].
        expected: u16,
    },
    /// The decoded program does not validate.
    #[error("holds an invalid program: {error}")]
    InvalidProgram {
        /// Why (part of the message).
        error: ProgramError,
    },
}

/// What separates the file from the text error: JSON errors read `FILE:LINE:COLUMN: ...`.
fn separator(error: &ModelFileError) -> &'static str {
    match error {
        ModelFileError::Json { .. } => ":",
        ModelFileError::Field { .. } | ModelFileError::Value { .. } | ModelFileError::TooLarge { .. } => ": ",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rejected_text_names_the_file_as_before() {
        let json = ModelFileError::Json { line: 3, column: 5, message: "expected value".into() };
        let field = ModelFileError::Field { field: "format", message: "is \"x\", expected \"y\"".into() };
        let path = PathBuf::from("m.json");
        assert_eq!(ModelError::File { path: path.clone(), error: json }.to_string(), "m.json:3:5: expected value");
        assert_eq!(
            ModelError::File { path, error: field }.to_string(),
            "m.json: field `format` is \"x\", expected \"y\""
        );
        assert_eq!(ModelError::TrailingBytes { count: 1 }.to_string(), "has 1 byte after the program");
        assert_eq!(ModelError::TrailingBytes { count: 2 }.to_string(), "has 2 bytes after the program");
    }
}
