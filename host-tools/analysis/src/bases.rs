//! Regression bases shared by diagnose's candidates and the effects' identification.
//!
//! The Laguerre bank is the hot loop of `diagnose` (a sixth of its time: every candidate's
//! grid filters each group whole, warm-up included), so its common sizes run on a stage state
//! held in registers rather than in a `Vec`; every size computes the same arithmetic in the
//! same order, so the outputs are the same bits whichever path runs (the test checks it).

/// Pole of the Laguerre banks that model the servo's response to a disturbance, in the
/// diagnosis's candidates and in the effect terms fitted for them alike.
pub const LAGUERRE_POLE: f64 = 0.93;

/// Laguerre filter bank outputs of `u` (whole group), kept over `start..`.
pub fn laguerre(u: &[f64], start: usize, a: f64, stages: usize) -> Vec<Vec<f64>> {
    match stages {
        4 => laguerre_fixed::<4>(u, start, a),
        8 => laguerre_fixed::<8>(u, start, a),
        16 => laguerre_fixed::<16>(u, start, a),
        _ => laguerre_any(u, start, a, stages),
    }
}

/// One sample through the bank: stage 0 a first-order low pass, each further stage an
/// all-pass section fed by the one before.
#[inline(always)]
fn step(y: &mut [f64], uk: f64, a: f64, g: f64) {
    let Some((first, rest)) = y.split_first_mut() else { return };
    let mut prev_old = *first;
    let mut prev_new = a * *first + g * uk;
    *first = prev_new;
    for yi in rest {
        let old = *yi;
        let new = a * old - a * prev_new + prev_old;
        *yi = new;
        prev_old = old;
        prev_new = new;
    }
}

fn laguerre_fixed<const N: usize>(u: &[f64], start: usize, a: f64) -> Vec<Vec<f64>> {
    let g = (1.0 - a * a).sqrt();
    let start = start.min(u.len());
    let mut y = [0.0; N];
    for &uk in &u[..start] {
        step(&mut y, uk, a, g);
    }
    let rows: Vec<[f64; N]> = u[start..]
        .iter()
        .map(|&uk| {
            step(&mut y, uk, a, g);
            y
        })
        .collect();
    (0..N).map(|i| rows.iter().map(|r| r[i]).collect()).collect()
}

fn laguerre_any(u: &[f64], start: usize, a: f64, stages: usize) -> Vec<Vec<f64>> {
    let g = (1.0 - a * a).sqrt();
    let mut out = vec![Vec::with_capacity(u.len().saturating_sub(start)); stages];
    let mut y = vec![0.0; stages];
    for (k, &uk) in u.iter().enumerate() {
        step(&mut y, uk, a, g);
        if k >= start {
            for (o, v) in out.iter_mut().zip(&y) {
                o.push(*v);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_size_gives_the_same_bits_as_the_general_bank() {
        let u: Vec<f64> =
            (0..3000).map(|k| (k as f64 * 0.013).sin() + 0.3 * (k as f64 * 0.41).cos().signum()).collect();
        for stages in [4, 8, 16] {
            for start in [0, 1234, 3000, 4000] {
                let fast = laguerre(&u, start, 0.93, stages);
                let general = laguerre_any(&u, start, 0.93, stages);
                assert_eq!(fast.len(), stages);
                assert_eq!(fast[0].len(), u.len().saturating_sub(start));
                let bits = |b: &[Vec<f64>]| b.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&fast), bits(&general), "{stages} stages from {start}");
            }
        }
    }

    #[test]
    fn the_first_stage_settles_at_its_dc_gain() {
        // Stage 0 is sqrt(1 - a^2) / (1 - a z^-1): a step settles at sqrt((1 + a) / (1 - a)).
        let a: f64 = 0.9;
        let out = laguerre(&vec![1.0; 400], 0, a, 4);
        let settled = *out[0].last().expect("samples");
        assert!((settled - ((1.0 + a) / (1.0 - a)).sqrt()).abs() < 1e-9, "{settled}");
    }
}
