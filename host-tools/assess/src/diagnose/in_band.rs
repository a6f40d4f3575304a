//! A structural mode inside the band, looked for in the data's own error when no candidate
//! explains a twin's residual at the command frequency.
//!
//! A twin fitted on the data it is diagnosed on (the lab's workflow) has bent its amplitude
//! and phase formulas towards a resonance between the test's frequencies as far as smooth
//! formulas can, so what it leaves is the resonance minus the formulas' bend: no longer a
//! resonance's shape, and the candidate scored on it falls short of significance (1 of 6
//! in-band draws named before this stage). The data's own error keeps the shape. So, where
//! the residual at the command frequency stands well above the data's floor and the twin
//! carries no resonance, the error's phasors are fitted with the axis's linear response (a
//! velocity bank) alone and with a resonance beside it, held out by fold of groups, and the
//! per-group reductions go through the same sign-flip test as every candidate. The search
//! is the one `fit --effect structural-mode` chooses from ([`sts_fit::effects::in_band_mode_evidence`]),
//! so this stage names a mode exactly where that fit would carry one with a term.

use crate::AssessError;
use sts_model::{Effect, ModelFile};
use sts_twin_core::program::TickTerm;

use super::{DataError, Diagnosis, PhasorGain, Ranked};
use sts_analysis::repeat::NOT_REPEATING_MIN_UM;

/// The residual at the command frequency must be this many times the data's floor (or
/// [`NOT_REPEATING_MIN_UM`]) for the stage to look.
pub const FUNDAMENTAL_OVER_FLOOR: f64 = 2.0;

/// Whether the model's program already carries a resonance term.
fn carries_resonance(model: &ModelFile) -> bool {
    model.firmware_program().is_ok_and(|p| p.terms.iter().any(|t| matches!(t, TickTerm::Resonance { .. })))
}

/// The stage's ranked result, when it applies and the data holds an in-band mode; `None`
/// otherwise. `data_error` of the dataset as the model reads it (its probe gain divided out).
pub(super) fn look(data_error: &DataError, model: &ModelFile, d: &Diagnosis) -> Result<Option<Ranked>, AssessError> {
    let floor_um = d.repeatability.known_floor_um().max(NOT_REPEATING_MIN_UM);
    if carries_resonance(model) || d.structure.fundamental.rms_um <= FUNDAMENTAL_OVER_FLOOR * floor_um {
        return Ok(None);
    }
    let Some(evidence) = data_error.phasors()?.in_band_mode() else {
        return Ok(None);
    };
    Ok(rank(&evidence, d))
}

/// Whether the data's own error holds a resonance inside the band beyond the axis's linear
/// response (the stage's test, whatever the twin leaves): what a mode named on a twin's
/// residual must also show before it stands against a late setpoint, whose error a twin's
/// formulas bend into a resonance's shape at the bottom of the band.
pub(super) fn mode_beyond_linear_response(data_error: &DataError, d: &Diagnosis) -> Result<bool, AssessError> {
    Ok(data_error.phasors()?.in_band_mode().and_then(|evidence| rank(&evidence, d)).is_some_and(|r| r.significant))
}

/// The mode's evidence through the test every candidate takes.
fn rank(evidence: &sts_fit::effects::InBandModeEvidence, d: &Diagnosis) -> Option<Ranked> {
    let floor_um = d.repeatability.known_floor_um().max(NOT_REPEATING_MIN_UM);
    let gain =
        PhasorGain::of(evidence.bank_only_ss_um2.iter().copied().zip(evidence.with_mode_ss_um2.iter().copied()))?;
    Some(Ranked {
        effect: Effect::StructuralMode.name().into(),
        explained_fraction: gain.explained_fraction,
        p_value: gain.p_value,
        groups_improved: gain.improved(),
        params: vec![("freq_hz".into(), evidence.freq_hz), ("damping".into(), evidence.damping)],
        evidence: format!(
            "the twin leaves {:.1} nm at the command frequency ({:.1}x the data's floor); in the data's own error a resonance at {:.1} Hz (damping {:.3}) beside the axis's linear response (a velocity bank) takes {:.0}% of what the bank alone leaves at the command frequency, held out ({} of {} groups better): a mode between the test's frequencies, whose peak the twin's formulas do not follow",
            d.structure.fundamental.rms_um * 1e3,
            d.structure.fundamental.rms_um / floor_um,
            evidence.freq_hz,
            evidence.damping,
            gain.explained_fraction * 100.0,
            gain.improved(),
            gain.reductions.len()
        ),
        significant: gain.significant(floor_um),
        explained_rms_um: gain.explained_rms_um,
        without_fundamental: false,
    })
}
