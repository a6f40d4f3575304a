//! Exact zero-order-hold discretisation of the linear plant, by nalgebra's matrix exponential
//! (Padé with scaling and squaring). The emulated machine has its own numerics: the twin's
//! axis discretisation (`sts_twin_core::axis`) is the model under test, so the plant that
//! plays the real machine shares no code with it.

use nalgebra::SMatrix;

/// Number of linear states: slide position, velocity, motor force, two modes (q, q').
pub(crate) const NX: usize = 7;
/// Number of inputs: force command, disturbance force.
pub(crate) const NU: usize = 2;
const NA: usize = NX + NU;

/// `exp([[A, B], [0, 0]] h)` split into `Phi = e^{Ah}` and `Gamma = int_0^h e^{As} ds B`.
pub(crate) fn discretize(a: &[[f64; NX]; NX], b: &[[f64; NU]; NX], h: f64) -> ([[f64; NX]; NX], [[f64; NU]; NX]) {
    let m = SMatrix::<f64, NA, NA>::from_fn(|i, j| match (i < NX, j < NX) {
        (true, true) => a[i][j] * h,
        (true, false) => b[i][j - NX] * h,
        _ => 0.0,
    });
    let e = m.exp();
    let phi = std::array::from_fn(|i| std::array::from_fn(|j| e[(i, j)]));
    let gamma = std::array::from_fn(|i| std::array::from_fn(|j| e[(i, NX + j)]));
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
