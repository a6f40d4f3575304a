//! The HTML report renders in a real browser: headless Chromium loads it, its DOM has the
//! charts and tables, and its screenshot is a picture, not a blank page.
//!
//! Skips (with a message) only when `chromium` is not installed and `STS_TWIN_REQUIRE_BROWSER`
//! is not set; CI sets it and installs Debian's `chromium` package.

use std::path::{Path, PathBuf};
use std::process::Command;

use sts_assess::compare::compare;
use sts_assess::diagnose::diagnose;
use sts_emulator::{EffectSpec, MeasureConfig};
use sts_fit::{fit, FitConfig};
use sts_twin::report::{render, ReportInput};

fn chromium() -> Option<PathBuf> {
    for name in ["chromium", "chromium-browser"] {
        for dir in std::env::var("PATH").unwrap_or_default().split(':') {
            let p = Path::new(dir).join(name);
            if p.is_file() {
                return Some(p);
            }
        }
    }
    None
}

fn small_measurement(effects: Vec<EffectSpec>, seed: u64) -> sts_dataset::Dataset {
    let config = MeasureConfig {
        freqs_hz: vec![5.0, 20.0, 40.0],
        amps_um: vec![2.0, 6.0, 10.0],
        duration_s: 5.5,
        effects,
        seed,
        ..MeasureConfig::default()
    };
    sts_emulator::measure::run(&config, &|_| {}).expect("measurement")
}

fn run_chromium(browser: &Path, profile: &Path, args: &[String]) -> std::process::Output {
    let mut cmd = Command::new(browser);
    cmd.args([
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        "--hide-scrollbars",
    ]);
    cmd.arg(format!("--user-data-dir={}", profile.display()));
    cmd.args(args);
    cmd.output().expect("chromium runs")
}

/// Width and height from a PNG's IHDR chunk.
fn png_size(bytes: &[u8]) -> Option<(u32, u32)> {
    if bytes.len() < 24 || &bytes[..8] != b"\x89PNG\r\n\x1a\n" || &bytes[12..16] != b"IHDR" {
        return None;
    }
    Some((u32::from_be_bytes(bytes[16..20].try_into().ok()?), u32::from_be_bytes(bytes[20..24].try_into().ok()?)))
}

#[test]
fn the_report_renders_in_headless_chromium() {
    let Some(browser) = chromium() else {
        if std::env::var_os("STS_TWIN_REQUIRE_BROWSER").is_some() {
            panic!("STS_TWIN_REQUIRE_BROWSER is set but chromium is not installed (apt-get install -y chromium)");
        }
        eprintln!("SKIPPED: chromium is not installed (apt-get install -y chromium); set STS_TWIN_REQUIRE_BROWSER to make this a failure");
        return;
    };
    let clean = small_measurement(Vec::new(), 1);
    let config = FitConfig { max_epochs: 6, folds: 3, ..FitConfig::default() };
    let model = fit(&clean, "report test", &config, &mut |_| {}).expect("fit");
    let drifting = small_measurement(vec!["thermal-drift:rise_k=1.5,tau_s=60,um_per_k=1".parse().unwrap()], 2);
    let (c, waves) = compare(&drifting, &model).unwrap();
    let (b, bwaves) = compare(&clean, &model).unwrap();
    let d = diagnose(&drifting, &model).unwrap();
    let html = render(&ReportInput {
        dataset: "drifting".into(),
        model: (&c, &waves),
        model_label: "model.json".into(),
        baseline: Some((&b, &bwaves, "on clean data".into())),
        diagnosis: Some(&d),
        chosen_groups: vec![0],
    });
    assert!(
        !html.contains("http://")
            || html.matches("http://").count() == html.matches("http://www.w3.org/2000/svg").count(),
        "the report must not reach the network"
    );

    let dir = std::env::temp_dir().join(format!("sts-twin-report-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let page = dir.join("report.html");
    std::fs::write(&page, &html).unwrap();
    let url = format!("file://{}", page.display());

    // DOM: what the browser parsed.
    let out = run_chromium(&browser, &dir.join("profile-dom"), &["--dump-dom".to_string(), url.clone()]);
    assert!(out.status.success(), "chromium --dump-dom failed: {}", String::from_utf8_lossy(&out.stderr));
    let dom = String::from_utf8_lossy(&out.stdout);
    let svgs = dom.matches("<svg").count();
    assert!(svgs >= 8, "only {svgs} charts in the DOM");
    for id in [
        "id=\"summary\"",
        "id=\"verdict\"",
        "id=\"ranking\"",
        "id=\"map-model\"",
        "id=\"harmonics\"",
        "id=\"time\"",
        "id=\"groups\"",
    ] {
        assert!(dom.contains(id), "DOM lacks {id}");
    }
    assert_eq!(dom.matches("class=\"cell\"").count(), 2 * 9, "heat maps have one cell per group");
    assert!(dom.contains("thermal-drift"), "the diagnosis names the drift");

    // Screenshot: a picture with content.
    let shot = dir.join("report.png");
    let out = run_chromium(
        &browser,
        &dir.join("profile-shot"),
        &[format!("--screenshot={}", shot.display()), "--window-size=1360,2400".to_string(), url],
    );
    assert!(out.status.success(), "chromium --screenshot failed: {}", String::from_utf8_lossy(&out.stderr));
    let png = std::fs::read(&shot).expect("screenshot written");
    assert_eq!(png_size(&png), Some((1360, 2400)));
    // A blank page of that size compresses to a few kB; charts and tables do not.
    assert!(png.len() > 60_000, "screenshot is only {} bytes: blank page?", png.len());
    let _ = std::fs::remove_dir_all(&dir);
}
