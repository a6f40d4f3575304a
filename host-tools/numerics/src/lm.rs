//! Levenberg-Marquardt: the damped Gauss-Newton loop of every nonlinear fit of the host (the
//! servo-axis twin's identification, symbolic regression's constants). Each iteration
//! prepares its Jacobian once, as [`Steps`] says, and tries dampings on it until a step
//! lowers the cost.
//!
//! Hand-written rather than the `levenberg-marquardt` crate (MINPACK's trust region): measured
//! in the axis identification's place, it reached the same fits no faster in all and slower
//! where the fit is quickest, and it would pin nalgebra's version.

use crate::lsq::{Damped, Normal, Stats};

/// A nonlinear least-squares problem: residuals `r(p)` to bring towards zero.
pub trait Problem {
    /// A point of the search: the parameters and whatever rides along with them.
    type Point: Clone;

    /// The residuals at `p`, `None` where they are not defined (a value not finite).
    fn residuals(&mut self, p: &Self::Point) -> Option<Vec<f64>>;

    /// The Jacobian of the residuals at `p` (where they are `r`), one column per entry of a
    /// step; `None` where it is not defined.
    fn jacobian(&mut self, p: &Self::Point, r: &[f64]) -> Option<Vec<Vec<f64>>>;

    /// The residuals at the start `p` and, where the problem gets them in the same pass, the
    /// Jacobian there (forward-mode derivatives carry the values along); by default the
    /// residuals alone, the Jacobian then asked of [`Self::jacobian`]. `None` where the
    /// residuals are not defined.
    #[allow(clippy::type_complexity)]
    fn start(&mut self, p: &Self::Point) -> Option<(Vec<f64>, Option<Vec<Vec<f64>>>)> {
        self.residuals(p).map(|r| (r, None))
    }

    /// `p` moved by `step` (one entry per Jacobian column), `None` where that leaves the
    /// problem's domain.
    fn moved(&self, p: &Self::Point, step: &[f64]) -> Option<Self::Point>;

    /// What the fit lowers: the residuals' RMS unless the problem says otherwise.
    fn cost(&self, r: &[f64]) -> f64 {
        rms(r)
    }
}

/// How long the loop runs and how it damps.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    /// Iterations at most (Jacobians evaluated).
    pub iterations: usize,
    /// Dampings tried per iteration, each ten times the last, before the fit stops.
    pub tries: usize,
    /// The damping of the first step, in Marquardt's scaling (relative to each column's
    /// squared norm).
    pub damping_start: f64,
    /// The least damping: an accepted step multiplies it by 0.3 down to this.
    pub damping_min: f64,
    /// A step that lowers the cost by less than this fraction of it is taken, and ends the fit.
    pub min_relative_gain: f64,
    /// How the steps are solved.
    pub steps: Steps,
}

/// How an iteration solves for its steps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Steps {
    /// The Jacobian reduced to its triangular factor once ([`Damped`]), each damping by QR:
    /// every digit, for Jacobians that may be ill-conditioned (the axis identification).
    Triangular,
    /// The normal equations by Cholesky ([`Normal`]): half the digits for a fraction of the
    /// work, where the columns are few and the fit runs many thousand times (symbolic
    /// regression's constants). A damping whose matrix is not positive definite counts as a
    /// step that failed.
    Normal,
}

/// An iteration's Jacobian, prepared for its steps.
enum System {
    Triangular(Damped),
    Normal(Normal),
}

impl System {
    fn new(steps: Steps, jacobian: &[Vec<f64>], minus_r: &[f64]) -> Option<Self> {
        match steps {
            Steps::Triangular => Damped::new(&[&Stats::from_columns(jacobian, minus_r)]).map(System::Triangular),
            Steps::Normal => Some(System::Normal(Normal::new(jacobian, minus_r))),
        }
    }

    fn step(&self, damping: f64) -> Option<Vec<f64>> {
        match self {
            System::Triangular(d) => Some(d.solve(damping)),
            System::Normal(n) => n.solve(damping),
        }
    }
}

