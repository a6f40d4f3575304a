//! The model file `sts-twin-model/1`: the fitted formulas as text, their fit statistics,
//! the feature settings they were trained on, and the firmware program ready to upload.
//!
//! The program (postcard bytes, hex) is authoritative: it is what the firmware runs and what
//! the host evaluates to predict, so that host predictions and firmware outputs agree bit
//! for bit. The formulas and statistics are for people.

use std::path::Path;

use serde::{Deserialize, Serialize};
use sts_symreg::{Expr, FloatType};
use sts_twin_core::features::{FeatureConfig, FEATURE_LABELS};
use sts_twin_core::program::Program;

use crate::{Effect, ModelError, ModelFileError, SERVO_AXIS};

/// The largest model file read, bytes: a twin of thousands of groups takes a few MB; a
/// larger file is not one.
pub const MAX_MODEL_FILE_BYTES: usize = 16 << 20;

/// The longest string read in a model file, bytes (formulas, descriptions and selection
/// notes take hundreds).
pub const MAX_MODEL_STRING_BYTES: usize = 64 << 10;

/// The value of the `format` field.
pub const MODEL_FORMAT: &str = "sts-twin-model/1";

/// A statistic read back from a model file: JSON has no infinity or NaN, so a non-finite
/// one (an R^2 over groups without variance, say) is written as `null` and read as NaN.
fn null_as_nan<'de, D: serde::Deserializer<'de>>(deserializer: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(deserializer)?.unwrap_or(f64::NAN))
}

/// One fitted formula.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Formula {
    /// The formula in plain infix with feature labels (f1..f12).
    pub formula: String,
    /// The expression tree (variables are feature indices 0..11).
    pub expr: Expr,
    /// Node count.
    pub complexity: usize,
    /// R^2 on all training groups.
    #[serde(deserialize_with = "null_as_nan")]
    pub r2_train: f64,
    /// R^2 of the held-out predictions of the cross-validation.
    #[serde(deserialize_with = "null_as_nan")]
    pub r2_cv: f64,
    /// The Pareto front of the final search: formula, loss, complexity, score.
    pub front: Vec<FrontEntry>,
    /// Why this member of the front was selected.
    pub selection: String,
}

/// One member of a Pareto front, as reported.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FrontEntry {
    /// The formula.
    pub formula: String,
    /// Mean squared error on the training data.
    #[serde(deserialize_with = "null_as_nan")]
    pub loss: f64,
    /// Node count.
    pub complexity: usize,
    /// The engine's selection score (drop in ln NMSE per added node).
    #[serde(deserialize_with = "null_as_nan")]
    pub score: f64,
    /// Held-out R^2 of the cross-validation's formulas of at most this complexity.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub r2_cv: Option<f64>,
}

/// The settings a model was trained with.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainingSettings {
    /// Seed of the searches.
    pub seed: u64,
    /// Seconds at each group's start left out of the feature window.
    pub skip_s: f64,
    /// Length of the feature window, s.
    pub feature_window_s: f64,
    /// Length of the target window at each group's end, s.
    pub target_window_s: f64,
    /// Groups with a smaller measured dynamic-error amplitude neither train nor score the
    /// phase, um.
    pub phase_min_amp_um: f64,
    /// Cross-validation folds.
    pub folds: usize,
    /// Operators the formulas could use.
    pub operators: String,
    /// Largest complexity searched.
    pub max_complexity: usize,
    /// Epoch limit of each search.
    pub max_epochs: usize,
    /// Good-enough NMSE of the amplitude model.
    pub amplitude_goal_nmse: f64,
    /// Good-enough NMSE of the phase model.
    pub phase_goal_nmse: f64,
    /// Tolerance factor on the best held-out NMSE in model selection.
    pub cv_ratio: f64,
    /// Epochs the final amplitude and phase searches ran.
    pub epochs: [usize; 2],
}

