//! The planted benchmark problems and the "exact form recovered" check.
//!
//! Both problems have 12 positive features, of which only two or three matter:
//!
//! | problem | formula | features used | ranges |
//! |---|---|---|---|
//! | P1 | `2.5*x0*abs(x1/x2)**0.78` | x0, x1, x2 | x0 in [1, 5], x1, x2 in [0.5, 10] |
//! | P2 | `1.95 - 1.23*tanh(-0.0441*x0 + 0.122*x1 + 1.08)` | x0, x1 | x0 in [5, 40] (a frequency in Hz, as in the paper), x1 in [1, 10] |
//!
//! Distractors `x3..x11` (P1) and `x2..x11` (P2) are uniform on ranges between 0.5 and 20
//! (see [`ranges`]). In P2 the tanh argument spans about -0.6 to 2.1, so the curvature matters.
//! The data are noise-free.
//!
//! A formula counts as the exact form ([`is_exact_recovery`]) when (1) it uses no distractor
//! and (2) on 4000 points drawn from the feature box widened by half its width on each side
//! (lower bounds kept positive) it is valid everywhere and within 1% of the true value at
//! every point. Extrapolation is what separates the true form from approximations that fit
//! the training box (a polynomial stand-in for tanh, say); within 1% everywhere also pins
//! the constants to about 1%.

use crate::data::Matrix;
use crate::expr::Expr;
use crate::mutate::Rand;

/// A planted problem.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Planted {
    /// `y = 2.5*x0*|x1/x2|^0.78`.
    P1,
    /// `y = 1.95 - 1.23*tanh(-0.0441*x0 + 0.122*x1 + 1.08)`.
    P2,
}

/// Number of features of every planted problem.
pub const N_FEATURES: usize = 12;

impl Planted {
    /// The true value at one row.
    pub fn truth(self, x: &[f64]) -> f64 {
        match self {
            Planted::P1 => 2.5 * x[0] * (x[1] / x[2]).abs().powf(0.78),
            Planted::P2 => 1.95 - 1.23 * (-0.0441 * x[0] + 0.122 * x[1] + 1.08).tanh(),
        }
    }

    /// Indices of the features the truth uses.
    pub fn used_features(self) -> &'static [usize] {
        match self {
            Planted::P1 => &[0, 1, 2],
            Planted::P2 => &[0, 1],
        }
    }

    /// The true formula as text (SymPy syntax).
    pub fn formula(self) -> &'static str {
        match self {
            Planted::P1 => "2.5*x0*abs(x1/x2)**0.78",
            Planted::P2 => "1.95 - 1.23*tanh(-0.0441*x0 + 0.122*x1 + 1.08)",
        }
    }

    /// Short name.
    pub fn name(self) -> &'static str {
        match self {
            Planted::P1 => "P1",
            Planted::P2 => "P2",
        }
    }
}

/// The sampling range `(low, high)` of each feature.
pub fn ranges(problem: Planted) -> [(f64, f64); N_FEATURES] {
    let mut r = [(0.5, 10.0); N_FEATURES];
    match problem {
        Planted::P1 => {
            r[0] = (1.0, 5.0);
        }
        Planted::P2 => {
            r[0] = (5.0, 40.0);
            r[1] = (1.0, 10.0);
        }
    }
    // Distractors on varied scales.
    let distractors = [
        (0.5, 2.0),
        (1.0, 20.0),
        (0.5, 10.0),
        (2.0, 8.0),
        (0.5, 5.0),
        (1.0, 15.0),
        (0.5, 3.0),
        (3.0, 20.0),
        (0.5, 10.0),
        (1.0, 4.0),
    ];
    for (j, d) in (problem.used_features().len()..N_FEATURES).zip(distractors) {
        r[j] = d;
    }
    r
}

