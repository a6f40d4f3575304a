//! `explain`: the lab's loop run by itself. Fit a twin (or start from a given one), diagnose
//! its residual on the same data, give the twin the named effect, refit, diagnose again;
//! until `diagnose` names nothing (the residual is at the data's floor, or no term that
//! reshapes the response at the command frequency lowers it by [`UNNAMED_MIN_GAIN`]), the named effect
//! does not lower the error by [`NAMED_MIN_GAIN`], it cannot be added, or the effect budget is
//! spent. No effect is kept whose own term does not lower the error.
//!
//! Each step's "before" is the twin's error on the data (a twin fitted on it: its own
//! 5-fold held-out waveform RMS; a given base twin: its waveform RMS on the data, every group
//! held out for it) and "after" the refitted twin's held-out RMS, so the ladder compares like
//! with like from the second step on.

use rayon::prelude::*;
use serde::Serialize;
use sts_analysis::repeat::rms_without;
use sts_dataset::Dataset;
use sts_fit::effects::{fit_with, EffectRecord};
use sts_fit::{fit, FitConfig, FitError};
use sts_model::{Effect, ModelFile};

use crate::compare::{compare, Comparison};
use crate::diagnose::{diagnose, groups_needed, Diagnosis};
use crate::AssessError;

/// Settings of the loop.
#[derive(Clone, Debug)]
pub struct ExplainConfig {
    /// The formulas' fit (seed, folds, budgets).
    pub fit: FitConfig,
    /// Effects added at most (a base twin's own effects not counted).
    pub max_effects: usize,
}

/// A twin to start from instead of fitting one.
pub struct Base {
    /// The model.
    pub model: ModelFile,
    /// The effects it already carries (its file's `effects` field).
    pub effects: Vec<EffectRecord>,
}

/// One rung of the ladder: an effect named and added.
#[derive(Clone, Debug, Serialize)]
pub struct Step {
    /// Canonical effect name.
    pub effect: String,
    /// What `diagnose` saw before it was added: explained fraction of the held-out residual.
    pub explained_fraction: f64,
    /// The sign-flip test's p-value.
    pub p_value: f64,
    /// The evidence in words.
    pub evidence: String,
    /// The effect's parameters as the refitted twin identified them (name with unit, value).
    pub params: Vec<(String, f64)>,
    /// The twin's waveform RMS on the data before the step, um.
    pub waveform_rms_um_before: f64,
    /// The refitted twin's held-out waveform RMS, um.
    pub waveform_rms_um_after: f64,
}

/// Why the loop stopped.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Stop {
    /// `diagnose` named nothing: no candidate explains more than the data's floor.
    None,
    /// `diagnose` named nothing, but on so few groups that no candidate could have been
    /// significant ([`crate::diagnose::groups_needed`]): the residual may still hold an effect.
    TooFewGroups {
        /// The groups diagnosed.
        groups: usize,
        /// The fewest on which the test can name an effect.
        needed: usize,
    },
    /// The effect budget is spent while `diagnose` still names one.
    MaxEffects {
        /// The effect it named next.
        next: String,
    },
    /// The twin already carries the named effect: its term does not capture it all.
    AlreadyCarried {
        /// The effect.
        effect: String,
    },
    /// Adding the named effect did not lower the held-out error by [`NAMED_MIN_GAIN`]; the twin
    /// before it is kept.
    NoGain {
        /// The effect.
        effect: String,
        /// The held-out error with it, um.
        waveform_rms_um: f64,
    },
    /// The effect could not be added (for example, over the firmware's budget with the others).
    CannotAdd {
        /// The effect.
        effect: String,
        /// Why.
        reason: String,
    },
}

impl Stop {
    /// One sentence.
    pub fn describe(&self) -> String {
        match self {
            Stop::None => "none: no candidate explains more of the residual than the data's own floor".into(),
            Stop::TooFewGroups { groups, needed } => format!(
                "too few groups: on {groups} no candidate can be significant, so nothing was named and the residual may still hold an effect; measure at least {needed} groups"
            ),
            Stop::MaxEffects { next } => format!("the effect budget is spent; diagnose names {next} next"),
            Stop::AlreadyCarried { effect } => {
                format!(
                    "diagnose names {effect} again, which the twin already carries: its term does not capture it all"
                )
            }
            Stop::NoGain { effect, waveform_rms_um } => format!(
                "adding {effect} did not lower the held-out error by {:.0}% ({:.1} nm with it); the twin before it is kept",
                NAMED_MIN_GAIN * 100.0,
                waveform_rms_um * 1e3
            ),
            Stop::CannotAdd { effect, reason } => format!("{effect} cannot be added: {reason}"),
        }
    }

