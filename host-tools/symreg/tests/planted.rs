//! The engine recovers the planted forms (CI-sized versions; the full 10-seed benchmark
//! against the peers is `bench/symreg-peers/run.py`).
use sts_symreg::planted::{generate, is_exact_recovery, Planted};
use sts_symreg::{fit, Matrix, OperatorSet, SearchConfig};

#[test]
fn p1_exact_form_is_selected() {
    let (x, y) = generate(Planted::P1, 0, 99);
    let cfg = SearchConfig { seed: 0, ..SearchConfig::default() };
    let r = fit(&x, &y, &cfg, |_| {}).unwrap();
    let best = r.best();
    assert!(is_exact_recovery(Planted::P1, &best.expr), "{}\n{}", best.expr, r.explanation);
    assert_eq!(best.complexity, 9, "{}", r.explanation);
}

#[test]
fn p2_exact_form_is_selected_without_distractors() {
    // Reduced: only the two relevant features and the operators + - * tanh.
    let (x_full, y) = generate(Planted::P2, 1, 99);
    let rows: Vec<Vec<f64>> = (0..x_full.n_rows()).map(|r| x_full.row(r)[..2].to_vec()).collect();
    let x = Matrix::from_rows(&rows).unwrap();
    let cfg = SearchConfig { seed: 1, operators: OperatorSet::parse("+,-,*,tanh").unwrap(), ..SearchConfig::default() };
    let r = fit(&x, &y, &cfg, |_| {}).unwrap();
    let best = r.best();
    assert!(is_exact_recovery(Planted::P2, &best.expr), "{}\n{}", best.expr, r.explanation);
    // The selection rule picks neither a simpler approximation nor a bigger exact form.
    assert!(r.front[..r.selected].iter().all(|m| !is_exact_recovery(Planted::P2, &m.expr)));
}

#[test]
fn noisy_target_selects_the_true_form_not_the_most_complex() {
    // y = 3*x0/x1 + noise (1% of the spread): the front keeps improving slightly with
    // complexity by fitting noise; the rule must stop at the true form.
    let (x, _) = generate(Planted::P1, 5, 99);
    let mut noise_state = 12345u64;
    let y: Vec<f64> = (0..x.n_rows())
        .map(|r| {
            noise_state = noise_state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let u = (noise_state >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
            3.0 * x.get(r, 0) / x.get(r, 1) + 0.05 * u
        })
        .collect();
    let cfg = SearchConfig { seed: 2, max_epochs: 12, ..SearchConfig::default() };
    let r = fit(&x, &y, &cfg, |_| {}).unwrap();
    let best = r.best();
    assert!(best.complexity <= 7, "picked complexity {}:\n{}", best.complexity, r.explanation);
    assert!(best.r2 > 0.99, "{}", r.explanation);
    assert!(best.expr.uses_var(0) && best.expr.uses_var(1), "{}", r.explanation);
}
