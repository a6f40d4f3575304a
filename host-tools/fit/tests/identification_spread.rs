//! The axis identification as it varies with the data below its noise: one machine with sharp
//! Coulomb friction alone, measured over its range (231 groups), identified with friction,
//! hysteresis and ripple as `trial-table` identifies it; then the same measurement with each
//! probe and command reading moved by -10, 0 or +10 pm at random (the probe's noise is 5 nm,
//! the files' rounding 5 pm), identified again. The probe fits must agree within 1.2x: a
//! twin that lands in another valley on such a draw leaves a lab with another twin each time
//! it measures.
//!
//! Long (2-4 minutes on 2 cores): `cargo test -p sts-fit --profile ci --test tests --
//! --ignored identification_spread::`. It fails as the code stands: as measured, every start
//! that survives the grid's halving fits the encoder to 18 nm (command delays 1, 2 and 3
//! alike), where on the moved draws the best reaches 7-10 nm, and the probe fit ends at 50.8
//! nm against 17.1-20.3 nm.

use sts_emulator::MeasureConfig;
use sts_fit::effects::prepare;

/// The identification's probe fit (`axis_tcp_rms_nm`) on `data`.
fn probe_fit_nm(data: &sts_dataset::Dataset) -> f64 {
    let effects = ["coulomb-friction", "presliding-hysteresis", "force-ripple"].map(String::from);
    let prepared = prepare(data, &effects).expect("prepare");
    crate::linear_terms::param(&prepared.records, "coulomb-friction", "axis_tcp_rms_nm")
}

#[test]
#[ignore = "long (five identifications of 231 groups, 2-4 minutes); fails at this commit: 50.8 nm as measured, 17.1-20.3 nm on the draws"]
fn the_friction_twin_is_the_same_from_a_measurement_moved_below_its_noise() {
    let config = MeasureConfig {
        effects: vec!["coulomb-friction".parse().expect("effect")],
        seed: 1,
        freqs_hz: std::iter::once(1.0).chain((1..=20).map(|k| 5.0 * f64::from(k))).collect(),
        ..MeasureConfig::default()
    };
    let data = sts_emulator::measure::run(&config, &|_| {}).expect("measurement");
    let mut fits_nm = vec![probe_fit_nm(&data)];
    for draw in 1..=4u64 {
        let mut moved = data.clone();
        // xorshift: -1, 0 or +1 step of 10 pm per reading.
        let mut state = draw.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let mut step_um = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            ((state % 3) as f64 - 1.0) * 1e-5
        };
        for group in &mut moved.groups {
            for (tcp, cmd) in group.z_tcp_um.iter_mut().zip(group.z_cmd_um.iter_mut()) {
                *tcp += step_um();
                *cmd += step_um();
            }
        }
        fits_nm.push(probe_fit_nm(&moved));
    }
    let (low, high) = fits_nm.iter().fold((f64::INFINITY, 0.0f64), |(l, h), x| (l.min(*x), h.max(*x)));
    println!("the identification's probe fit, as measured and on four draws: {fits_nm:.1?} nm");
    assert!(high <= 1.2 * low, "probe fits from {low:.1} to {high:.1} nm: {fits_nm:.1?}");
}
