//! Linear least squares for the host's fits: per-group sufficient statistics that folds of
//! groups add up (diagnose, effect identification), and small dense fits (calibration).

// Small dense systems read clearest with indices.
#![allow(clippy::needless_range_loop)]

/// Sufficient statistics of one group for a linear candidate: `X'X`, `X'r`, `r'r`.
#[derive(Clone, Debug)]
pub struct Stats {
    /// `X'X`.
    pub xtx: Vec<Vec<f64>>,
    /// `X'r`.
    pub xtr: Vec<f64>,
    /// `r'r`.
    pub rr: f64,
}

impl Stats {
    /// Accumulates stats of regressor columns `x` (each over the window) and residual `r`.
    pub fn from_columns(x: &[Vec<f64>], r: &[f64]) -> Self {
        let p = x.len();
        let mut xtx = vec![vec![0.0; p]; p];
        let mut xtr = vec![0.0; p];
        for i in 0..p {
            xtr[i] = x[i].iter().zip(r).map(|(a, b)| a * b).sum();
            for j in 0..=i {
                let v: f64 = x[i].iter().zip(&x[j]).map(|(a, b)| a * b).sum();
                xtx[i][j] = v;
                xtx[j][i] = v;
            }
        }
        Self { xtx, xtr, rr: r.iter().map(|v| v * v).sum() }
    }

    /// Residual sum of squares after subtracting `X theta`.
    pub fn sse(&self, theta: &[f64]) -> f64 {
        let p = theta.len();
        let mut quad = 0.0;
        for i in 0..p {
            for j in 0..p {
                quad += theta[i] * self.xtx[i][j] * theta[j];
            }
        }
        let lin: f64 = theta.iter().zip(&self.xtr).map(|(a, b)| a * b).sum();
        (self.rr - 2.0 * lin + quad).max(0.0)
    }
}

/// Least-squares coefficients over a set of groups' stats.
pub fn solve(stats: &[&Stats]) -> Vec<f64> {
    let p = stats.first().map_or(0, |s| s.xtr.len());
    let mut a = vec![vec![0.0; p]; p];
    let mut b = vec![0.0; p];
    for s in stats {
        for i in 0..p {
            b[i] += s.xtr[i];
            for j in 0..p {
                a[i][j] += s.xtx[i][j];
            }
        }
    }
    solve_ridge(a, b)
}

