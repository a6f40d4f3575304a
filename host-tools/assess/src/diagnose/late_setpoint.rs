//! A late setpoint, looked for in the data's own error when no candidate explains a twin's
//! residual at the command frequency.
//!
//! The twin's formulas read the error's amplitude from the accelerometer, and at the bottom
//! of the band the accelerometer barely sees the motion (5 Hz x 10 um is 0.01 m/s^2, a few of
//! its ADC's steps): a machine whose error there is small, as a tuned servo's is, loses little
//! by it. A delay ahead of the servo loop (a slow command path, an interpolator or bus between
//! the trajectory and the loop) makes the error there large, `cmd(t - tau) - cmd(t)`: in
//! quadrature with the motion and in proportion to the frequency and the stroke. A twin fitted
//! on that data (the lab's workflow) then leaves it at the slowest groups in steps of the
//! accelerometer's resolution, and the candidate scored on that residual (a delay of the
//! measured motion at every frequency) finds nothing of its shape, since the formulas follow
//! the delay everywhere the accelerometer sees it. The data's own error keeps the shape. So,
//! where the residual at the command frequency stands 1.5x above the data's floor, the twin
//! carries nothing driven by the command's velocity, and the error at the slowest frequency
//! is a delay's (in quadrature with the motion, the servo's own in-phase part small beside
//! it), the axis's linear response to the command (the velocity
//! bank that `fit --effect setpoint-delay` carries, [`sts_fit::effects::linear_response_evidence`])
//! is fitted on the error's phasors, held out by fold of groups, against the twin's own
//! residual there; the per-group reductions go through the same sign-flip test as every
//! candidate.

use crate::AssessError;
use sts_analysis::repeat::NOT_REPEATING_MIN_UM;
use sts_analysis::response::phasor_of;
use sts_model::{Effect, ModelFile};
use sts_twin_core::program::{TermInput, TickTerm};

use super::{DataError, Diagnosis, GroupCtx, PhasorGain, Ranked};

/// What the bank takes beyond the twin must stand this many times above the data's floor.
/// Not once: on a clean machine, too, the bank follows the slowest groups better than formulas
/// that read them from the accelerometer (on the emulator's clean machine by up to about 1.4x
/// the floor), and that is the twin's resolution there, not an effect to add; a setpoint
/// 150-400 us late makes it 1.6x and more.
pub const GAIN_OVER_FLOOR: f64 = 1.5;

/// How far short of a delay's -90 degrees the error's phase at the slowest frequency may lie:
/// the delay must dominate the error there, its part in phase with the motion (the servo's
/// own, a stiffness's) at most `tan(9 deg)`, about a sixth, of the delay's. The bank takes
/// more than the twin on any linear machine whose slowest groups the accelerometer barely
/// sees, so what tells a late setpoint is that its error is the error there: the emulator's
/// clean machine and its above-band modes sit 10.5 deg short (its 250 us pipeline against the
/// servo's in-phase error), setpoints 143-395 us later 6.6-4.0 deg short.
pub const DELAY_PHASE_SHORT_DEG: f64 = 9.0;

/// How far past -90 degrees it may lie. A delay's error `e^(-j w tau) - 1` stays in
/// quadrature to second order (past it by `w tau / 2`: 0.3 deg at 1 Hz for 1.5 ms); a servo's
/// own lag behind the command, a position loop without full velocity feedforward (a type-1
/// loop), is the same at the slowest groups but first-order, `-j w T / (1 + j w / k)`, past
/// quadrature by `atan(w / k)`: the foreign machine's (30 Hz loop, 60% feedforward, 2.1 ms)
/// sits 3.7 deg past at 2 Hz. That lag belongs to the servo, not to a late setpoint.
pub const DELAY_PHASE_PAST_DEG: f64 = 1.0;

/// Whether the model's program already predicts from the command: a velocity bank (the
/// axis's linear response, a delay ahead of it included) or the servo-axis twin, whose
/// command delay is identified in whole ticks (it carries a late setpoint, so this stage does
/// not look for one there).
fn carries_command_response(model: &ModelFile) -> bool {
    model.firmware_program().is_ok_and(|p| {
        p.terms
            .iter()
            .any(|t| matches!(t, TickTerm::Axis(_) | TickTerm::Laguerre { input: TermInput::VelocitySign { .. }, .. }))
    })
}

/// The stage's ranked result, when it applies and the data holds a late setpoint; `None`
/// otherwise. `data_error` of the dataset as the model reads it (its probe gain divided out),
/// `ctx` its groups.
pub(super) fn look(
    data_error: &DataError,
    model: &ModelFile,
    ctx: &[GroupCtx],
    d: &Diagnosis,
) -> Result<Option<Ranked>, AssessError> {
    let floor_um = d.repeatability.known_floor_um().max(NOT_REPEATING_MIN_UM);
    // Below this the bank could not take what the test asks of it.
    if carries_command_response(model) || d.structure.fundamental.rms_um <= GAIN_OVER_FLOOR * floor_um {
        return Ok(None);
    }
    let evidence = data_error.phasors()?.linear_response();
    let off_deg = evidence.slowest_phase_deg + 90.0;
    if !((-DELAY_PHASE_PAST_DEG..=DELAY_PHASE_SHORT_DEG).contains(&off_deg) && evidence.slowest_lag_us > 0.0) {
        return Ok(None);
    }
    // The twin's residual at the command frequency per group, against what the bank leaves.
    let Some(gain) = PhasorGain::of(ctx.iter().map(|c| {
        let r = phasor_of(&c.sin_theta, &c.cos_theta, &c.residual);
        (r.0 * r.0 + r.1 * r.1, evidence.bank_only_ss_um2[c.sample.index])
    })) else {
        return Ok(None);
    };
    let lag_deg_at_40 = 360.0 * 40.0 * evidence.slowest_lag_us * 1e-6;
    Ok(Some(Ranked {
        effect: Effect::SetpointDelay.name().into(),
        explained_fraction: gain.explained_fraction,
        p_value: gain.p_value,
        groups_improved: gain.improved(),
        params: vec![("delay_us".into(), evidence.slowest_lag_us), ("phase_lag_at_40hz_deg".into(), lag_deg_at_40)],
        evidence: format!(
            "the twin leaves {:.1} nm at the command frequency ({:.1}x the data's floor); at the slowest groups ({} Hz) the error lags the motion by {:.1} deg, as a delay's does, and the whole response is {:.0} us late there ({:.2} deg at 40 Hz, every delay between the trajectory and the tool); the axis's linear response fitted from the command (a velocity bank) takes {:.0}% of what the twin leaves at the command frequency, held out ({} of {} groups better): a delay ahead of the servo loop (the setpoint or the command path) whose error the twin's formulas, reading the accelerometer, do not follow where it barely sees the motion",
            d.structure.fundamental.rms_um * 1e3,
            d.structure.fundamental.rms_um / floor_um,
            evidence.slowest_freq_hz,
            -evidence.slowest_phase_deg,
            evidence.slowest_lag_us,
            lag_deg_at_40,
            gain.explained_fraction * 100.0,
            gain.improved(),
            gain.reductions.len()
        ),
        significant: gain.significant(GAIN_OVER_FLOOR * floor_um),
        explained_rms_um: gain.explained_rms_um,
        without_fundamental: false,
    }))
}
