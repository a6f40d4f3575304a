//! The normal equations of a damped least-squares step, solved by Cholesky: `(J^T J + damping
//! diag(J^T J)) step = J^T r`. They square the Jacobian's condition number, so this is no
//! general solver (the module above says why); it serves where a step only has to lower a
//! cost that is checked anyway and the work per step must be least: symbolic regression's few
//! constants, stepped many thousand times per search. By hand because its sums' order is
//! what the searches' formulas depend on, bit for bit.

/// `J^T J` and `J^T r` of a Jacobian with few columns, for the steps of several dampings.
#[derive(Clone, Debug)]
pub struct Normal {
    /// Columns.
    k: usize,
    /// `J^T J`, `k x k`, row-major.
    gram: Vec<f64>,
    /// `J^T r`.
    rhs: Vec<f64>,
}

impl Normal {
    /// The products of the Jacobian's `columns` (each as long as `r`) and the target `r`.
    pub fn new(columns: &[Vec<f64>], r: &[f64]) -> Self {
        let k = columns.len();
        let mut gram = vec![0.0; k * k];
        let mut rhs = vec![0.0; k];
        for a in 0..k {
            let ja = &columns[a];
            let mut s = 0.0;
            for (j, v) in ja.iter().zip(r) {
                s += j * v;
            }
            rhs[a] = s;
            for b in 0..=a {
                let jb = &columns[b];
                let mut s = 0.0;
                for (x, y) in ja.iter().zip(jb) {
                    s += x * y;
                }
                gram[a * k + b] = s;
                gram[b * k + a] = s;
            }
        }
        Self { k, gram, rhs }
    }

    /// The step for `damping` (Marquardt's scaling: each diagonal entry grows by `damping`
    /// times itself, at least `1e-12`); `None` where the damped matrix is not positive
    /// definite or the step not finite.
    pub fn solve(&self, damping: f64) -> Option<Vec<f64>> {
        let k = self.k;
        let mut m = self.gram.clone();
        for a in 0..k {
            let d = self.gram[a * k + a];
            m[a * k + a] = d + damping * d.max(1e-12);
        }
        cholesky_solve(&mut m, &self.rhs, k)
    }
}

/// Solves `m x = b` for a symmetric positive definite `k x k` matrix by Cholesky, in place.
fn cholesky_solve(m: &mut [f64], b: &[f64], k: usize) -> Option<Vec<f64>> {
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

    #[test]
    fn an_undamped_step_is_the_least_squares_solution() {
        // r = 2 a + 3 b exactly: columns (1, 0, 1), (0, 1, 1); r = (2, 3, 5).
        let n = Normal::new(&[vec![1.0, 0.0, 1.0], vec![0.0, 1.0, 1.0]], &[2.0, 3.0, 5.0]);
        let x = n.solve(0.0).unwrap();
        assert!((x[0] - 2.0).abs() < 1e-12 && (x[1] - 3.0).abs() < 1e-12, "{x:?}");
        // Damping shortens the step.
        let damped = n.solve(1.0).unwrap();
        assert!(damped[0].abs() < x[0].abs() && damped[1].abs() < x[1].abs(), "{damped:?}");
    }

    #[test]
    fn a_dependent_column_without_damping_has_no_step() {
        let n = Normal::new(&[vec![1.0, 2.0], vec![1.0, 2.0]], &[1.0, 2.0]);
        assert!(n.solve(0.0).is_none());
        assert!(n.solve(1e-3).is_some());
    }
}