/// The loop from `start`: the best point found and its cost (`f64::INFINITY` where the
/// residuals at `start` are not defined; the start is then returned as it was).
pub fn minimize<P: Problem>(problem: &mut P, start: P::Point, settings: &Settings) -> (P::Point, f64) {
    let mut point = start;
    let Some((mut r, mut start_jacobian)) = problem.start(&point) else { return (point, f64::INFINITY) };
    let mut cost = problem.cost(&r);
    let mut damping = settings.damping_start;
    for _ in 0..settings.iterations {
        if !cost.is_finite() || cost == 0.0 {
            break;
        }
        let Some(jacobian) = start_jacobian.take().or_else(|| problem.jacobian(&point, &r)) else { break };
        let minus_r: Vec<f64> = r.iter().map(|v| -v).collect();
        let Some(system) = System::new(settings.steps, &jacobian, &minus_r) else { break };
        let mut improved = false;
        for _ in 0..settings.tries {
            let trial = system.step(damping).and_then(|step| problem.moved(&point, &step));
            if let Some((trial, rt)) = trial.and_then(|t| problem.residuals(&t).map(|rt| (t, rt))) {
                let ct = problem.cost(&rt);
                if ct < cost {
                    improved = cost - ct > settings.min_relative_gain * cost;
                    (point, r, cost) = (trial, rt, ct);
                    damping = (damping * 0.3).max(settings.damping_min);
                    break;
                }
            }
            damping *= 10.0;
        }
        if !improved {
            break;
        }
    }
    (point, cost)
}

/// Root mean square, `f64::INFINITY` where it is not finite.
pub fn rms(r: &[f64]) -> f64 {
    let s: f64 = r.iter().map(|x| x * x).sum();
    let v = (s / r.len().max(1) as f64).sqrt();
    if v.is_finite() {
        v
    } else {
        f64::INFINITY
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `y = a exp(b x)` on a few points.
    struct Exponential {
        x: Vec<f64>,
        y: Vec<f64>,
    }

    impl Problem for Exponential {
        type Point = [f64; 2];

        fn residuals(&mut self, p: &[f64; 2]) -> Option<Vec<f64>> {
            let r: Vec<f64> = self.x.iter().zip(&self.y).map(|(x, y)| p[0] * (p[1] * x).exp() - y).collect();
            r.iter().all(|v| v.is_finite()).then_some(r)
        }

        fn jacobian(&mut self, p: &[f64; 2], _r: &[f64]) -> Option<Vec<Vec<f64>>> {
            let da = self.x.iter().map(|x| (p[1] * x).exp()).collect();
            let db = self.x.iter().map(|x| p[0] * x * (p[1] * x).exp()).collect();
            Some(vec![da, db])
        }

        fn moved(&self, p: &[f64; 2], step: &[f64]) -> Option<[f64; 2]> {
            let q = [p[0] + step[0], p[1] + step[1]];
            q.iter().all(|v| v.is_finite()).then_some(q)
        }
    }

    const SETTINGS: Settings = Settings {
        iterations: 100,
        tries: 8,
        damping_start: 1e-3,
        damping_min: 1e-12,
        min_relative_gain: 1e-12,
        steps: Steps::Triangular,
    };

    #[test]
    fn recovers_an_exponential_from_far_off() {
        let x: Vec<f64> = (0..30).map(|i| f64::from(i) * 0.1).collect();
        let y = x.iter().map(|x| 2.5 * (-1.3 * x).exp()).collect();
        let (p, cost) = minimize(&mut Exponential { x, y }, [1.0, 0.5], &SETTINGS);
        assert!(cost < 1e-10, "cost {cost}");
        assert!((p[0] - 2.5).abs() < 1e-8 && (p[1] + 1.3).abs() < 1e-8, "{p:?}");
    }

    #[test]
    fn the_normal_equations_recover_it_too() {
        let x: Vec<f64> = (0..30).map(|i| f64::from(i) * 0.1).collect();
        let y = x.iter().map(|x| 2.5 * (-1.3 * x).exp()).collect();
        let settings = Settings { steps: Steps::Normal, ..SETTINGS };
        let (p, cost) = minimize(&mut Exponential { x, y }, [1.0, 0.5], &settings);
        assert!(cost < 1e-7, "cost {cost}");
        assert!((p[0] - 2.5).abs() < 1e-6 && (p[1] + 1.3).abs() < 1e-6, "{p:?}");
    }

    #[test]
    fn never_ends_above_its_start_and_keeps_an_undefined_start() {
        let x: Vec<f64> = (0..20).map(|i| f64::from(i) * 0.25).collect();
        let y: Vec<f64> = x.iter().map(|v| 3.0 * v.sin()).collect();
        let mut problem = Exponential { x, y };
        let start = [0.5, 0.1];
        let before = rms(&problem.residuals(&start).unwrap());
        let (p, cost) = minimize(&mut problem, start, &Settings { iterations: 5, ..SETTINGS });
        assert!(cost <= before);
        assert_eq!(rms(&problem.residuals(&p).unwrap()), cost);
        let undefined = [1.0, 1e300];
        assert_eq!(minimize(&mut problem, undefined, &SETTINGS), (undefined, f64::INFINITY));
    }
}