/// Held-out prediction of one group.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct GroupValidation {
    /// The group's file.
    pub file: String,
    /// Command frequency, Hz.
    pub freq_hz: f64,
    /// Command amplitude, um.
    pub amp_um: f64,
    /// Measured dynamic-error amplitude, um.
    #[serde(deserialize_with = "null_as_nan")]
    pub measured_amp_um: f64,
    /// Held-out predicted amplitude, um.
    #[serde(deserialize_with = "null_as_nan")]
    pub predicted_amp_um: f64,
    /// Measured dynamic-error phase, degrees.
    #[serde(deserialize_with = "null_as_nan")]
    pub measured_phase_deg: f64,
    /// Held-out predicted phase, degrees.
    #[serde(deserialize_with = "null_as_nan")]
    pub predicted_phase_deg: f64,
    /// Mean absolute error of the predicted waveform over the last second, um.
    #[serde(deserialize_with = "null_as_nan")]
    pub waveform_mae_um: f64,
    /// RMS error of the predicted waveform over the last second, um.
    #[serde(deserialize_with = "null_as_nan")]
    pub waveform_rms_um: f64,
}

/// The cross-validation summary.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Validation {
    /// Number of folds (groups are assigned round robin).
    pub folds: usize,
    /// R^2 of held-out amplitudes over all groups.
    #[serde(deserialize_with = "null_as_nan")]
    pub amplitude_r2: f64,
    /// R^2 of held-out phases over the groups whose phase is defined.
    #[serde(deserialize_with = "null_as_nan")]
    pub phase_r2: f64,
    /// Mean absolute error of the held-out predicted waveform over all groups, um.
    #[serde(deserialize_with = "null_as_nan")]
    pub waveform_mae_um: f64,
    /// RMS error of the held-out predicted waveform over all groups, um.
    #[serde(deserialize_with = "null_as_nan")]
    pub waveform_rms_um: f64,
    /// Per group.
    pub groups: Vec<GroupValidation>,
}

/// The firmware program in readable form (the postcard bytes are authoritative).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ProgramListing {
    /// Program id (CRC-32 of the program with id 0).
    pub id: u32,
    /// Bytecode, hex.
    pub code_hex: String,
    /// Constant table.
    pub consts: Vec<f32>,
    /// Number of per-tick terms.
    pub terms: usize,
}

/// A model file.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ModelFile {
    /// Always [`MODEL_FORMAT`].
    pub format: String,
    /// What data and settings produced it.
    pub description: String,
    /// The feature settings the formulas were trained on (the firmware must use the same).
    pub feature_config: FeatureConfig,
    /// How the model was trained (absent in files written before it was recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub training: Option<TrainingSettings>,
    /// Amplitude of the dynamic error, um.
    pub amplitude: Formula,
    /// Phase of the dynamic error relative to the command, degrees.
    pub phase: Formula,
    /// Cross-validation.
    pub validation: Validation,
    /// Readable program.
    pub program: ProgramListing,
    /// The program as postcard bytes, hex: what is uploaded to the firmware.
    pub program_postcard_hex: String,
    /// The probe's gain found by `fit --effect sensor-gain` when it is not one: the model is
    /// of the tool, so `compare` and `diagnose` divide a dataset's probe readings by it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub probe_gain: Option<f64>,
}

impl ModelFile {
    /// `dataset` as this model reads it: the probe readings divided by the model's probe gain
    /// (borrowed unchanged when there is none).
    pub fn probe_corrected<'a>(&self, dataset: &'a sts_dataset::Dataset) -> std::borrow::Cow<'a, sts_dataset::Dataset> {
        match self.probe_gain {
            Some(gain) => std::borrow::Cow::Owned(crate::replay::with_probe_gain(dataset, gain)),
            None => std::borrow::Cow::Borrowed(dataset),
        }
    }
}

impl ModelFile {
    /// Reads and checks a model file; errors name the file (and line and column for JSON).
    pub fn read(path: &Path) -> Result<Self, ModelError> {
        use std::io::Read as _;
        let read_error = |source| ModelError::Read { path: path.to_path_buf(), source };
        let mut text = String::new();
        std::fs::File::open(path)
            .map_err(read_error)?
            .take(MAX_MODEL_FILE_BYTES as u64 + 1)
            .read_to_string(&mut text)
            .map_err(read_error)?;
        if text.len() > MAX_MODEL_FILE_BYTES {
            let error = ModelFileError::TooLarge { max_bytes: MAX_MODEL_FILE_BYTES };
            return Err(ModelError::File { path: path.to_path_buf(), error });
        }
        Self::from_json(&text).map_err(|error| ModelError::File { path: path.to_path_buf(), error })
    }

