//! The upper-triangular factor `R` of a QR decomposition, by Householder reflections.
//!
//! Written by hand because it is the hot loop of every fit (diagnose and explain spent about a
//! quarter of their time in nalgebra's `qr()`), and no crate of the dependency tree forms `R`
//! alone: nalgebra's decomposition keeps the reflectors for `Q`, reflects through generic
//! column views and starts from the whole matrix. Here rows are added to a factor in blocks
//! ([`Triangular::absorb`]); each reflection touches only the factor's row and the block's
//! rows, on contiguous columns. The measured difference is in BENCHMARKS.md, "Least squares".

use nalgebra::DMatrix;

/// An upper-triangular `cols x cols` factor, column-major.
#[derive(Clone, Debug)]
pub(super) struct Triangular {
    cols: usize,
    r: Vec<f64>,
}

impl Triangular {
    /// The factor of no rows.
    pub(super) fn zeros(cols: usize) -> Self {
        Self { cols, r: vec![0.0; cols * cols] }
    }

    /// Reduces `[R; block]` to its triangular factor, `block` holding `rows` rows column-major
    /// (it is used as scratch): `R'^T R' = R^T R + block^T block`.
    pub(super) fn absorb(&mut self, block: &mut [f64], rows: usize) {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU supports AVX2 (checked just above).
                return unsafe { self.absorb_avx2(block, rows) };
            }
        }
        self.absorb_generic(block, rows)
    }

    /// [`Triangular::absorb`] compiled for AVX2 (4 lanes instead of SSE2's 2): the same IEEE
    /// operations in the same order (no FMA, which Rust never contracts to), so the same bits.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn absorb_avx2(&mut self, block: &mut [f64], rows: usize) {
        self.absorb_generic(block, rows)
    }

    /// The body of [`Triangular::absorb`], for every instruction set.
    #[inline(always)]
    fn absorb_generic(&mut self, block: &mut [f64], rows: usize) {
        let c = self.cols;
        assert_eq!(block.len(), rows * c, "a block of {rows} rows and {c} columns");
        if rows == 0 {
            return;
        }
        for k in 0..c {
            let (done, rest) = block.split_at_mut((k + 1) * rows);
            let v = &done[k * rows..];
            let sigma = dot(v, v);
            if sigma == 0.0 {
                continue;
            }
            // The reflection that maps (R[k][k], v) onto (alpha, 0), with alpha's sign opposite
            // to R[k][k] so that R[k][k] - alpha does not cancel; 2 / |u|^2 in closed form.
            let x0 = self.r[k * c + k];
            let norm = (x0 * x0 + sigma).sqrt();
            let alpha = if x0 >= 0.0 { -norm } else { norm };
            let u0 = x0 - alpha;
            let beta = 1.0 / (norm * (norm + x0.abs()));
            for (j, column) in rest.chunks_exact_mut(rows).enumerate() {
                let rkj = &mut self.r[(k + 1 + j) * c + k];
                let f = beta * (u0 * *rkj + dot(v, column));
                *rkj -= f * u0;
                for (y, x) in column.iter_mut().zip(v) {
                    *y -= f * x;
                }
            }
            self.r[k * c + k] = alpha;
        }
    }

    /// The factor as a matrix.
    pub(super) fn into_matrix(self) -> DMatrix<f64> {
        DMatrix::from_vec(self.cols, self.cols, self.r)
    }
}

/// The triangular factor of `m`, square (zero rows below when `m` has fewer rows than columns).
pub(super) fn triangular_factor(mut m: DMatrix<f64>) -> DMatrix<f64> {
    let (rows, cols) = m.shape();
    let mut factor = Triangular::zeros(cols);
    factor.absorb(m.as_mut_slice(), rows);
    factor.into_matrix()
}

/// `a . b` in eight interleaved sums, which the compiler vectorises and whose additions do
/// not wait on each other (one running sum cannot be reordered).
#[inline(always)]
pub(super) fn dot(a: &[f64], b: &[f64]) -> f64 {
    const LANES: usize = 8;
    let mut sums = [0.0f64; LANES];
    let (a8, b8) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let tail: f64 = a8.remainder().iter().zip(b8.remainder()).map(|(x, y)| x * y).sum();
    for (x, y) in a8.zip(b8) {
        for l in 0..LANES {
            sums[l] += x[l] * y[l];
        }
    }
    ((sums[0] + sums[1]) + (sums[2] + sums[3])) + ((sums[4] + sums[5]) + (sums[6] + sums[7])) + tail
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `R^T R` of a factor.
    fn gram(r: &DMatrix<f64>) -> DMatrix<f64> {
        r.transpose() * r
    }

    #[test]
    fn the_factor_is_triangular_and_keeps_the_gram_matrix() {
        let (n, c) = (37, 5);
        let m = DMatrix::from_fn(n, c, |i, j| ((i * 7 + j * 13) as f64 * 0.61).sin() + if j == 2 { 3.0 } else { 0.0 });
        let r = triangular_factor(m.clone());
        for j in 0..c {
            for i in j + 1..c {
                assert_eq!(r[(i, j)], 0.0, "below the diagonal at {i} {j}");
            }
        }
        let (want, got) = (gram(&m), gram(&r));
        assert!((want - got).abs().max() < 1e-12 * m.norm_squared(), "R^T R differs from M^T M");
        // nalgebra's factor, up to the signs of the rows.
        let theirs = m.qr().r();
        for i in 0..c {
            let sign = (r[(i, i)] * theirs[(i, i)]).signum();
            for j in i..c {
                assert!((r[(i, j)] - sign * theirs[(i, j)]).abs() < 1e-12, "{i} {j}");
            }
        }
    }

    #[test]
    fn blocks_absorbed_one_after_another_give_the_factor_of_all_rows() {
        let (n, c) = (100, 4);
        let m = DMatrix::from_fn(n, c, |i, j| ((i * (j + 2)) as f64 * 0.37).cos());
        let whole = triangular_factor(m.clone());
        let mut factor = Triangular::zeros(c);
        for (start, rows) in [(0, 30), (30, 1), (31, 69)] {
            let mut block = m.rows(start, rows).into_owned();
            factor.absorb(block.as_mut_slice(), rows);
        }
        let blocked = factor.into_matrix();
        assert!((blocked - whole).abs().max() < 1e-12);
    }

    #[test]
    fn zero_and_short_inputs_give_a_square_factor() {
        let r = triangular_factor(DMatrix::from_row_slice(1, 3, &[3.0, 0.0, 4.0]));
        assert_eq!(r.shape(), (3, 3));
        assert!((r[(0, 0)].abs() - 3.0).abs() < 1e-15 && (r[(0, 2)].abs() - 4.0).abs() < 1e-15);
        assert!(r.row(1).iter().chain(r.row(2).iter()).all(|&v| v == 0.0));
        let zero = triangular_factor(DMatrix::zeros(5, 2));
        assert!(zero.iter().all(|&v| v == 0.0));
    }

    #[test]
    fn a_non_finite_value_stays_visible() {
        let r = triangular_factor(DMatrix::from_row_slice(2, 2, &[1.0, f64::NAN, 2.0, 1.0]));
        assert!(r.iter().any(|v| v.is_nan()));
    }
}
