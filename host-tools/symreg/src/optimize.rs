//! Constant optimisation by Levenberg-Marquardt on the squared error, with forward-mode
//! derivatives from [`crate::eval::Evaluator::eval_with_jacobian`].
//!
//! Its own loop on the normal equations rather than `sts_numerics::lm`'s QR steps: on the
//! shared loop the formulas differ in their last digits, and CI's explain set of friction
//! beside hysteresis then misses the friction (61.5 nm against 8.0 nm clean), a sensitivity
//! of the ladder to mend first.

use crate::eval::{Evaluator, Program};
use crate::expr::Expr;

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

    /// Runs up to `iterations` Levenberg-Marquardt steps on the constants of `expr` (in
    /// place, only if that lowers the error) and returns the final MSE (`None` if invalid).
    pub fn optimize_constants(&mut self, expr: &mut Expr, iterations: usize) -> Option<f64> {
        let mut theta = expr.constants();
        let k = theta.len();
        let mut program = Program::compile(expr);
        if k == 0 || iterations == 0 {
            return self.mse_program(&program);
        }
        let n = self.y.len();
        self.jac.resize(k * n, 0.0);
        let mut lambda = 1e-3;
        let mut current: Option<f64> = None;
        let mut jtj = vec![0.0; k * k];
        let mut jtr = vec![0.0; k];
        let mut trial = vec![0.0; k];
        // Whether `theta` moved from the expression's constants (written back at the end).
        let mut accepted = false;
        let mut iter = 0;
        while iter < iterations {
            iter += 1;
            self.evaluations += 1;
            if !self.evaluator.eval_with_jacobian(&program, self.columns, &mut self.pred, &mut self.jac) {
                break;
            }
            let sse: f64 = self.pred.iter().zip(self.y).map(|(p, y)| (p - y) * (p - y)).sum();
            let mse = sse / n as f64;
            if !mse.is_finite() {
                break;
            }
            current = Some(mse);
            if mse == 0.0 {
                break;
            }
            // Normal equations J^T J d = -J^T r, r = pred - y.
            for a in 0..k {
                let ja = &self.jac[a * n..(a + 1) * n];
                let mut s = 0.0;
                for ((j, p), y) in ja.iter().zip(&self.pred[..n]).zip(&self.y[..n]) {
                    s += j * (p - y);
                }
                jtr[a] = s;
                for b in 0..=a {
                    let jb = &self.jac[b * n..(b + 1) * n];
                    let mut s = 0.0;
                    for r in 0..n {
                        s += ja[r] * jb[r];
                    }
                    jtj[a * k + b] = s;
                    jtj[b * k + a] = s;
                }
            }
            // Try damped steps until one lowers the error (a few attempts per iteration).
            let mut improved = false;
            for _ in 0..6 {
                let mut m = jtj.clone();
                for a in 0..k {
                    let d = jtj[a * k + a];
                    m[a * k + a] = d + lambda * d.max(1e-12);
                }
                let Some(step) = solve_spd(&mut m, &jtr, k) else {
                    lambda *= 10.0;
                    continue;
                };
                for a in 0..k {
                    trial[a] = theta[a] - step[a];
                }
                if trial.iter().any(|v| !v.is_finite()) {
                    lambda *= 10.0;
                    continue;
                }
                program.set_constants(&trial);
                match self.mse_program(&program) {
                    Some(m2) if m2 < mse => {
                        theta.copy_from_slice(&trial);
                        accepted = true;
                        current = Some(m2);
                        lambda = (lambda * 0.3).max(1e-12);
                        improved = true;
                        break;
                    }
                    _ => {
                        program.set_constants(&theta);
                        lambda *= 10.0;
                    }
                }
            }
            if !improved {
                break;
            }
            // Converged to rounding level: further steps cannot help.
            if let Some(c) = current
                && mse - c <= 1e-10 * mse
            {
                break;
            }
        }
        if accepted {
            expr.set_constants(&theta);
        }
        match current {
            Some(c) => Some(c),
            None => self.mse_program(&program),
        }
    }
}

/// Solves `m x = b` for a symmetric positive definite `k x k` matrix by Cholesky (in place).
fn solve_spd(m: &mut [f64], b: &[f64], k: usize) -> Option<Vec<f64>> {
    for j in 0..k {
        let mut d = m[j * k + j];
        for p in 0..j {
            d -= m[j * k + p] * m[j * k + p];
        }
        if d <= 0.0 || !d.is_finite() {
            return None;
        }
        let d = d.sqrt();
        m[j * k + j] = d;
        for i in j + 1..k {
            let mut s = m[i * k + j];
            for p in 0..j {
                s -= m[i * k + p] * m[j * k + p];
            }
            m[i * k + j] = s / d;
        }
    }
    let mut z = vec![0.0; k];
    for i in 0..k {
        let mut s = b[i];
        for p in 0..i {
            s -= m[i * k + p] * z[p];
        }
        z[i] = s / m[i * k + i];
    }
    let mut x = vec![0.0; k];
    for i in (0..k).rev() {
        let mut s = z[i];
        for p in i + 1..k {
            s -= m[p * k + i] * x[p];
        }
        x[i] = s / m[i * k + i];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
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