/// Solves `a x = b` (`a` symmetric positive semi-definite) by Cholesky with a tiny ridge
/// relative to the diagonal, so collinear regressors give a finite, minimal-ish answer.
pub fn solve_ridge(mut a: Vec<Vec<f64>>, b: Vec<f64>) -> Vec<f64> {
    let n = b.len();
    if n == 0 {
        return Vec::new();
    }
    let scale: Vec<f64> = (0..n).map(|i| a[i][i].abs().sqrt().max(1e-300)).collect();
    // Normalise to unit diagonal (conditioning), add the ridge.
    for i in 0..n {
        for j in 0..n {
            a[i][j] /= scale[i] * scale[j];
        }
        a[i][i] += 1e-9;
    }
    let bs: Vec<f64> = (0..n).map(|i| b[i] / scale[i]).collect();
    let mut l = vec![vec![0.0; n]; n];
    for i in 0..n {
        for j in 0..=i {
            let mut s = a[i][j];
            for k in 0..j {
                s -= l[i][k] * l[j][k];
            }
            if i == j {
                l[i][i] = s.max(1e-12).sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    let mut y = vec![0.0; n];
    for i in 0..n {
        let mut s = bs[i];
        for k in 0..i {
            s -= l[i][k] * y[k];
        }
        y[i] = s / l[i][i];
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        let mut s = y[i];
        for k in i + 1..n {
            s -= l[k][i] * x[k];
        }
        x[i] = s / l[i][i];
    }
    (0..n).map(|i| x[i] / scale[i]).collect()
}

/// A least-squares fit: the coefficients and the RMS of the residuals.
#[derive(Clone, Debug, PartialEq)]
pub struct LinearFit {
    /// One coefficient per column of the design matrix.
    pub coefficients: Vec<f64>,
    /// RMS of `y - X b`, in the unit of `y`.
    pub residual_rms: f64,
    /// Largest `|y - X b|`, in the unit of `y`.
    pub residual_max: f64,
}

/// Fits `y ~ X b` by the normal equations (Gaussian elimination with partial pivoting).
/// `None` when there are fewer rows than columns or the columns are linearly dependent.
///
/// ```
/// use sts_analysis::lsq::least_squares;
/// let rows = [[1.0, 0.0], [1.0, 1.0], [1.0, 2.0]];
/// let fit = least_squares(&rows, &[1.0, 3.0, 5.0]).unwrap();
/// assert!((fit.coefficients[0] - 1.0).abs() < 1e-12 && (fit.coefficients[1] - 2.0).abs() < 1e-12);
/// ```
pub fn least_squares<const N: usize>(rows: &[[f64; N]], y: &[f64]) -> Option<LinearFit> {
    if rows.len() < N || rows.len() != y.len() || N == 0 {
        return None;
    }
    let mut m = [[0.0f64; N]; N];
    let mut v = [0.0f64; N];
    for (row, &yi) in rows.iter().zip(y) {
        for i in 0..N {
            v[i] += row[i] * yi;
            for j in 0..N {
                m[i][j] += row[i] * row[j];
            }
        }
    }
    let scale = (0..N).map(|i| m[i][i].abs()).fold(0.0, f64::max);
    for col in 0..N {
        let pivot = (col..N).max_by(|&a, &b| m[a][col].abs().total_cmp(&m[b][col].abs()))?;
        let size = m[pivot][col].abs();
        if size.is_nan() || size <= 1e-12 * scale {
            return None;
        }
        m.swap(col, pivot);
        v.swap(col, pivot);
        for r in col + 1..N {
            let factor = m[r][col] / m[col][col];
            for c in col..N {
                m[r][c] -= factor * m[col][c];
            }
            v[r] -= factor * v[col];
        }
    }
    let mut b = [0.0f64; N];
    for r in (0..N).rev() {
        let tail: f64 = (r + 1..N).map(|c| m[r][c] * b[c]).sum();
        b[r] = (v[r] - tail) / m[r][r];
    }
    let residuals: Vec<f64> =
        rows.iter().zip(y).map(|(row, &yi)| yi - row.iter().zip(&b).map(|(x, c)| x * c).sum::<f64>()).collect();
    let residual_rms = (residuals.iter().map(|r| r * r).sum::<f64>() / residuals.len() as f64).sqrt();
    let residual_max = residuals.iter().fold(0.0f64, |m, r| m.max(r.abs()));
    if !b.iter().all(|c| c.is_finite()) {
        return None;
    }
    Some(LinearFit { coefficients: b.to_vec(), residual_rms, residual_max })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_a_small_system() {
        let x = solve_ridge(vec![vec![4.0, 1.0], vec![1.0, 3.0]], vec![1.0, 2.0]);
        assert!((x[0] - 1.0 / 11.0).abs() < 1e-6 && (x[1] - 7.0 / 11.0).abs() < 1e-6);
    }

    #[test]
    fn recovers_a_plane_and_reports_the_residual() {
        let rows: Vec<[f64; 3]> = (0..20).map(|k| [1.0, k as f64, (k as f64 * 0.7).sin()]).collect();
        let y: Vec<f64> = rows
            .iter()
            .enumerate()
            .map(|(k, r)| 0.5 + 2.0 * r[1] - 3.0 * r[2] + if k % 2 == 0 { 0.01 } else { -0.01 })
            .collect();
        let fit = least_squares(&rows, &y).unwrap();
        assert!((fit.coefficients[1] - 2.0).abs() < 1e-3, "{fit:?}");
        assert!((fit.coefficients[2] + 3.0).abs() < 1e-2, "{fit:?}");
        assert!((fit.residual_rms - 0.01).abs() < 2e-3, "{fit:?}");
        assert!(fit.residual_max < 0.02, "{fit:?}");
    }

    #[test]
    fn dependent_columns_and_too_few_rows_give_none() {
        assert!(least_squares(&[[1.0, 2.0], [2.0, 4.0], [3.0, 6.0]], &[1.0, 2.0, 3.0]).is_none());
        assert!(least_squares(&[[1.0, 2.0]], &[1.0]).is_none());
        assert!(least_squares(&[[1.0], [1.0]], &[1.0]).is_none());
    }

    #[test]
    fn stats_give_the_sse_of_a_fit() {
        let x = vec![vec![1.0, 2.0, 3.0], vec![1.0, 1.0, 1.0]];
        let r = vec![2.0, 4.1, 6.0];
        let s = Stats::from_columns(&x, &r);
        let theta = solve(&[&s]);
        let direct: f64 = (0..3).map(|k| (r[k] - theta[0] * x[0][k] - theta[1] * x[1][k]).powi(2)).sum();
        assert!((s.sse(&theta) - direct).abs() < 1e-9);
        assert!((theta[0] - 2.0).abs() < 0.1);
    }
}
