//! Exact zero-order-hold discretisation of the linear plant (matrix exponential).

/// Number of linear states: slide position, velocity, motor force, two modes (q, q').
pub(crate) const NX: usize = 7;
/// Number of inputs: force command, disturbance force.
pub(crate) const NU: usize = 2;
const NA: usize = NX + NU;

type Mat = [[f64; NA]; NA];

fn mul(a: &Mat, b: &Mat) -> Mat {
    let mut c = [[0.0; NA]; NA];
    for i in 0..NA {
        for k in 0..NA {
            let aik = a[i][k];
            if aik != 0.0 {
                for j in 0..NA {
                    c[i][j] += aik * b[k][j];
                }
            }
        }
    }
    c
}

/// `exp([[A, B], [0, 0]] h)` split into `Phi = e^{Ah}` and `Gamma = int_0^h e^{As} ds B`.
pub(crate) fn discretize(a: &[[f64; NX]; NX], b: &[[f64; NU]; NX], h: f64) -> ([[f64; NX]; NX], [[f64; NU]; NX]) {
    let mut m: Mat = [[0.0; NA]; NA];
    for i in 0..NX {
        for j in 0..NX {
            m[i][j] = a[i][j] * h;
        }
        for j in 0..NU {
            m[i][NX + j] = b[i][j] * h;
        }
    }
    // Scaling and squaring with a Taylor series: fine for these small, well-scaled matrices.
    let norm = m.iter().map(|r| r.iter().map(|v| v.abs()).sum::<f64>()).fold(0.0, f64::max);
    let mut squarings = 0;
    let mut scale = 1.0;
    while norm * scale > 0.25 {
        scale *= 0.5;
        squarings += 1;
    }
    for row in m.iter_mut() {
        for v in row.iter_mut() {
            *v *= scale;
        }
    }
    let mut result: Mat = [[0.0; NA]; NA];
    let mut term: Mat = [[0.0; NA]; NA];
    for i in 0..NA {
        result[i][i] = 1.0;
        term[i][i] = 1.0;
    }
    for k in 1..=16 {
        term = mul(&term, &m);
        for row in term.iter_mut() {
            for v in row.iter_mut() {
                *v /= k as f64;
            }
        }
        for i in 0..NA {
            for j in 0..NA {
                result[i][j] += term[i][j];
            }
        }
    }
    for _ in 0..squarings {
        result = mul(&result, &result);
    }
    let mut phi = [[0.0; NX]; NX];
    let mut gamma = [[0.0; NU]; NX];
    for i in 0..NX {
        phi[i].copy_from_slice(&result[i][..NX]);
        gamma[i].copy_from_slice(&result[i][NX..]);
    }
    (phi, gamma)
}

#[cfg(test)]
mod tests {
    #[test]
    fn double_integrator_is_exact() {
        let mut a = [[0.0; super::NX]; super::NX];
        let mut b = [[0.0; super::NU]; super::NX];
        a[0][1] = 1.0;
        b[1][0] = 1.0;
        let (phi, gamma) = super::discretize(&a, &b, 0.5);
        assert!((phi[0][1] - 0.5).abs() < 1e-15);
        assert!((gamma[0][0] - 0.125).abs() < 1e-15);
        assert!((gamma[1][0] - 0.5).abs() < 1e-15);
    }
}
