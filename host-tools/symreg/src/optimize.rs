//! Constant optimisation: Levenberg-Marquardt ([`sts_numerics::lm`], its steps on the normal
//! equations) on the squared error, with forward-mode derivatives from
//! [`crate::eval::Evaluator::eval_with_jacobian`].

use crate::eval::{Evaluator, Program};
use crate::expr::Expr;
use sts_numerics::lm::{self, Problem, Settings, Steps};

/// Evaluation context shared by a search thread: the data and reusable buffers.
pub(crate) struct Workspace<'a> {
    pub columns: &'a [&'a [f64]],
    pub y: &'a [f64],
    pub evaluator: Evaluator,
    pred: Vec<f64>,
    jac: Vec<f64>,
    /// Evaluations done (a Jacobian evaluation counts as one).
    pub evaluations: u64,
}

impl<'a> Workspace<'a> {
    pub fn new(columns: &'a [&'a [f64]], y: &'a [f64]) -> Self {
        let n = y.len();
        Workspace { columns, y, evaluator: Evaluator::new(n), pred: vec![0.0; n], jac: Vec::new(), evaluations: 0 }
    }

    /// Mean squared error, or `None` if the expression is invalid on the data.
    pub fn mse(&mut self, expr: &Expr) -> Option<f64> {
        let program = Program::compile(expr);
        self.mse_program(&program)
    }

    fn mse_program(&mut self, program: &Program) -> Option<f64> {
        self.evaluations += 1;
        if !self.evaluator.eval(program, self.columns, &mut self.pred) {
            return None;
        }
        let sse: f64 = self.pred.iter().zip(self.y).map(|(p, y)| (p - y) * (p - y)).sum();
        let mse = sse / self.y.len() as f64;
        mse.is_finite().then_some(mse)
    }

    /// The last evaluation's residuals, prediction minus target.
    fn residuals(&self) -> Vec<f64> {
        self.pred.iter().zip(self.y).map(|(p, y)| p - y).collect()
    }

    /// Runs up to `iterations` Levenberg-Marquardt steps ([`sts_numerics::lm`] on the normal
    /// equations) on the constants of `expr` (in place, only if that lowers the error) and
    /// returns the final MSE (`None` if invalid).
    pub fn optimize_constants(&mut self, expr: &mut Expr, iterations: usize) -> Option<f64> {
        let theta = expr.constants();
        let program = Program::compile(expr);
        if theta.is_empty() || iterations == 0 {
            return self.mse_program(&program);
        }
        let (best, mse) =
            lm::minimize(&mut Constants { ws: self, program }, theta.clone(), &Settings { iterations, ..CONSTANTS_LM });
        if best != theta {
            expr.set_constants(&best);
        }
        mse.is_finite().then_some(mse)
    }
}

/// The damping of the constants' fits: from 1e-3, down to 1e-12 after each step that helps,
/// six tries per Jacobian, stopping where a step gains less than 1e-10 of the error.
const CONSTANTS_LM: Settings = Settings {
    iterations: 0,
    tries: 6,
    damping_start: 1e-3,
    damping_min: 1e-12,
    min_relative_gain: 1e-10,
    steps: Steps::Normal,
};

/// An expression's constants as a least-squares problem: residuals `prediction - y`, the
/// Jacobian by forward-mode derivatives, the cost the mean squared error.
struct Constants<'w, 'a> {
    ws: &'w mut Workspace<'a>,
    program: Program,
}

impl Constants<'_, '_> {
    /// The residuals and the Jacobian at `theta`, by forward-mode derivatives.
    fn derivatives(&mut self, theta: &[f64]) -> Option<(Vec<f64>, Vec<Vec<f64>>)> {
        let ws = &mut *self.ws;
        ws.evaluations += 1;
        let n = ws.y.len();
        ws.jac.resize(theta.len() * n, 0.0);
        self.program.set_constants(theta);
        if !ws.evaluator.eval_with_jacobian(&self.program, ws.columns, &mut ws.pred, &mut ws.jac) {
            return None;
        }
        Some((ws.residuals(), ws.jac.chunks(n.max(1)).map(<[f64]>::to_vec).collect()))
    }
}