    /// `"none"`, or the kind of stop.
    pub fn verdict(&self) -> &'static str {
        match self {
            Stop::None => "none",
            Stop::TooFewGroups { .. } => "too-few-groups",
            Stop::MaxEffects { .. } => "max-effects",
            Stop::AlreadyCarried { .. } => "already-carried",
            Stop::NoGain { .. } => "no-gain",
            Stop::CannotAdd { .. } => "cannot-add",
        }
    }
}

/// The ladder and the final twin.
pub struct Explanation {
    /// The starting twin's error on the data, um (before any step).
    pub start_waveform_rms_um: f64,
    /// The rungs.
    pub steps: Vec<Step>,
    /// Why it stopped.
    pub stop: Stop,
    /// The last diagnosis (of the final twin).
    pub last: Diagnosis,
    /// The final twin.
    pub model: ModelFile,
    /// The final twin's effects (for its file's `effects` field).
    pub effects: Vec<EffectRecord>,
    /// The final twin's error on the data, um.
    pub waveform_rms_um: f64,
}

/// What the loop reports as it goes.
pub enum ExplainProgress<'a> {
    /// The starting twin is being fitted.
    Fitting,
    /// A twin is being diagnosed (its error on the data, um).
    Diagnosing {
        /// Effects it carries.
        effects: &'a [String],
    },
    /// A twin with these effects is being fitted.
    Refitting {
        /// Effects it will carry.
        effects: &'a [String],
    },
}

