//! The 40 Hz bicuspid cut's form error and phase error against the feed (how fast the cut's
//! amplitude shrinks), for the range twin of the default machine and the friction axis twin
//! (the hil-tests' fixtures), the core on the host:
//!
//! ```text
//! cargo run --release -p sts-rig --example phase_vs_feed
//! ```

use sts_emulator::{EffectSpec, PlantParams};
use sts_model::ModelFile;
use sts_rig::trial::{calibrated, run_trial, TrialConfig};
use sts_rig::SimCoprocessor;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let fixtures = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../hil-tests/fixtures");
    let friction: EffectSpec = "coulomb-friction:coulomb_n=3,static_n=4.5,stribeck_mps=2e-4".parse()?;
    let cases = [("twin-range-default-machine.json", vec![]), ("twin-friction-axis.json", vec![friction])];
    let plant = PlantParams::default();
    println!("| twin | feed, um/rev | form error PV, um | phase error, deg |");
    println!("|---|---|---|---|");
    for (name, effects) in &cases {
        let model = ModelFile::read(&fixtures.join(name))?;
        for feed_um_per_rev in [1.25, 2.5, 5.0, 10.0] {
            let mut cop = SimCoprocessor::boot(&[]);
            let (params, _) = calibrated(&mut cop, &plant, effects, 1, true)?;
            let config = TrialConfig { feed_um_per_rev, ..TrialConfig::default() };
            let r = run_trial(&mut cop, &plant, effects, Some(&model), params, &config)?;
            println!("| {name} | {feed_um_per_rev} | {:.4} | {:+.4} |", r.form_error_pv_um, r.phase_error_deg);
        }
    }
    Ok(())
}
