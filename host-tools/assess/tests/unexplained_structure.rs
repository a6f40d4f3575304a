//! Structure that no candidate explains is shown where it lies, not named as the nearest
//! effect: a machine whose probe also sees a floor vibration at 137 Hz (an effect outside the
//! library), diagnosed against the twin of the clean machine.

use sts_assess::diagnose::diagnose;
use sts_emulator::MeasureConfig;
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