impl Problem for Constants<'_, '_> {
    type Point = Vec<f64>;

    fn residuals(&mut self, theta: &Vec<f64>) -> Option<Vec<f64>> {
        let ws = &mut *self.ws;
        ws.evaluations += 1;
        self.program.set_constants(theta);
        if !ws.evaluator.eval(&self.program, ws.columns, &mut ws.pred) {
            return None;
        }
        Some(ws.residuals())
    }

    fn jacobian(&mut self, theta: &Vec<f64>, _r: &[f64]) -> Option<Vec<Vec<f64>>> {
        self.derivatives(theta).map(|(_, jacobian)| jacobian)
    }

    /// One pass of forward-mode derivatives at the start gives its residuals too.
    fn start(&mut self, theta: &Vec<f64>) -> Option<(Vec<f64>, Option<Vec<Vec<f64>>>)> {
        match self.derivatives(theta) {
            Some((r, jacobian)) => Some((r, Some(jacobian))),
            None => self.residuals(theta).map(|r| (r, None)),
        }
    }

    fn moved(&self, theta: &Vec<f64>, step: &[f64]) -> Option<Vec<f64>> {
        let trial: Vec<f64> = theta.iter().zip(step).map(|(t, s)| t + s).collect();
        trial.iter().all(|v| v.is_finite()).then_some(trial)
    }

    fn cost(&self, r: &[f64]) -> f64 {
        let sse: f64 = r.iter().map(|v| v * v).sum();
        let mse = sse / r.len() as f64;
        if mse.is_finite() {
            mse
        } else {
            f64::INFINITY
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::expr::{BinaryOp::*, UnaryOp::*};

    #[test]
    fn recovers_tanh_constants() {
        // y = 1.95 - 1.23*tanh(-0.0441*x0 + 0.122*x1 + 1.08)
        let x0: Vec<f64> = (0..60).map(|i| 5.0 + (i as f64 * 7.3) % 35.0).collect();
        let x1: Vec<f64> = (0..60).map(|i| 1.0 + (i as f64 * 3.1) % 9.0).collect();
        let y: Vec<f64> =
            x0.iter().zip(&x1).map(|(a, b)| 1.95 - 1.23 * (-0.0441 * a + 0.122 * b + 1.08).tanh()).collect();
        let cols: Vec<&[f64]> = vec![&x0, &x1];
        let mut ws = Workspace::new(&cols, &y);
        let inner = Expr::binary(
            Add,
            Expr::binary(
                Add,
                Expr::binary(Mul, Expr::Const(-0.1), Expr::Var(0)),
                Expr::binary(Mul, Expr::Const(0.2), Expr::Var(1)),
            ),
            Expr::Const(0.5),
        );
        let mut e = Expr::binary(Sub, Expr::Const(2.0), Expr::binary(Mul, Expr::Const(1.0), Expr::unary(Tanh, inner)));
        let mse = ws.optimize_constants(&mut e, 100).unwrap();
        assert!(mse < 1e-20, "mse {mse}, {e}");
        let k = e.constants();
        assert!((k[0] - 1.95).abs() < 1e-6 && (k[1] - 1.23).abs() < 1e-6, "{e}");
    }

    #[test]
    fn never_makes_things_worse() {
        let x0: Vec<f64> = (1..40).map(|i| i as f64 * 0.25).collect();
        let y: Vec<f64> = x0.iter().map(|v| v.sin() * 3.0).collect();
        let cols: Vec<&[f64]> = vec![&x0];
        let mut ws = Workspace::new(&cols, &y);
        let mut e =
            Expr::binary(Mul, Expr::Const(0.5), Expr::unary(Exp, Expr::binary(Mul, Expr::Const(0.1), Expr::Var(0))));
        let before = ws.mse(&e).unwrap();
        let after = ws.optimize_constants(&mut e, 20).unwrap();
        assert!(after <= before);
        assert_eq!(ws.mse(&e).unwrap(), after);
    }
}