    /// Parses and checks the text of a model file: its format, no string longer than
    /// [`MAX_MODEL_STRING_BYTES`], only known effects in its `effects` field, a valid program.
    pub fn from_json(text: &str) -> Result<Self, ModelFileError> {
        if text.len() > MAX_MODEL_FILE_BYTES {
            return Err(ModelFileError::TooLarge { max_bytes: MAX_MODEL_FILE_BYTES });
        }
        let json = |e: serde_json::Error| ModelFileError::Json {
            line: e.line(),
            column: e.column(),
            message: json_message(&e),
        };
        // The format first, so that another kind of file is named as such.
        let value: serde_json::Value = serde_json::from_str(text).map_err(json)?;
        match value.get("format").and_then(|f| f.as_str()) {
            Some(MODEL_FORMAT) => {}
            Some(other) => {
                return Err(ModelFileError::Field {
                    field: "format",
                    message: format!("is {other:?}, expected {MODEL_FORMAT:?}"),
                })
            }
            None => {
                return Err(ModelFileError::Field {
                    field: "format",
                    message: format!("is missing or not a string (expected {MODEL_FORMAT:?})"),
                })
            }
        }
        check_strings(&value, &mut String::new())?;
        check_effects(&value)?;
        let model: ModelFile = serde_json::from_str(text).map_err(json)?;
        model
            .firmware_program()
            .map_err(|e| ModelFileError::Field { field: "program_postcard_hex", message: e.to_string() })?;
        Ok(model)
    }

    /// Writes the model file as pretty JSON, whole or not at all
    /// ([`sts_dataset::output::write_file`]).
    pub fn write(&self, path: &Path) -> Result<(), ModelError> {
        let text = serde_json::to_string_pretty(self)?;
        Ok(sts_dataset::output::write_file(path, (text + "\n").as_bytes())?)
    }

    /// The formulas as Rust source: `dynamic_error_amp_um(x: &[f64]) -> f64` and
    /// `dynamic_error_phase_deg`, `x[0]` being f1. `origin` names the training data.
    pub fn rust_source(&self, origin: &str) -> String {
        format!(
            "// Generated by sts-twin fit from {origin}.\n// Inputs are the features f1..f12 of the accelerometer (docs/features.md), x[0] = f1.\n\n{}\n{}",
            self.amplitude.expr.to_rust("dynamic_error_amp_um", &FEATURE_LABELS, FloatType::F64),
            self.phase.expr.to_rust("dynamic_error_phase_deg", &FEATURE_LABELS, FloatType::F64)
        )
    }

    /// The formulas as C source: `double dynamic_error_amp_um(const double *x)` and
    /// `dynamic_error_phase_deg`, `x[0]` being f1. `origin` names the training data.
    pub fn c_source(&self, origin: &str) -> String {
        format!(
            "/* Generated by sts-twin fit from {origin}.\n   Inputs are the features f1..f12 of the accelerometer (docs/features.md), x[0] = f1. */\n\n{}\n{}",
            self.amplitude.expr.to_c("dynamic_error_amp_um", &FEATURE_LABELS, FloatType::F64),
            self.phase.expr.to_c("dynamic_error_phase_deg", &FEATURE_LABELS, FloatType::F64)
        )
    }

