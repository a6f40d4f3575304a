//! Linear least squares for every fit of the host, on Householder QR (never the normal
//! equations, whose squared condition number costs half the digits): the triangular factors by
//! hand ([`triangular`], the fits' hot loop), `Q` where one is needed from `nalgebra`:
//!
//! - [`Stats`]: one group's regression reduced to the triangular factor of `[X | r]`, which
//!   folds of groups stack and reduce again ([`solve`]), so cross-validation by group never
//!   goes back to the samples (diagnose's candidates, the effects' terms);
//! - [`solve_damped`], [`Damped`]: the same with Marquardt's damping (the steps of
//!   [`crate::lm`], the Jacobian reduced once for every damping tried);
//! - [`least_squares`]: a small fit with its residuals, refusing dependent columns
//!   (calibration, sine fits);
//! - [`Projection`]: what many series leave after least squares on the same fixed columns
//!   (the ripple's pitch search, whose candidate columns all lose the same nuisance);
//! - [`Normal`]: the one exception, a damped step on the normal equations, for
//!   [`crate::lm`] where a step is only kept if it lowers the cost and must cost least
//!   (symbolic regression's constants).
//!
//! Collinear regressors are common (a candidate's columns can nearly coincide on a short
//! window), so [`solve`] adds a ridge of [`RIDGE`] relative to each column's norm: a finite,
//! nearly minimal answer instead of a blow-up.

mod normal;
mod triangular;

pub use normal::Normal;

use nalgebra::{DMatrix, DVector};
use triangular::{dot, triangular_factor, Triangular};

/// The ridge of [`solve`] and [`solve_damped`], relative to each column's squared norm.
pub const RIDGE: f64 = 1e-9;

/// A column whose diagonal in the triangular factor is below this fraction of the largest
/// counts as dependent in [`least_squares`].
const RANK_TOLERANCE: f64 = 1e-9;

/// One group's regression `r ~ X theta` reduced to the upper-triangular factor `R` of the QR
/// decomposition of `[X | r]`: `||r - X theta||^2 = ||R [-theta; 1]||^2` for every `theta`,
/// and stacking the factors of several groups is the QR of their stacked samples.
#[derive(Clone, Debug)]
pub struct Stats {
    /// `(p + 1) x (p + 1)` upper-triangular factor; the last column belongs to `r`.
    r_factor: DMatrix<f64>,
}

impl Stats {
    /// The factor of regressor columns `x` (each over the window) and residual `r`.
    pub fn from_columns(x: &[Vec<f64>], r: &[f64]) -> Self {
        let cols = x.len() + 1;
        // Tall and skinny: added to the factor block by block, so each reduction works on rows
        // that stay in cache; the same factor as one QR of all rows.
        let mut factor = Triangular::zeros(cols);
        let mut block = vec![0.0; r.len().min(QR_BLOCK_ROWS) * cols];
        for start in (0..r.len()).step_by(QR_BLOCK_ROWS) {
            let rows = (r.len() - start).min(QR_BLOCK_ROWS);
            let block = &mut block[..rows * cols];
            for (j, column) in block.chunks_exact_mut(rows).enumerate() {
                let samples = if j + 1 < cols { &x[j][start..start + rows] } else { &r[start..start + rows] };
                column.copy_from_slice(samples);
            }
            factor.absorb(block, rows);
        }
        Self { r_factor: factor.into_matrix() }
    }

    /// Number of regressors.
    pub fn columns(&self) -> usize {
        self.r_factor.ncols() - 1
    }

    /// Sum of squares of `r` (the residual before any regressor).
    pub fn residual_ss(&self) -> f64 {
        self.r_factor.column(self.columns()).norm_squared()
    }

    /// Residual sum of squares after subtracting `X theta`.
    pub fn sse(&self, theta: &[f64]) -> f64 {
        let p = self.columns();
        let v = DVector::from_fn(p + 1, |i, _| if i < p { -theta.get(i).copied().unwrap_or(0.0) } else { 1.0 });
        (&self.r_factor * v).norm_squared()
    }
}

