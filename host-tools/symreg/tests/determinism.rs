//! Same data, seed and thread count give the same result bit for bit (and the thread count
//! does not matter either); a different seed explores differently.
use sts_symreg::planted::{generate, Planted};
use sts_symreg::{fit, SearchConfig, SearchResult};

fn run(seed: u64, threads: usize) -> SearchResult {
    let (x, y) = generate(Planted::P2, 4, 99);
    // A fixed, short budget without early stop, so every run does the same amount of work.
    let cfg = SearchConfig {
        seed,
        threads,
        max_epochs: 3,
        islands: 4,
        offspring_per_epoch: 100,
        early_stop_nmse: None,
        ..SearchConfig::default()
    };
    fit(&x, &y, &cfg, |_| {}).expect("search runs")
}

/// Bit-exact fingerprint: `{:?}` prints every f64 with round-trip precision.
fn fingerprint(r: &SearchResult) -> String {
    format!("{r:?}")
}

#[test]
fn same_seed_and_threads_give_identical_results() {
    let a = run(7, 2);
    let b = run(7, 2);
    assert_eq!(fingerprint(&a), fingerprint(&b));
    assert_eq!(a, b);
    for (ma, mb) in a.front.iter().zip(&b.front) {
        assert_eq!(ma.loss.to_bits(), mb.loss.to_bits());
        for (ca, cb) in ma.expr.constants().iter().zip(mb.expr.constants()) {
            assert_eq!(ca.to_bits(), cb.to_bits());
        }
    }
}

#[test]
fn thread_count_does_not_change_the_result() {
    assert_eq!(fingerprint(&run(7, 1)), fingerprint(&run(7, 3)));
}

#[test]
fn different_seeds_explore_differently() {
    assert_ne!(fingerprint(&run(7, 2)), fingerprint(&run(8, 2)));
}
