//! Zero-order-hold discretisation of the axis's linear part, in f64 from `+ * /` only (a
//! matrix exponential by Taylor series with scaling and squaring), so that the firmware
//! (soft-float f64) and the host derive the same single-precision coefficients.

/// States: slide position (m), velocity (m/s), motor force per kg (m/s^2), modal
/// displacement at the TCP (m) and its rate (m/s).
pub const STATES: usize = 5;
/// Inputs: force command per kg and nonlinear force per kg (m/s^2), held over a tick.
pub const INPUTS: usize = 2;
const N: usize = STATES + INPUTS;

type Mat = [[f64; N]; N];

fn mul(a: &Mat, b: &Mat) -> Mat {
    let mut out = [[0.0; N]; N];
    for (i, row) in out.iter_mut().enumerate() {
        for (j, cell) in row.iter_mut().enumerate() {
            let mut acc = 0.0;
            for k in 0..N {
                acc += a[i][k] * b[k][j];
            }
            *cell = acc;
        }
    }
    out
}

/// `exp(a)`: Taylor series of degree 18 on `a / 2^s` with `|a| / 2^s <= 1/2` (infinity
/// norm), then `s` squarings.
fn expm(a: &Mat) -> Mat {
    let norm = a.iter().map(|row| row.iter().map(|x| if *x < 0.0 { -*x } else { *x }).sum::<f64>()).fold(0.0, f64::max);
    let (mut scale, mut squarings) = (1.0, 0u32);
    // The caller has checked every entry is finite and bounded; 64 squarings cover any norm it passes.
    while norm * scale > 0.5 && squarings < 64 {
        scale *= 0.5;
        squarings += 1;
    }
    let mut x = [[0.0; N]; N];
    for i in 0..N {
        for j in 0..N {
            x[i][j] = a[i][j] * scale;
        }
    }
    let mut term = [[0.0; N]; N];
    let mut sum = [[0.0; N]; N];
    for i in 0..N {
        term[i][i] = 1.0;
        sum[i][i] = 1.0;
    }
    for k in 1..=18 {
        term = mul(&term, &x);
        let inv = 1.0 / k as f64;
        for i in 0..N {
            for j in 0..N {
                term[i][j] *= inv;
                sum[i][j] += term[i][j];
            }
        }
    }
    for _ in 0..squarings {
        sum = mul(&sum, &sum);
    }
    sum
}

/// The continuous model, all forces per kg of moving mass.
pub struct Continuous {
    /// Viscous drag per kg, 1/s.
    pub viscous_per_s: f64,
    /// Current-loop time constant, s.
    pub current_tau_s: f64,
    /// Mode angular frequency, rad/s.
    pub mode_rad_per_s: f64,
    /// Mode damping ratio.
    pub mode_damping: f64,
    /// Modal displacement at the TCP per unit of slide motion.
    pub mode_tcp_gain: f64,
}

/// `(phi, gamma)` over `tick_s`: `s' = phi s + gamma [u, F]`.
pub fn zoh(model: &Continuous, tick_s: f64) -> ([[f64; STATES]; STATES], [[f64; INPUTS]; STATES]) {
    let c = model.viscous_per_s;
    let w = model.mode_rad_per_s;
    let g = model.mode_tcp_gain;
    let mut a = [[0.0; N]; N];
    a[0][1] = 1.0;
    a[1] = [0.0, -c, 1.0, 0.0, 0.0, 0.0, 1.0];
    a[2][2] = -1.0 / model.current_tau_s;
    a[2][5] = 1.0 / model.current_tau_s;
    a[3][4] = 1.0;
    // The mode is driven by the slide's acceleration: q'' + 2 zeta w q' + w^2 q = -g a.
    a[4] = [0.0, g * c, -g, -w * w, -2.0 * model.mode_damping * w, 0.0, -g];
    for row in a.iter_mut() {
        for x in row.iter_mut() {
            *x *= tick_s;
        }
    }
    let e = expm(&a);
    let mut phi = [[0.0; STATES]; STATES];
    let mut gamma = [[0.0; INPUTS]; STATES];
    for i in 0..STATES {
        phi[i].copy_from_slice(&e[i][..STATES]);
        gamma[i].copy_from_slice(&e[i][STATES..]);
    }
    (phi, gamma)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_free_mass_integrates_exactly() {
        // No drag, instant current loop approximated by a 1 ns lag: v grows by F h, x by F h^2 / 2.
        let model = Continuous {
            viscous_per_s: 0.0,
            current_tau_s: 1e-9,
            mode_rad_per_s: 100.0,
            mode_damping: 0.5,
            mode_tcp_gain: 0.0,
        };
        let (phi, gamma) = zoh(&model, 1e-3);
        assert!((phi[0][1] - 1e-3).abs() < 1e-15);
        assert!((gamma[1][1] - 1e-3).abs() < 1e-15);
        assert!((gamma[0][1] - 0.5e-6).abs() < 1e-15);
        assert!((phi[0][0] - 1.0).abs() < 1e-15 && (phi[1][1] - 1.0).abs() < 1e-15);
    }

    #[test]
    fn the_mode_oscillates_at_its_frequency() {
        let w = 2.0 * core::f64::consts::PI * 90.0;
        let model = Continuous {
            viscous_per_s: 6.7,
            current_tau_s: 80e-6,
            mode_rad_per_s: w,
            mode_damping: 0.0,
            mode_tcp_gain: 2.0,
        };
        let (phi, _) = zoh(&model, 125e-6);
        // Undamped: the (q, q') block is a rotation by w h.
        let wh = w * 125e-6;
        assert!((phi[3][3] - wh.cos()).abs() < 1e-12, "{}", phi[3][3]);
        assert!((phi[3][4] - wh.sin() / w).abs() < 1e-12);
    }
}
