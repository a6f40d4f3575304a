//! Structure that no candidate explains is shown where it lies, not named as the nearest
//! effect: a machine whose probe also sees a floor vibration at 137 Hz (an effect outside the
//! library), diagnosed against the twin of the clean machine. And where the groups are too few
//! for the test to name anything, the tool says that, not `none`.

use sts_assess::diagnose::{diagnose, groups_needed};
use sts_assess::explain::{explain, ExplainConfig, Stop};
use sts_emulator::{EffectSpec, MeasureConfig};
use sts_fit::{fit, FitConfig};

#[test]
fn a_vibration_outside_the_library_is_reported_as_a_line_not_named_as_an_effect() {
    let config = MeasureConfig { seed: 31, duration_s: 5.5, ..MeasureConfig::default() };
    let clean = sts_emulator::measure::run(&config, &|_| {}).expect("measurement");
    let twin = fit(&clean, "clean", &FitConfig { max_epochs: 10, ..FitConfig::default() }, &mut |_| {}).expect("fit");

    // The clean twin on its own machine: nothing to report.
    let own = diagnose(&clean, &twin).expect("diagnose");
    assert_eq!(own.verdict, "none");
    assert!(own.unexplained.is_none(), "{:?}", own.unexplained);

    // The same machine on a floor that vibrates: 40 nm at 137 Hz in the probe reading,
    // its phase running on with machine time.
    let mut shaken = sts_emulator::measure::run(&MeasureConfig { seed: 32, ..config }, &|_| {}).expect("measurement");
    for (g, info) in shaken.groups.iter_mut().zip(&shaken.manifest.groups) {
        for (z, t) in g.z_tcp_um.iter_mut().zip(&g.t_s) {
            *z += 0.040 * (2.0 * std::f64::consts::PI * 137.0 * (info.start_s + t)).sin();
        }
    }
    let d = diagnose(&shaken, &twin).expect("diagnose");
    assert_eq!(d.verdict, "none", "{}", d.summary);
    let line = d.structure.line.as_ref().expect("a line");
    assert!((line.freq_hz - 137.0).abs() <= 1.0, "{line:?}");
    assert!((line.rms_um - 0.040 / 2f64.sqrt()).abs() < 0.01, "{line:?}");
    assert!(d.structure.rest.rms_um > d.structure.fundamental.rms_um, "{:?}", d.structure);
    // The vibration does not repeat with the command's period, so it is most of the data's
    // floor; the report still names it as a line, not as noise.
    let text = d.unexplained.expect("the line is reported");
    assert!(text.contains("a line at 137 Hz"), "{text}");
    println!("{}\nunexplained: {text}", d.summary);
}

/// A drifting machine measured on 8 groups: the drift explains half the residual, but no
/// candidate can be significant on so few, and `explain` stops saying so instead of `none`.
#[test]
fn too_few_groups_stop_the_ladder_as_such_not_as_none() {
    let config = MeasureConfig {
        seed: 4,
        freqs_hz: vec![5.0, 10.0, 20.0, 40.0],
        amps_um: vec![2.0, 8.0],
        effects: vec!["thermal-drift".parse::<EffectSpec>().expect("an effect")],
        ..MeasureConfig::default()
    };
    let data = sts_emulator::measure::run(&config, &|_| {}).expect("measurement");
    assert!(data.groups.len() < groups_needed());
    let config = ExplainConfig { fit: FitConfig { max_epochs: 10, ..FitConfig::default() }, max_effects: 3 };
    let e = explain(&data, "eight groups", None, &config, &mut |_| {}).expect("explain");
    assert!(e.steps.is_empty(), "{:?}", e.steps.iter().map(|s| &s.effect).collect::<Vec<_>>());
    assert_eq!(e.stop, Stop::TooFewGroups { groups: 8, needed: groups_needed() });
    assert_eq!(e.stop.verdict(), "too-few-groups");
    assert!(e.last.summary.starts_with("no candidate can be significant on 8 groups"), "{}", e.last.summary);
    let text = e.last.unexplained.as_deref().unwrap_or_default();
    assert!(text.is_empty() || text.contains("does not tell which effect"), "{text}");
    // A script reading `diagnose --json` sees it too.
    let json = sts_assess::json::diagnosis(&e.last, &data);
    assert_eq!((json["groups"].as_u64(), json["groups_needed"].as_u64()), (Some(8), Some(groups_needed() as u64)));
    println!("{}\n{}", e.stop.describe(), e.last.summary);
}
