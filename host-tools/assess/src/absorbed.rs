//! When a hidden effect that the tools did not name counts as absorbed by the twin: only where
//! the data shows it. The suites of this crate and the CLI's foreign-machine tests judge a
//! miss by this one rule.

/// The twin's error within this factor of the clean machine's twin's error...
pub const ABSORBED_WITHIN: f64 = 1.2;
/// ...and a refit with the effect lowering that error by less than this fraction.
pub const ABSORBED_MAX_GAIN: f64 = 0.1;

/// Whether a refit with a missed effect (`refit_um`) leaves the twin's error (`twin_um`) as it
/// was, within [`ABSORBED_MAX_GAIN`].
pub fn refit_gains_nothing(refit_um: f64, twin_um: f64) -> bool {
    refit_um >= (1.0 - ABSORBED_MAX_GAIN) * twin_um
}

/// Whether a missed effect counts as absorbed: the twin (`twin_um`) within [`ABSORBED_WITHIN`]
/// of the clean twin's error (`clean_um`) and the refit with the effect (`refit_um`) gaining
/// nothing.
pub fn absorbed(twin_um: f64, clean_um: f64, refit_um: f64) -> bool {
    twin_um <= ABSORBED_WITHIN * clean_um && refit_gains_nothing(refit_um, twin_um)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_miss_is_absorbed_only_near_the_clean_error_and_where_the_refit_gains_nothing() {
        assert!(absorbed(1.1, 1.0, 1.05));
        assert!(!absorbed(1.3, 1.0, 1.3), "too far from clean");
        assert!(!absorbed(1.1, 1.0, 0.9), "the refit gains 18%");
    }
}
