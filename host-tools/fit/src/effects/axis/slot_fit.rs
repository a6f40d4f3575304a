//! The Levenberg-Marquardt fits of a candidate's slots ([`sts_numerics::lm`]).

use sts_numerics::lm::{self, Settings, Steps};

use super::candidate::{moved, Candidate, Slot};
use super::sample::{Fit, Sample};

/// The damping of the axis's fits: from a moderate start, never below 1e-7 (the servo's gains
/// are nearly interchangeable along a valley, where an undamped step overshoots), stopping where
/// a step gains less than 0.01%.
const AXIS_LM: Settings = Settings {
    iterations: 0,
    tries: 8,
    damping_start: 1e-2,
    damping_min: 1e-7,
    min_relative_gain: 1e-4,
    steps: Steps::Triangular,
};

/// Levenberg-Marquardt ([`sts_numerics::lm`]) over `free` slots, at most `iterations`.
pub(super) fn levenberg_marquardt(
    start: Candidate,
    free: &[Slot],
    sample: &Sample,
    what: Fit,
    iterations: usize,
) -> (Candidate, f64) {
    lm::minimize(&mut SlotFit { free, sample, what }, start, &Settings { iterations, ..AXIS_LM })
}

/// The fit of a candidate's `free` slots to the sample's readings: a Jacobian by forward
/// differences (the probes simulated side by side), each slot moved on its own scale and
/// kept within its bounds.
struct SlotFit<'s, 'a> {
    free: &'s [Slot],
    sample: &'s Sample<'a>,
    what: Fit,
}

/// The forward difference's step, in each slot's scale.
const PROBE_STEP: f64 = 1e-5;

impl lm::Problem for SlotFit<'_, '_> {
    type Point = Candidate;

    fn residuals(&mut self, c: &Candidate) -> Option<Vec<f64>> {
        Some(self.sample.residuals(c, self.what))
    }

    fn jacobian(&mut self, c: &Candidate, r: &[f64]) -> Option<Vec<Vec<f64>>> {
        let probes: Vec<Candidate> = self.free.iter().map(|&slot| moved(c, slot, PROBE_STEP)).collect();
        Some(
            self.sample
                .residuals_of(&probes, self.what)
                .into_iter()
                .map(|rs| rs.iter().zip(r).map(|(a, b)| (a - b) / PROBE_STEP).collect())
                .collect(),
        )
    }

    fn moved(&self, c: &Candidate, step: &[f64]) -> Option<Candidate> {
        Some(self.free.iter().zip(step).fold(*c, |trial, (&slot, &s)| moved(&trial, slot, s)))
    }
}