/// Why `explain` failed (a step that merely cannot go on is a [`Stop`], not an error).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ExplainError {
    /// Fitting the starting twin failed.
    #[error("fitting the starting twin: {0}")]
    Fit(#[from] FitError),
    /// Comparing or diagnosing failed.
    #[error(transparent)]
    Assess(#[from] AssessError),
}

/// A twin's error on the ladder's data: the whole and per group.
struct Standing {
    /// Waveform RMS over every group, um (held out for a twin fitted on the data).
    rms_um: f64,
    /// Per group: file and waveform RMS, um.
    groups: Vec<(String, f64)>,
}

impl Standing {
    fn of_fit(model: &ModelFile) -> Self {
        let groups = model.validation.groups.iter().map(|g| (g.file.clone(), g.waveform_rms_um)).collect();
        Self { rms_um: model.validation.waveform_rms_um, groups }
    }

    fn of_comparison(c: &Comparison) -> Self {
        Self {
            rms_um: c.waveform_rms_um,
            groups: c.groups.iter().map(|g| (g.file.clone(), g.waveform_rms_um)).collect(),
        }
    }

    /// The RMS over the groups whose error repeats from one period to the next (`skip`: the
    /// files of those that do not), um; the whole RMS where none is skipped. Where the axis
    /// moves by itself (a hunting limit cycle) no twin driven by the command can predict the
    /// error, and those groups' share swamps what a step gains elsewhere (a second mode that
    /// nearly halves the error of the groups that repeat gains a tenth of the whole).
    fn repeating_rms_um(&self, skip: &[String]) -> f64 {
        rms_without(self.groups.iter().map(|(file, rms)| (file.as_str(), *rms)), skip).unwrap_or(self.rms_um)
    }
}

/// Significant candidates a rung tries, strongest first, before it stops.
const MAX_TRIES: usize = 3;

/// Least relative fall of the held-out error that keeps a named effect: a term of its own
/// lets any refit bend a little closer to the data, and a name is a claim about the machine
/// (the suites count an effect whose refit gains less as absorbed by the twin).
pub const NAMED_MIN_GAIN: f64 = 0.1;

/// Least relative fall of the held-out error that keeps the axis twin's second mode when
/// `diagnose` did not name it: an axis with one mode gains a little from a second one too.
const SECOND_MODE_MIN_GAIN: f64 = 0.2;

/// Least relative fall of the held-out error that keeps a named effect with a partner when
/// the named effect alone brought no gain ([`best_partner`]).
const PARTNER_MIN_GAIN: f64 = 0.2;

/// Where the strongest named effect (`named`, of the ranking) did not lower the error when
/// refitted alone: refits it beside each of the [`MAX_TRIES`] strongest other candidates with
/// a term of their own, significant or not, and returns the partner and the refit of the pair
/// that ends lowest (kept by the caller if it lowers the error by [`PARTNER_MIN_GAIN`]). An effect the twin does
/// not carry can bend the refitted formulas enough to hide what the named one's term brings:
/// a ripple turns the phase formula at the slowest groups, so a coupling's refit alone can end
/// worse than without it while both together reach the data's floor.
fn best_partner(
    dataset: &Dataset,
    description: &str,
    config: &ExplainConfig,
    d: &Diagnosis,
    named: usize,
    carried: &[String],
    progress: &mut dyn FnMut(ExplainProgress),
) -> Option<(usize, Refit)> {
    let mut partners: Vec<usize> = (0..d.ranking.len())
        .filter(|&j| j != named && d.ranking[j].explained_fraction > 0.0)
        .filter(|&j| {
            let effect = &d.ranking[j].effect;
            // Only effects with terms of their own (the others are carried by the formulas).
            Effect::from_name(effect).is_some_and(Effect::beyond_the_fundamental) && !carried.contains(effect)
        })
        .collect();
    // Strongest first (the ranking's order on a tie).
    partners
        .sort_by(|&a, &b| d.ranking[b].explained_fraction.total_cmp(&d.ranking[a].explained_fraction).then(a.cmp(&b)));
    partners.truncate(MAX_TRIES);
    let skip = &d.not_repeating_files();
    let tries = partners
        .into_iter()
        .map(|j| (j, [carried, &[d.ranking[named].effect.clone(), d.ranking[j].effect.clone()]].concat()))
        .collect();
    // The first of the lowest in the order above.
    let mut best: Option<(usize, Refit)> = None;
    for (j, (m, r)) in refit_each(dataset, description, config, tries, progress) {
        let lowest = best.as_ref().map_or(f64::INFINITY, |(_, (b, _))| Standing::of_fit(b).repeating_rms_um(skip));
        if Standing::of_fit(&m).repeating_rms_um(skip) < lowest {
            best = Some((j, (m, r)));
        }
    }
    best
}

/// Whether the effects `carried` hold one that the servo-axis twin carries.
fn carries_axis_twin(carried: &[String]) -> bool {
    carried.iter().any(|c| Effect::name_carried_by_the_axis_twin(c))
}

/// The parameters `records` give for `effect` (none where it has no record).
fn params_of(records: &[EffectRecord], effect: &str) -> Vec<(String, f64)> {
    records.iter().find(|r| r.effect == effect).map_or_else(Vec::new, |r| r.params.clone())
}

/// Where the twin carries a servo-axis twin with one mode and `diagnose` names again an effect
/// that twin carries, or names nothing though the residual stands well above the data's floor
/// ([`Diagnosis::unexplained`]): the structural-mode candidate, to be tried as the axis twin's
/// second mode. The forces of friction, hysteresis or a ripple ring a mode the twin lacks at
/// the command's harmonics, right when they act, so its residual looks like the carried
/// effect's or like no candidate's.
fn second_mode_try(d: &Diagnosis, carried: &[String]) -> Option<usize> {
    let mode = Effect::StructuralMode.name().to_string();
    let has_axis = carries_axis_twin(carried);
    let axis_named_again = Effect::name_carried_by_the_axis_twin(&d.verdict) && carried.contains(&d.verdict);
    let unexplained = d.verdict == "none" && d.unexplained.is_some();
    (has_axis && !carried.contains(&mode) && (axis_named_again || unexplained))
        .then(|| d.ranking.iter().position(|r| r.effect == mode))
        .flatten()
}

/// Least relative fall of the held-out error that keeps a term tried at the command frequency
/// when `diagnose` named nothing ([`at_the_fundamental`]): the gain a name must bring on a
/// clean machine to be more than a twin bending closer to its data.
pub const UNNAMED_MIN_GAIN: f64 = 0.3;

/// A refit within this factor of the best one counts as as good; the one with the fewest
/// parameters among them is kept, as the formulas' selection keeps the simplest.
const AS_GOOD_WITHIN: f64 = 1.1;

/// A refitted twin and its effects.
type Refit = (ModelFile, Vec<EffectRecord>);

/// Refits the twin with each of `tries` (a candidate's place in the ranking, the effects of
/// its refit), every one reported first, then fitted side by side: the choices that follow
/// compare them all, and each fit is deterministic whatever runs beside it. The refits that
/// fit, in the order of `tries`.
fn refit_each(
    dataset: &Dataset,
    description: &str,
    config: &ExplainConfig,
    tries: Vec<(usize, Vec<String>)>,
    progress: &mut dyn FnMut(ExplainProgress),
) -> Vec<(usize, Refit)> {
    for (_, with) in &tries {
        progress(ExplainProgress::Refitting { effects: with });
    }
    tries
        .into_par_iter()
        .filter_map(|(i, with)| {
            fit_with(dataset, &with, description, &config.fit, &mut |_| {}).ok().map(|fit| (i, fit))
        })
        .collect()
}

/// Where `diagnose` named nothing, the twin carries no servo-axis twin, and the residual
/// stands well above the data's floor ([`Diagnosis::unexplained`]), most of it at the command
/// frequency: the formulas do not reproduce the axis's response there, which a term that
/// reshapes it (a mode's, a delay's, a scale's) may. Refits the twin with each such candidate,
/// whatever the sign of its explained fraction (diagnose scores a linear correction of the
/// formulas' residual, not the twin a refit builds: on the clean foreign two-mass machine every
/// such score was below zero where the mode's refit took the error from 27.9 to 8.8 nm), and
/// returns, of the refits that lower the error by [`UNNAMED_MIN_GAIN`] and end within
/// [`AS_GOOD_WITHIN`] of the lowest, one that diagnose's score points to where there is one
/// (a name is a claim about the machine), the simplest: a plant whose response the formulas
/// cannot follow, a late setpoint the formulas bent towards.
#[allow(clippy::too_many_arguments)]
fn at_the_fundamental(
    dataset: &Dataset,
    description: &str,
    config: &ExplainConfig,
    d: &Diagnosis,
    carried: &[String],
    skip: &[String],
    now_um: f64,
    progress: &mut dyn FnMut(ExplainProgress),
) -> Option<(usize, Refit)> {
    let has_axis = carries_axis_twin(carried);
    let s = &d.structure;
    let at_fundamental = s.fundamental.rms_um.powi(2) >= 0.5 * s.residual_rms_um.powi(2);
    if d.verdict != "none" || d.unexplained.is_none() || has_axis || !at_fundamental {
        return None;
    }
    // Each candidate that reshapes the response, with the effects of its refit.
    let tries = d
        .ranking
        .iter()
        .enumerate()
        .filter(|(_, candidate)| {
            let reshapes = Effect::from_name(&candidate.effect).is_some_and(|e| !e.beyond_the_fundamental());
            reshapes && !carried.contains(&candidate.effect)
        })
        .map(|(i, candidate)| (i, [carried, std::slice::from_ref(&candidate.effect)].concat()))
        .collect();
    // Each: its place in the ranking, its error, its parameters, the refit.
    let refits: Vec<(usize, f64, usize, Refit)> = refit_each(dataset, description, config, tries, progress)
        .into_iter()
        .filter_map(|(i, (m, r))| {
            let after_um = Standing::of_fit(&m).repeating_rms_um(skip);
            (after_um.is_finite() && after_um < (1.0 - UNNAMED_MIN_GAIN) * now_um).then(|| {
                let params = params_of(&r, &d.ranking[i].effect).len();
                (i, after_um, params, (m, r))
            })
        })
        .collect();
    let tried: Vec<Reshaped> = refits
        .iter()
        .map(|r| Reshaped { after_um: r.1, params: r.2, supported: d.ranking[r.0].explained_fraction > 0.0 })
        .collect();
    let kept = reshaping_to_keep(&tried)?;
    refits.into_iter().nth(kept).map(|(i, _, _, refit)| (i, refit))
}

/// A refit [`at_the_fundamental`] tried: its error, its term's parameter count, and whether
/// diagnose's score points to its term (a positive explained fraction).
#[derive(Clone, Copy, Debug)]
struct Reshaped {
    after_um: f64,
    params: usize,
    supported: bool,
}

/// Which of the refits to keep: among those within [`AS_GOOD_WITHIN`] of the lowest error,
/// one diagnose points to first, then the fewest parameters, then the lower error.
fn reshaping_to_keep(tried: &[Reshaped]) -> Option<usize> {
    let lowest_um = tried.iter().map(|r| r.after_um).fold(f64::INFINITY, f64::min);
    tried
        .iter()
        .enumerate()
        .filter(|(_, r)| r.after_um <= AS_GOOD_WITHIN * lowest_um)
        .min_by(|(_, a), (_, b)| {
            b.supported.cmp(&a.supported).then(a.params.cmp(&b.params)).then(a.after_um.total_cmp(&b.after_um))
        })
        .map(|(i, _)| i)
}

/// Runs the loop on `dataset`, from `base` or from a twin fitted on the data.
pub fn explain(
    dataset: &Dataset,
    description: &str,
    base: Option<Base>,
    config: &ExplainConfig,
    progress: &mut dyn FnMut(ExplainProgress),
) -> Result<Explanation, ExplainError> {
    let (mut model, mut records, mut standing) = match base {
        Some(b) => {
            let (c, _) = compare(dataset, &b.model)?;
            (b.model, b.effects, Standing::of_comparison(&c))
        }
        None => {
            progress(ExplainProgress::Fitting);
            let m = fit(dataset, description, &config.fit, &mut |_| {})?;
            let s = Standing::of_fit(&m);
            (m, Vec::new(), s)
        }
    };
    let start_rms_um = standing.rms_um;
    let mut steps = Vec::new();
    loop {
        let names: Vec<String> = records.iter().map(|r| r.effect.clone()).collect();
        progress(ExplainProgress::Diagnosing { effects: &names });
        let d = diagnose(dataset, &model)?;
        // A step's gain is judged where the error repeats (see `Standing::repeating_rms_um`).
        let skip = d.not_repeating_files();
        let now_um = standing.repeating_rms_um(&skip);
        let gain_pct = |after: &ModelFile| (1.0 - Standing::of_fit(after).repeating_rms_um(&skip) / now_um) * 100.0;
        let over = if skip.is_empty() {
            String::new()
        } else {
            format!(" (over the groups whose error repeats; {} do not)", skip.len())
        };
        // The significant candidates the twin does not carry yet, strongest first: when the
        // first brings no gain (or cannot be added), the next may (a weaker effect named first
        // ahead of a stronger one that its term would carry, say).
        let mut tries: Vec<usize> = (0..d.ranking.len())
            .filter(|&i| d.ranking[i].significant && !names.contains(&d.ranking[i].effect))
            .take(MAX_TRIES)
            .collect();
        let named_stop = if d.verdict == "none" && d.group_files.len() < groups_needed() {
            Some(Stop::TooFewGroups { groups: d.group_files.len(), needed: groups_needed() })
        } else if d.verdict == "none" {
            Some(Stop::None)
        } else if tries.is_empty() {
            Some(Stop::AlreadyCarried { effect: d.verdict.clone() })
        } else if steps.len() >= config.max_effects {
            Some(Stop::MaxEffects { next: d.ranking[tries[0]].effect.clone() })
        } else {
            None
        };
        // Not named but tried last, and kept only for a clear gain; where it is not kept, the
        // ladder stops as the diagnosis alone would have it.
        let unnamed_try =
            second_mode_try(&d, &names).filter(|i| !tries.contains(i) && steps.len() < config.max_effects);
        tries.extend(unnamed_try);
        let stop = match &named_stop {
            Some(Stop::None | Stop::AlreadyCarried { .. }) if unnamed_try.is_some() => None,
            other => other.clone(),
        };
        // Where it stops, the twin so far is the answer.
        let done = |stop, last, steps, model, effects| {
            Ok(Explanation {
                start_waveform_rms_um: start_rms_um,
                steps,
                stop,
                last,
                model,
                effects,
                waveform_rms_um: standing.rms_um,
            })
        };
        if stop == Some(Stop::None)
            && steps.len() < config.max_effects
            && let Some((i, (m, r))) =
                at_the_fundamental(dataset, description, config, &d, &names, &skip, now_um, progress)
        {
            let tried = &d.ranking[i];
            steps.push(Step {
                effect: tried.effect.clone(),
                explained_fraction: tried.explained_fraction,
                p_value: tried.p_value,
                evidence: format!(
                    "diagnose named nothing, yet the residual stands well above the data's floor, most of it at the command frequency, where the formulas do not follow the axis's response; of the terms that reshape it, {}'s lowered the held-out error by {:.0}% (the one with the fewest parameters within {:.0}% of the best){over}",
                    tried.effect,
                    gain_pct(&m),
                    (AS_GOOD_WITHIN - 1.0) * 100.0
                ),
                params: params_of(&r, &tried.effect),
                waveform_rms_um_before: standing.rms_um,
                waveform_rms_um_after: m.validation.waveform_rms_um,
            });
            standing = Standing::of_fit(&m);
            model = m;
            records = r;
            continue;
        }
        if let Some(stop) = stop {
            return done(stop, d, steps, model, records);
        }
        let mut first_failure: Option<Stop> = None;
        let mut added = None;
        // The named effect whose partner is added alone (it brought nothing beside it).
        let mut partner_of: Option<usize> = None;
        for &i in &tries {
            let named = &d.ranking[i];
            let mut with: Vec<String> = names.clone();
            with.push(named.effect.clone());
            progress(ExplainProgress::Refitting { effects: &with });
            let refit = fit_with(dataset, &with, description, &config.fit, &mut |_| {});
            let failure = match refit {
                Err(e) => Stop::CannotAdd { effect: named.effect.clone(), reason: e.to_string() },
                Ok((m, _))
                    if m.validation.waveform_rms_um.is_nan()
                        || Standing::of_fit(&m).repeating_rms_um(&skip)
                            >= (1.0 - if Some(i) == unnamed_try { SECOND_MODE_MIN_GAIN } else { NAMED_MIN_GAIN })
                                * now_um =>
                {
                    Stop::NoGain { effect: named.effect.clone(), waveform_rms_um: m.validation.waveform_rms_um }
                }
                Ok(r) => {
                    added = Some((i, r));
                    break;
                }
            };
            first_failure.get_or_insert(failure);
        }
        // Every named try without gain: the first again, with a partner.
        if let (None, Some(&first), Some(Stop::NoGain { waveform_rms_um: alone_um, .. })) =
            (&added, tries.first(), &first_failure)
        {
            let named_alone = named_stop.is_none() && Some(first) != unnamed_try && alone_um.is_finite();
            let pair = if named_alone && steps.len() + 2 <= config.max_effects {
                best_partner(dataset, description, config, &d, first, &names, progress).filter(|(_, (m, _))| {
                    Standing::of_fit(m).repeating_rms_um(&skip) < (1.0 - PARTNER_MIN_GAIN) * now_um
                })
            } else {
                None
            };
            // The named effect is kept beside its partner only where it adds to the partner
            // alone (a partner tried above brought no gain by itself); otherwise the partner
            // alone is the step, as if named.
            let partner_alone = pair.as_ref().filter(|(j, _)| !tries.contains(j)).and_then(|(j, (pair_model, _))| {
                let mut with = names.clone();
                with.push(d.ranking[*j].effect.clone());
                progress(ExplainProgress::Refitting { effects: &with });
                let (m, r) = fit_with(dataset, &with, description, &config.fit, &mut |_| {}).ok()?;
                let pair_um = Standing::of_fit(pair_model).repeating_rms_um(&skip);
                (pair_um >= (1.0 - NAMED_MIN_GAIN) * Standing::of_fit(&m).repeating_rms_um(&skip))
                    .then_some((*j, (m, r)))
            });
            if let Some((j, (m, r))) = partner_alone {
                added = Some((j, (m, r)));
                partner_of = Some(first);
            } else if let Some((j, (m, r))) = pair {
                let (a, b) = (&d.ranking[first], &d.ranking[j]);
                let after_um = m.validation.waveform_rms_um;
                steps.push(Step {
                    effect: a.effect.clone(),
                    explained_fraction: a.explained_fraction,
                    p_value: a.p_value,
                    evidence: format!(
                        "{}; refitted alone it left the held-out error at {:.1} nm, kept with the next step, which needs it",
                        a.evidence,
                        alone_um * 1e3
                    ),
                    params: params_of(&r, &a.effect),
                    waveform_rms_um_before: standing.rms_um,
                    waveform_rms_um_after: *alone_um,
                });
                steps.push(Step {
                    effect: b.effect.clone(),
                    explained_fraction: b.explained_fraction,
                    p_value: b.p_value,
                    evidence: format!(
                        "{}; {} alone, tried beside {}, whose refit alone brought no gain: together they lowered the held-out error by {:.0}%{over}",
                        b.evidence,
                        if b.significant { "significant" } else { "not significant" },
                        a.effect,
                        gain_pct(&m)
                    ),
                    params: params_of(&r, &b.effect),
                    waveform_rms_um_before: *alone_um,
                    waveform_rms_um_after: after_um,
                });
                standing = Standing::of_fit(&m);
                model = m;
                records = r;
                continue;
            }
        }
        let Some((i, (next_model, next_records))) = added else {
            let stop = named_stop.or(first_failure).unwrap_or(Stop::None);
            return done(stop, d, steps, model, records);
        };
        let named = &d.ranking[i];
        let after_um = next_model.validation.waveform_rms_um;
        let params = params_of(&next_records, &named.effect);
        steps.push(Step {
            effect: named.effect.clone(),
            explained_fraction: named.explained_fraction,
            p_value: named.p_value,
            evidence: if let Some(a) = partner_of {
                format!(
                    "{}; {} alone, tried beside {}, which diagnose named but whose refit brought no gain: {} alone lowered the held-out error by {:.0}% and {} added nothing to it{over}",
                    named.evidence,
                    if named.significant { "significant" } else { "not significant" },
                    d.ranking[a].effect,
                    named.effect,
                    gain_pct(&next_model),
                    d.ranking[a].effect
                )
            } else if Some(i) == unnamed_try {
                format!(
                    "{}: a mode the servo-axis twin lacks rings where its effects act; the twin's second mode was tried and lowered the held-out error by {:.0}%{over}",
                    if d.verdict == "none" {
                        "diagnose named nothing, yet the residual stands well above the data's floor".to_string()
                    } else {
                        format!("diagnose named {} again, which the servo-axis twin carries", d.verdict)
                    },
                    gain_pct(&next_model)
                )
            } else {
                named.evidence.clone()
            },
            params,
            waveform_rms_um_before: standing.rms_um,
            waveform_rms_um_after: after_um,
        });
        standing = Standing::of_fit(&next_model);
        model = next_model;
        records = next_records;
    }
}

#[cfg(test)]
mod tests {
    use super::{reshaping_to_keep, Reshaped};

    fn refit(after_um: f64, params: usize, supported: bool) -> Reshaped {
        Reshaped { after_um, params, supported }
    }

    #[test]
    fn a_reshaping_term_diagnose_points_to_is_kept_first_then_the_simplest() {
        // The clean foreign two-mass machine: every score below zero; the late setpoint's two
        // parameters within 10% of the mode's five.
        assert_eq!(reshaping_to_keep(&[refit(0.0088, 5, false), refit(0.0096, 2, false)]), Some(1));
        // The mode pointed to: kept over the simpler term nobody pointed to.
        assert_eq!(reshaping_to_keep(&[refit(0.0088, 5, true), refit(0.0096, 2, false)]), Some(0));
        // Pointed to but more than 10% worse than the best: not as good, not kept.
        assert_eq!(reshaping_to_keep(&[refit(0.0110, 2, true), refit(0.0088, 5, false)]), Some(1));
        // Equal support and parameters: the lower error.
        assert_eq!(reshaping_to_keep(&[refit(0.0092, 2, true), refit(0.0090, 2, true)]), Some(1));
        assert_eq!(reshaping_to_keep(&[]), None);
    }
}
