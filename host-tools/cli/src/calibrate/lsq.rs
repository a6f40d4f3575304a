//! Small linear least squares for the calibration fits (a handful of parameters).

// Small dense normal equations read clearest with indices.
#![allow(clippy::needless_range_loop)]

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
/// use sts_twin::calibrate::lsq::least_squares;
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
}