impl Stats {
    /// The statistics of new columns that are linear combinations of these columns,
    /// `X' = X M` with `mix[j]` column `j` of `M` (one weight per old column), against the same
    /// residual, without going back to the samples: a grid of variants that only reweight a
    /// few base columns per group costs a small QR each.
    pub fn mixed(&self, mix: &[Vec<f64>]) -> Self {
        let p = self.columns();
        let q = mix.len();
        let r = &self.r_factor;
        let m = DMatrix::from_fn(p + 1, q + 1, |i, j| {
            if j < q {
                (0..p).map(|k| r[(i, k)] * mix[j].get(k).copied().unwrap_or(0.0)).sum()
            } else {
                r[(i, p)]
            }
        });
        Self { r_factor: triangular_factor(m) }
    }
}

/// Rows of one block of [`Stats::from_columns`]'s reduction.
const QR_BLOCK_ROWS: usize = 256;

/// Ridge least-squares coefficients over a set of groups' stats: the groups' factors stacked
/// and reduced again, each column scaled to unit norm with a ridge of [`RIDGE`].
pub fn solve(stats: &[&Stats]) -> Vec<f64> {
    solve_damped(stats, 0.0)
}

/// [`solve`] with a damping of `damping` in Marquardt's scaling added to the ridge
/// (a Levenberg-Marquardt step: `X` the Jacobian, `r` minus the residuals).
pub fn solve_damped(stats: &[&Stats], damping: f64) -> Vec<f64> {
    Damped::new(stats).map_or_else(Vec::new, |d| d.solve(damping))
}

/// A regression over a set of groups' stats, stacked and reduced once, to be solved with
/// several dampings (a Levenberg-Marquardt iteration tries dampings until a step helps).
#[derive(Clone, Debug)]
pub struct Damped {
    /// The reduced regressors, `p x p` upper-triangular over `p + 1` rows.
    x: DMatrix<f64>,
    /// The reduced target.
    y: DVector<f64>,
}

impl Damped {
    /// The groups' factors stacked and reduced again; `None` without a group or a column.
    pub fn new(stats: &[&Stats]) -> Option<Self> {
        let p = stats.first()?.columns();
        if p == 0 {
            return None;
        }
        let rows = p + 1;
        let mut stacked = DMatrix::zeros(rows * stats.len(), rows);
        for (k, s) in stats.iter().enumerate() {
            stacked.rows_mut(k * rows, rows).copy_from(&s.r_factor);
        }
        let reduced = triangular_factor(stacked);
        Some(Self { x: reduced.columns(0, p).into_owned(), y: reduced.column(p).into_owned() })
    }

    /// Minimises `||y - X b||^2 + (damping + RIDGE) ||D b||^2` where `D` holds the columns'
    /// norms (Marquardt's scaling), by QR of the augmented system.
    pub fn solve(&self, damping: f64) -> Vec<f64> {
        let (x, y) = (&self.x, &self.y);
        let (n, p) = x.shape();
        let scale: Vec<f64> = (0..p).map(|j| x.column(j).norm().max(1e-300)).collect();
        let root = (damping + RIDGE).sqrt();
        let augmented = DMatrix::from_fn(n + p, p + 1, |i, j| match (i < n, j < p) {
            (true, true) => x[(i, j)] / scale[j],
            (true, false) => y[i],
            (false, true) => {
                if i - n == j {
                    root
                } else {
                    0.0
                }
            }
            (false, false) => 0.0,
        });
        let r = triangular_factor(augmented);
        let rxx = r.view((0, 0), (p, p));
        let rhs = r.view((0, p), (p, 1)).into_owned();
        let w = rxx.solve_upper_triangular(&rhs).unwrap_or_else(|| DMatrix::zeros(p, 1));
        (0..p).map(|j| w[(j, 0)] / scale[j]).collect()
    }
}

/// The residual of least squares on fixed columns `X`, for any number of series: `y - Q Q^T y`
/// with `Q` the thin orthonormal factor of `X`'s QR, computed once.
///
/// ```
/// use sts_numerics::lsq::Projection;
/// let ones = vec![1.0; 4];
/// let ramp = vec![0.0, 1.0, 2.0, 3.0];
/// let left = Projection::new(&[ones, ramp]).residual(&[1.0, 3.0, 5.0, 8.0]);
/// assert!((left.iter().sum::<f64>()).abs() < 1e-12);
/// ```
#[derive(Clone, Debug)]
pub struct Projection {
    q: DMatrix<f64>,
}

