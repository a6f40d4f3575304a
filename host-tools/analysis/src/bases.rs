//! Regression bases shared by diagnose's candidates and the effects' identification.

/// Laguerre filter bank outputs of `u` (whole group), kept over `start..`.
pub fn laguerre(u: &[f64], start: usize, a: f64, stages: usize) -> Vec<Vec<f64>> {
    let g = (1.0 - a * a).sqrt();
    let mut out = vec![Vec::with_capacity(u.len().saturating_sub(start)); stages];
    let mut y = vec![0.0; stages];
    for (k, &uk) in u.iter().enumerate() {
        let mut prev_old = y[0];
        let mut prev_new = a * y[0] + g * uk;
        y[0] = prev_new;
        for yi in y.iter_mut().skip(1) {
            let old = *yi;
            let new = a * old - a * prev_new + prev_old;
            *yi = new;
            prev_old = old;
            prev_new = new;
        }
        if k >= start {
            for (o, v) in out.iter_mut().zip(&y) {
                o.push(*v);
            }
        }
    }
    out
}