/// `n_rows` noise-free rows of a problem, drawn with `seed`.
///
/// ```
/// use sts_symreg::planted::{generate, Planted};
/// let (x, y) = generate(Planted::P1, 3, 99);
/// assert_eq!((x.n_rows(), x.n_cols(), y.len()), (99, 12, 99));
/// ```
pub fn generate(problem: Planted, seed: u64, n_rows: usize) -> (Matrix, Vec<f64>) {
    let r = ranges(problem);
    let mut rng = Rand::new(seed, 1_000_000 + problem as u64);
    let mut data = Vec::with_capacity(n_rows * N_FEATURES);
    let mut y = Vec::with_capacity(n_rows);
    for _ in 0..n_rows {
        let row: Vec<f64> = r.iter().map(|&(lo, hi)| lo + (hi - lo) * rng.f64()).collect();
        y.push(problem.truth(&row));
        data.extend_from_slice(&row);
    }
    let x = Matrix::from_row_major(n_rows, N_FEATURES, data).expect("shape is consistent");
    (x, y)
}

/// Whether `expr` is the exact form of the planted truth (see the module docs).
pub fn is_exact_recovery(problem: Planted, expr: &Expr) -> bool {
    let used = problem.used_features();
    if (0..N_FEATURES).any(|j| !used.contains(&j) && expr.uses_var(j)) {
        return false;
    }
    if expr.n_vars_used() > N_FEATURES {
        return false;
    }
    let wide: Vec<(f64, f64)> = ranges(problem)
        .iter()
        .map(|&(lo, hi)| {
            let w = hi - lo;
            ((lo - 0.5 * w).max(0.5 * lo), hi + 0.5 * w)
        })
        .collect();
    let mut rng = Rand::new(12345, 2_000_000 + problem as u64);
    for _ in 0..4000 {
        let row: Vec<f64> = wide.iter().map(|&(lo, hi)| lo + (hi - lo) * rng.f64()).collect();
        let t = problem.truth(&row);
        let f = expr.eval_row(&row);
        if !f.is_finite() || (f - t).abs() > 0.01 * t.abs() {
            return false;
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::expr::{BinaryOp::*, UnaryOp::*};

    fn p1_truth() -> Expr {
        Expr::binary(
            Mul,
            Expr::binary(Mul, Expr::Const(2.5), Expr::Var(0)),
            Expr::binary(Pow, Expr::binary(Div, Expr::Var(1), Expr::Var(2)), Expr::Const(0.78)),
        )
    }

    #[test]
    fn the_check_accepts_the_truth_and_rejects_near_misses() {
        assert!(is_exact_recovery(Planted::P1, &p1_truth()));
        // Exponent 3% off.
        let mut off = p1_truth();
        off.set_constants(&[2.5, 0.80]);
        assert!(!is_exact_recovery(Planted::P1, &off));
        // A negligible distractor term still fails (the form is not exact).
        let extra = Expr::binary(Add, p1_truth(), Expr::binary(Mul, Expr::Const(1e-9), Expr::Var(5)));
        assert!(!is_exact_recovery(Planted::P1, &extra));
        // P2 truth and a linear stand-in.
        let inner = Expr::binary(
            Add,
            Expr::binary(
                Add,
                Expr::binary(Mul, Expr::Const(-0.0441), Expr::Var(0)),
                Expr::binary(Mul, Expr::Const(0.122), Expr::Var(1)),
            ),
            Expr::Const(1.08),
        );
        let p2 = Expr::binary(Sub, Expr::Const(1.95), Expr::binary(Mul, Expr::Const(1.23), Expr::unary(Tanh, inner)));
        assert!(is_exact_recovery(Planted::P2, &p2));
        let linear = Expr::binary(Add, Expr::Const(1.3), Expr::binary(Mul, Expr::Const(0.03), Expr::Var(0)));
        assert!(!is_exact_recovery(Planted::P2, &linear));
    }

    #[test]
    fn generation_is_deterministic_and_in_range() {
        let (a, ya) = generate(Planted::P2, 9, 50);
        let (b, yb) = generate(Planted::P2, 9, 50);
        assert_eq!(a, b);
        assert_eq!(ya, yb);
        let r = ranges(Planted::P2);
        for row in 0..50 {
            for (j, &(lo, hi)) in r.iter().enumerate() {
                let v = a.get(row, j);
                assert!(v >= lo && v <= hi);
            }
        }
    }
}