impl Projection {
    /// The projection off columns `x`, each as long as the series it will take.
    pub fn new(x: &[Vec<f64>]) -> Self {
        let n = x.first().map_or(0, Vec::len);
        let m = x.len().min(n);
        let q = if m == 0 { DMatrix::zeros(n, 0) } else { DMatrix::from_fn(n, m, |i, j| x[j][i]).qr().q() };
        Self { q }
    }

    /// `y` minus its least-squares fit on the columns.
    pub fn residual(&self, y: &[f64]) -> Vec<f64> {
        let mut out = y.to_vec();
        for q in self.q.column_iter() {
            let c = dot(q.as_slice(), y);
            for (o, a) in out.iter_mut().zip(q.iter()) {
                *o -= c * a;
            }
        }
        out
    }
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
    /// Each coefficient's standard error from the residuals' spread: the diagonal of
    /// `s^2 (X^T X)^-1` with `s^2` the residual sum of squares over `rows - columns`;
    /// infinite where there are no more rows than columns.
    pub standard_errors: Vec<f64>,
}

/// Fits `y ~ X b` by QR. `None` when there are fewer rows than columns, the columns are
/// linearly dependent or a value is not finite.
///
/// ```
/// use sts_numerics::lsq::least_squares;
/// let rows = [[1.0, 0.0], [1.0, 1.0], [1.0, 2.0]];
/// let fit = least_squares(&rows, &[1.0, 3.0, 5.0]).expect("independent columns");
/// assert!((fit.coefficients[0] - 1.0).abs() < 1e-12 && (fit.coefficients[1] - 2.0).abs() < 1e-12);
/// ```
pub fn least_squares<const N: usize>(rows: &[[f64; N]], y: &[f64]) -> Option<LinearFit> {
    if rows.len() < N || rows.len() != y.len() || N == 0 {
        return None;
    }
    let x = DMatrix::from_fn(rows.len(), N, |i, j| rows[i][j]);
    let qr = x.qr();
    let r = qr.r();
    let largest = (0..N).map(|i| r[(i, i)].abs()).fold(0.0, f64::max);
    // NaN on the diagonal also counts as dependent.
    let independent = |i: usize| r[(i, i)].abs() > RANK_TOLERANCE * largest;
    if !(0..N).all(independent) {
        return None;
    }
    let mut qty = DVector::from_column_slice(y);
    qr.q_tr_mul(&mut qty);
    let b = r.solve_upper_triangular(&qty.rows(0, N).into_owned())?;
    if !b.iter().all(|c| c.is_finite()) {
        return None;
    }
    let residuals: Vec<f64> =
        rows.iter().zip(y).map(|(row, &yi)| yi - row.iter().zip(b.iter()).map(|(x, c)| x * c).sum::<f64>()).collect();
    let residual_rms = (residuals.iter().map(|r| r * r).sum::<f64>() / residuals.len() as f64).sqrt();
    let residual_max = residuals.iter().fold(0.0f64, |m, r| m.max(r.abs()));
    let degrees_of_freedom = rows.len() - N;
    let standard_errors = if degrees_of_freedom == 0 {
        vec![f64::INFINITY; N]
    } else {
        let s2 = residuals.iter().map(|r| r * r).sum::<f64>() / degrees_of_freedom as f64;
        // (X^T X)^-1 = R^-1 R^-T: its diagonal is the squared norms of R^-1's rows.
        let r_inv = r.try_inverse()?;
        (0..N).map(|j| (s2 * r_inv.row(j).norm_squared()).sqrt()).collect()
    };
    Some(LinearFit { coefficients: b.iter().copied().collect(), residual_rms, residual_max, standard_errors })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lines_standard_errors_are_the_textbook_ones() {
        let x: Vec<f64> = (0..12).map(f64::from).collect();
        let wobble = [0.3, -0.1, 0.2, -0.4, 0.1, 0.0, -0.2, 0.5, -0.3, 0.1, 0.2, -0.4];
        let y: Vec<f64> = x.iter().zip(wobble).map(|(x, w)| 1.5 + 0.25 * x + w).collect();
        let rows: Vec<[f64; 2]> = x.iter().map(|&x| [1.0, x]).collect();
        let fit = least_squares(&rows, &y).unwrap();
        let n = x.len() as f64;
        let mean = x.iter().sum::<f64>() / n;
        let sxx: f64 = x.iter().map(|x| (x - mean) * (x - mean)).sum();
        let s2 = fit.residual_rms * fit.residual_rms * n / (n - 2.0);
        let slope_se = (s2 / sxx).sqrt();
        let intercept_se = (s2 * (1.0 / n + mean * mean / sxx)).sqrt();
        assert!((fit.standard_errors[1] - slope_se).abs() < 1e-12 * slope_se, "{:?}", fit.standard_errors);
        assert!((fit.standard_errors[0] - intercept_se).abs() < 1e-12 * intercept_se, "{:?}", fit.standard_errors);
        let exact = least_squares(&rows[..2], &y[..2]).unwrap();
        assert_eq!(exact.standard_errors, vec![f64::INFINITY; 2]);
    }

    #[test]
    fn solves_a_well_posed_system_and_damping_shrinks_the_step() {
        let x = vec![vec![1.0, 2.0, 3.0, 4.0], vec![1.0, -1.0, 1.0, -1.0]];
        let y: Vec<f64> = (0..4).map(|i| 0.5 * x[0][i] - 2.0 * x[1][i]).collect();
        let stats = Stats::from_columns(&x, &y);
        let b = solve(&[&stats]);
        assert!((b[0] - 0.5).abs() < 1e-6 && (b[1] + 2.0).abs() < 1e-6, "{b:?}");
        let damped = solve_damped(&[&stats], 1.0);
        assert!(damped[0].abs() < 0.5 && damped[1].abs() < 2.0, "{damped:?}");
    }

    #[test]
    fn a_projection_leaves_what_least_squares_leaves() {
        let n = 500;
        let t: Vec<f64> = (0..n).map(|i| i as f64 * 0.013).collect();
        let columns: Vec<Vec<f64>> =
            vec![vec![1.0; n], t.iter().map(|t| t.sin()).collect(), t.iter().map(|t| (3.0 * t).cos()).collect()];
        let y: Vec<f64> = t.iter().map(|t| 0.3 + 2.0 * t.sin() - (3.0 * t).cos() + (7.7 * t).sin() * t).collect();
        let left = Projection::new(&columns).residual(&y);
        let rows: Vec<[f64; 3]> = (0..n).map(|i| [columns[0][i], columns[1][i], columns[2][i]]).collect();
        let fit = least_squares(&rows, &y).expect("independent columns");
        for (i, l) in left.iter().enumerate() {
            let want = y[i] - (0..3).map(|j| fit.coefficients[j] * columns[j][i]).sum::<f64>();
            assert!((l - want).abs() < 1e-12, "{i}: {l} vs {want}");
        }
        // Orthogonal to every column.
        for c in &columns {
            assert!(c.iter().zip(&left).map(|(a, b)| a * b).sum::<f64>().abs() < 1e-9);
        }
    }

    #[test]
    fn mixed_columns_give_the_statistics_of_the_mixed_samples() {
        let n = 300;
        let x: Vec<Vec<f64>> = (0..2).map(|j| (0..n).map(|i| ((i * (j + 3)) as f64 * 0.21).sin()).collect()).collect();
        let r: Vec<f64> = (0..n).map(|i| 0.3 * x[0][i] - 0.8 * x[1][i] + (i as f64 * 0.05).cos() * 0.1).collect();
        let mix = vec![vec![2.0, -1.0], vec![0.5, 0.25], vec![1.0, 0.0]];
        let direct: Vec<Vec<f64>> =
            mix.iter().map(|w| (0..n).map(|i| w[0] * x[0][i] + w[1] * x[1][i]).collect()).collect();
        let (a, b) = (Stats::from_columns(&x, &r).mixed(&mix), Stats::from_columns(&direct, &r));
        assert!((a.residual_ss() - b.residual_ss()).abs() < 1e-9 * b.residual_ss());
        for theta in [[0.1, -0.3, 2.0], [1.0, 1.0, -1.0]] {
            assert!((a.sse(&theta) - b.sse(&theta)).abs() < 1e-9 * b.sse(&theta), "{theta:?}");
        }
        let (ta, tb) = (solve(&[&a]), solve(&[&b]));
        assert_eq!(ta.len(), 3);
        assert!((a.sse(&ta) - b.sse(&tb)).abs() < 1e-6 * b.residual_ss());
    }

    #[test]
    fn blocks_reduce_to_the_factor_of_all_rows() {
        let n = 3 * QR_BLOCK_ROWS + 17;
        let x: Vec<Vec<f64>> = (0..3).map(|j| (0..n).map(|i| ((i * (j + 2)) as f64 * 0.37).sin()).collect()).collect();
        let r: Vec<f64> = (0..n).map(|i| (i as f64 * 0.011).cos()).collect();
        let blocked = Stats::from_columns(&x, &r);
        let whole = triangular_factor(DMatrix::from_fn(n, 4, |i, j| if j < 3 { x[j][i] } else { r[i] }));
        // Equal up to the signs of the rows.
        for i in 0..4 {
            let sign = (blocked.r_factor[(i, i)] * whole[(i, i)]).signum();
            for j in 0..4 {
                assert!((blocked.r_factor[(i, j)] - sign * whole[(i, j)]).abs() < 1e-9, "{i} {j}");
            }
        }
    }

    #[test]
    fn collinear_columns_give_a_finite_answer() {
        let x = vec![vec![1.0, 2.0, 3.0], vec![1.0, 2.0, 3.0]];
        let b = solve(&[&Stats::from_columns(&x, &[2.0, 4.0, 6.0])]);
        assert!(b.iter().all(|v| v.is_finite()) && (b[0] + b[1] - 2.0).abs() < 1e-6, "{b:?}");
    }

    #[test]
    fn stacked_groups_solve_as_the_pooled_samples() {
        let x = [vec![vec![1.0, 2.0, 3.0], vec![1.0, 1.0, 1.0]], vec![vec![4.0, 5.0], vec![1.0, 1.0]]];
        let r = [vec![2.1, 3.9, 6.2], vec![8.1, 9.8]];
        let a = Stats::from_columns(&x[0], &r[0]);
        let b = Stats::from_columns(&x[1], &r[1]);
        let pooled = Stats::from_columns(
            &[[&x[0][0][..], &x[1][0][..]].concat(), [&x[0][1][..], &x[1][1][..]].concat()],
            &[&r[0][..], &r[1][..]].concat(),
        );
        let (theta, theta_pooled) = (solve(&[&a, &b]), solve(&[&pooled]));
        for (u, v) in theta.iter().zip(&theta_pooled) {
            assert!((u - v).abs() < 1e-9, "{theta:?} {theta_pooled:?}");
        }
        assert!((a.sse(&theta) + b.sse(&theta) - pooled.sse(&theta)).abs() < 1e-9);
        // A group with fewer samples than columns still reduces.
        let short = Stats::from_columns(&[vec![1.0], vec![2.0], vec![3.0]], &[1.0]);
        assert!((short.residual_ss() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn recovers_a_plane_and_reports_the_residual() {
        let rows: Vec<[f64; 3]> = (0..20).map(|k| [1.0, k as f64, (k as f64 * 0.7).sin()]).collect();
        let y: Vec<f64> = rows
            .iter()
            .enumerate()
            .map(|(k, r)| 0.5 + 2.0 * r[1] - 3.0 * r[2] + if k % 2 == 0 { 0.01 } else { -0.01 })
            .collect();
        let fit = least_squares(&rows, &y).expect("independent columns");
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
        assert!((s.residual_ss() - r.iter().map(|v| v * v).sum::<f64>()).abs() < 1e-9);
    }
}