    /// The firmware program, decoded from the postcard bytes and validated.
    pub fn firmware_program(&self) -> Result<Program, ModelError> {
        let bytes = hex_decode(&self.program_postcard_hex).ok_or(ModelError::NotHex)?;
        // The version first: another version's terms may not decode as this one's.
        if let Ok((found, _)) = postcard::take_from_bytes::<u16>(&bytes) {
            let expected = sts_twin_core::program::PROGRAM_VERSION;
            if found != expected {
                return Err(ModelError::ProgramVersion { found, expected });
            }
        }
        let (program, rest): (Program, &[u8]) =
            postcard::take_from_bytes(&bytes).map_err(|error| ModelError::NotPostcard { error })?;
        if !rest.is_empty() {
            return Err(ModelError::TrailingBytes { count: rest.len() });
        }
        program.validate().map_err(|error| ModelError::InvalidProgram { error })?;
        Ok(program)
    }
}

/// Refuses a string longer than [`MAX_MODEL_STRING_BYTES`] anywhere in `value`, naming its
/// field (`at` is the path so far).
fn check_strings(value: &serde_json::Value, at: &mut String) -> Result<(), ModelFileError> {
    use serde_json::Value;
    match value {
        Value::String(s) if s.len() > MAX_MODEL_STRING_BYTES => Err(ModelFileError::Value {
            field: at.trim_start_matches('.').to_string(),
            message: format!(
                "is a string of {} bytes, longer than any model file holds ({MAX_MODEL_STRING_BYTES})",
                s.len()
            ),
        }),
        Value::Array(items) => items.iter().enumerate().try_for_each(|(i, v)| {
            let len = at.len();
            at.push_str(&format!("[{i}]"));
            let r = check_strings(v, at);
            at.truncate(len);
            r
        }),
        Value::Object(map) => map.iter().try_for_each(|(k, v)| {
            let len = at.len();
            at.push('.');
            at.push_str(if k.len() > 64 { "(a long key)" } else { k });
            let r = if k.len() > MAX_MODEL_STRING_BYTES {
                Err(ModelFileError::Value {
                    field: at.trim_start_matches('.').to_string(),
                    message: format!("is a key of {} bytes, longer than any model file holds", k.len()),
                })
            } else {
                check_strings(v, at)
            };
            at.truncate(len);
            r
        }),
        _ => Ok(()),
    }
}

/// Refuses an `effects` entry naming an effect this release does not know.
fn check_effects(value: &serde_json::Value) -> Result<(), ModelFileError> {
    let Some(effects) = value.get("effects").and_then(|e| e.as_array()) else { return Ok(()) };
    for (i, record) in effects.iter().enumerate() {
        let name = record.get("effect").and_then(|n| n.as_str()).unwrap_or_default();
        if name != SERVO_AXIS && Effect::from_name(name).is_none() {
            return Err(ModelFileError::Value {
                field: format!("effects[{i}].effect"),
                message: format!("is {name:?}, not an effect this release knows ({SERVO_AXIS}, {})", Effect::names()),
            });
        }
    }
    Ok(())
}

/// serde_json's message without its trailing " at line L column C" (given separately).
fn json_message(e: &serde_json::Error) -> String {
    let text = e.to_string();
    match text.rfind(" at line ") {
        Some(i) => text[..i].to_string(),
        None => text,
    }
}

/// Lower-case hex of `bytes`.
pub fn hex_encode(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Bytes of a hex string.
pub fn hex_decode(text: &str) -> Option<Vec<u8>> {
    if !text.len().is_multiple_of(2) {
        return None;
    }
    (0..text.len()).step_by(2).map(|i| u8::from_str_radix(text.get(i..i + 2)?, 16).ok()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_non_finite_statistic_is_written_as_null_and_read_back() {
        // A phase R^2 over groups without variance is -inf: JSON writes null, which must
        // read back (the refit of a presliding-hysteresis dataset wrote one).
        let validation = Validation {
            folds: 5,
            amplitude_r2: 0.99,
            phase_r2: f64::NEG_INFINITY,
            waveform_mae_um: 0.004,
            waveform_rms_um: 0.005,
            groups: vec![],
        };
        let json = serde_json::to_string(&validation).unwrap();
        assert!(json.contains("\"phase_r2\":null"), "{json}");
        let back: Validation = serde_json::from_str(&json).unwrap();
        assert!(back.phase_r2.is_nan());
        assert_eq!(back.amplitude_r2, 0.99);
    }
}
