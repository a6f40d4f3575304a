//! Model selection: which member of the complexity-accuracy Pareto front is the model.
//!
//! The rule (PySR's "best" rule with an error floor):
//! 1. Each member's error is its normalised mean squared error `NMSE = MSE / var(y)`
//!    (`1 - R^2`), clamped below at `exact_nmse`: errors under the floor are rounding noise
//!    of an exact fit, so every exact member ties in accuracy.
//! 2. Each member's score is the drop in log-error per unit of complexity from the previous
//!    (simpler) member: `score_i = -(ln NMSE_i - ln NMSE_{i-1}) / (c_i - c_{i-1})`; the first
//!    member is scored against the mean of `y` (NMSE 1 at complexity 1).
//! 3. Candidates are the members whose clamped error is within `accuracy_ratio` of the best
//!    clamped error; the selected model is the candidate with the highest score (ties go to
//!    the simpler one).
//!
//! Step 3 keeps too-simple members out (they are not accurate enough); step 2 keeps
//! needlessly complex members out (their extra nodes buy almost no error reduction), and
//! with the floor of step 1 an exact fit is never beaten by a bigger exact fit.

use serde::{Deserialize, Serialize};
use std::fmt::Write as _;

/// Parameters of the selection rule.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SelectionConfig {
    /// NMSE below which fits count as exact (and tie).
    pub exact_nmse: f64,
    /// Candidates must have an NMSE at most this factor above the best.
    pub accuracy_ratio: f64,
}

impl Default for SelectionConfig {
    fn default() -> Self {
        SelectionConfig { exact_nmse: 1e-10, accuracy_ratio: 1.5 }
    }
}

/// The outcome of selection on one front (scores in front order).
#[derive(Clone, Debug, PartialEq)]
pub struct Selection {
    /// Index of the selected member.
    pub selected: usize,
    /// Score of each member.
    pub scores: Vec<f64>,
    /// Whether each member was accurate enough to be a candidate.
    pub candidate: Vec<bool>,
}

/// Applies the rule to a front given as `(complexity, nmse)` in increasing complexity.
/// Returns `None` for an empty front.
///
/// ```
/// use sts_symreg::{select_model, SelectionConfig};
/// // A noisy-data front: the big drop at complexity 9 is the true form.
/// let front = [(1, 1.0), (5, 0.2), (9, 0.010), (13, 0.0095), (19, 0.0090)];
/// let s = select_model(&front, &SelectionConfig::default()).unwrap();
/// assert_eq!(s.selected, 2);
/// ```
pub fn select_model(front: &[(usize, f64)], cfg: &SelectionConfig) -> Option<Selection> {
    if front.is_empty() {
        return None;
    }
    let floor = cfg.exact_nmse.max(f64::MIN_POSITIVE);
    let clamped: Vec<f64> = front.iter().map(|&(_, e)| e.max(floor)).collect();
    let mut scores = Vec::with_capacity(front.len());
    for (i, &(c, _)) in front.iter().enumerate() {
        let (prev_c, prev_e) = if i == 0 { (1usize, 1.0f64.max(floor)) } else { (front[i - 1].0, clamped[i - 1]) };
        let dc = c.saturating_sub(prev_c);
        let s = if dc == 0 { 0.0 } else { -(clamped[i].ln() - prev_e.ln()) / dc as f64 };
        scores.push(if s.is_finite() { s.max(0.0) } else { 0.0 });
    }
    let best = clamped.iter().copied().fold(f64::INFINITY, f64::min);
    let candidate: Vec<bool> = clamped.iter().map(|&e| e <= best * cfg.accuracy_ratio).collect();
    let mut selected = None::<usize>;
    for i in 0..front.len() {
        if !candidate[i] {
            continue;
        }
        match selected {
            Some(j) if scores[i] <= scores[j] => {}
            _ => selected = Some(i),
        }
    }
    Some(Selection { selected: selected.unwrap_or(front.len() - 1), scores, candidate })
}

/// A human-readable account of the choice: the rule and one line per member.
pub(crate) fn explain(rows: &[(usize, f64, f64, String)], sel: &Selection, cfg: &SelectionConfig) -> String {
    let mut s = String::new();
    let (c, _, r2, _) = &rows[sel.selected];
    let _ = writeln!(
        s,
        "Selected the complexity-{c} member (R^2 = {r2:.6}): the highest score (drop in ln NMSE per \
         added node) among the members with NMSE within {}x of the best (NMSE below {:e} counts as exact).",
        cfg.accuracy_ratio, cfg.exact_nmse
    );
    let _ = writeln!(s, "{:>10} {:>12} {:>10} {:>8} {:>9}  formula", "complexity", "nmse", "r2", "score", "candidate");
    for (i, (c, nmse, r2, formula)) in rows.iter().enumerate() {
        let mark = if i == sel.selected { " <- selected" } else { "" };
        let _ = writeln!(
            s,
            "{c:>10} {nmse:>12.4e} {r2:>10.6} {:>8.3} {:>9}  {formula}{mark}",
            sel.scores[i],
            if sel.candidate[i] { "yes" } else { "no" }
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_fit_beats_bigger_exact_fits_and_simpler_approximations() {
        // P2-like: linear approximation, then the exact tanh form, then bloated exact forms.
        let front = [(1, 1.0), (5, 0.05), (9, 0.004), (14, 1e-29), (16, 1e-31), (19, 1e-32)];
        let s = select_model(&front, &SelectionConfig::default()).unwrap();
        assert_eq!(s.selected, 3);
        assert_eq!(s.candidate, vec![false, false, false, true, true, true]);
    }

    #[test]
    fn too_simple_members_are_not_candidates() {
        // A big early drop would win on score alone; it is not accurate enough.
        let front = [(1, 1.0), (3, 0.01), (9, 0.001)];
        let s = select_model(&front, &SelectionConfig::default()).unwrap();
        assert_eq!(s.selected, 2);
    }

    #[test]
    fn empty_front_selects_nothing() {
        assert!(select_model(&[], &SelectionConfig::default()).is_none());
    }
}
