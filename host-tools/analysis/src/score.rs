//! How well predictions match measurements: R^2, with phases compared on the circle.

use crate::sine::wrap_deg;

/// R^2 of predictions against measurements.
pub fn r_squared(measured: &[f64], predicted: &[f64]) -> f64 {
    let n = measured.len().min(predicted.len());
    if n == 0 {
        return f64::NAN;
    }
    let mean = measured[..n].iter().sum::<f64>() / n as f64;
    let total: f64 = measured[..n].iter().map(|m| (m - mean).powi(2)).sum();
    let residual: f64 = measured[..n].iter().zip(&predicted[..n]).map(|(m, p)| (m - p).powi(2)).sum();
    if total == 0.0 {
        return if residual == 0.0 { 1.0 } else { f64::NEG_INFINITY };
    }
    1.0 - residual / total
}

/// Phase R^2 on wrapped differences (a 359 vs -1 degree pair is a 0 degree error).
pub fn phase_r_squared(measured_deg: &[f64], predicted_deg: &[f64]) -> f64 {
    let unwrapped: Vec<f64> = measured_deg.iter().zip(predicted_deg).map(|(m, p)| m + wrap_deg(p - m)).collect();
    r_squared(measured_deg, &unwrapped)
}
