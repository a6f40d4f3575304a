//! The model file `sts-twin-model/1`: the fitted formulas as text, their fit statistics,
//! the feature settings they were trained on, and the firmware program ready to upload.
//!
//! The program (postcard bytes, hex) is authoritative: it is what the firmware runs and what
//! the host evaluates to predict, so that host predictions and firmware outputs agree bit
//! for bit. The formulas and statistics are for people.

mod compile;

pub use compile::{compile_program, expr_to_code};

use std::path::Path;

use anyhow::Context as _;
use serde::{Deserialize, Serialize};
use sts_symreg::Expr;
use sts_twin_core::features::FeatureConfig;
use sts_twin_core::program::Program;

/// The value of the `format` field.
pub const MODEL_FORMAT: &str = "sts-twin-model/1";

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
    pub r2_train: f64,
    /// R^2 of the held-out predictions of the cross-validation.
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
    pub loss: f64,
    /// Node count.
    pub complexity: usize,
    /// The selection score.
    pub score: f64,
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
    pub measured_amp_um: f64,
    /// Held-out predicted amplitude, um.
    pub predicted_amp_um: f64,
    /// Measured dynamic-error phase, degrees.
    pub measured_phase_deg: f64,
    /// Held-out predicted phase, degrees.
    pub predicted_phase_deg: f64,
    /// Mean absolute error of the predicted waveform over the last second, um.
    pub waveform_mae_um: f64,
    /// RMS error of the predicted waveform over the last second, um.
    pub waveform_rms_um: f64,
}

/// The cross-validation summary.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Validation {
    /// Number of folds (groups are assigned round robin).
    pub folds: usize,
    /// R^2 of held-out amplitudes over all groups.
    pub amplitude_r2: f64,
    /// R^2 of held-out phases over the groups whose phase is defined.
    pub phase_r2: f64,
    /// Mean absolute error of the held-out predicted waveform over all groups, um.
    pub waveform_mae_um: f64,
    /// RMS error of the held-out predicted waveform over all groups, um.
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
}

impl ModelFile {
    /// Reads and checks a model file; errors name the file (and line and column for JSON).
    pub fn read(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path).with_context(|| format!("cannot read model file {}", path.display()))?;
        let model: ModelFile = serde_json::from_str(&text).with_context(|| format!("{}: not a valid model file", path.display()))?;
        if model.format != MODEL_FORMAT {
            anyhow::bail!("{}: field `format` is {:?}, expected {MODEL_FORMAT:?}", path.display(), model.format);
        }
        model.firmware_program().with_context(|| format!("{}: field `program_postcard_hex`", path.display()))?;
        Ok(model)
    }

    /// Writes the model file as pretty JSON.
    pub fn write(&self, path: &Path) -> anyhow::Result<()> {
        let text = serde_json::to_string_pretty(self)?;
        std::fs::write(path, text + "\n").with_context(|| format!("cannot write model file {}", path.display()))
    }

    /// The firmware program, decoded from the postcard bytes and validated.
    pub fn firmware_program(&self) -> anyhow::Result<Program> {
        let bytes = hex_decode(&self.program_postcard_hex).context("not hexadecimal")?;
        let program: Program = postcard::from_bytes(&bytes).map_err(|e| anyhow::anyhow!("not a postcard program: {e}"))?;
        program.validate().map_err(|e| anyhow::anyhow!("invalid program: {e}"))?;
        Ok(program)
    }
}

/// Lower-case hex of `bytes`.
pub fn hex_encode(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Bytes of a hex string.
pub fn hex_decode(text: &str) -> Option<Vec<u8>> {
    if text.len() % 2 != 0 {
        return None;
    }
    (0..text.len()).step_by(2).map(|i| u8::from_str_radix(text.get(i..i + 2)?, 16).ok()).collect()
}
