//! Dense symmetric solves for small least-squares problems.

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_a_small_system() {
        let x = solve_ridge(vec![vec![4.0, 1.0], vec![1.0, 3.0]], vec![1.0, 2.0]);
        assert!((x[0] - 1.0 / 11.0).abs() < 1e-6 && (x[1] - 7.0 / 11.0).abs() < 1e-6);
    }
}
