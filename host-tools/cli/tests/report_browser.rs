//! The HTML reports render in a real browser: headless Chromium loads each page (`compare`,
//! `explain` and `machine --html`), its DOM has the charts and tables, and the compare page's
//! screenshot is a picture, not a blank page.
//!
//! Skips (with a message) only when `chromium` is not installed and `STS_TWIN_REQUIRE_BROWSER`
//! is not set; CI sets it and installs Debian's `chromium` package.

use std::path::{Path, PathBuf};
use std::process::Command;

use sts_assess::compare::compare;
use sts_assess::diagnose::diagnose;
use sts_assess::explain::{explain, Base, ExplainConfig};
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
    measurement(&[5.0, 20.0, 40.0], effects, seed)
}

/// Groups at `freqs_hz` x 2, 6 and 10 um, 5.5 s each.
fn measurement(freqs_hz: &[f64], effects: Vec<EffectSpec>, seed: u64) -> sts_dataset::Dataset {
    let config = MeasureConfig {
        freqs_hz: freqs_hz.to_vec(),
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

/// The browser, or `None` (with a message) where none is installed and none is required.
fn browser_or_skip() -> Option<PathBuf> {
    let browser = chromium();
    if browser.is_none() {
        if std::env::var_os("STS_TWIN_REQUIRE_BROWSER").is_some() {
            panic!("STS_TWIN_REQUIRE_BROWSER is set but chromium is not installed (apt-get install -y chromium)");
        }
        eprintln!("SKIPPED: chromium is not installed (apt-get install -y chromium); set STS_TWIN_REQUIRE_BROWSER to make this a failure");
    }
    browser
}

/// The DOM of `page` as the browser parsed it.
fn dump_dom(browser: &Path, profile: &Path, page: &Path) -> String {
    let url = format!("file://{}", page.display());
    let out = run_chromium(browser, profile, &["--dump-dom".to_string(), url]);
    assert!(out.status.success(), "chromium --dump-dom failed: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn the_report_renders_in_headless_chromium() {
    let Some(browser) = browser_or_skip() else { return };
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
    let dom = dump_dom(&browser, &dir.join("profile-dom"), &page);
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

/// `explain --html` and `machine --html`: the ladder's page with its chart, rungs and stop;
/// the trial's page with its table and the cut's surface and error maps.
#[test]
fn the_explain_and_machine_pages_render_in_headless_chromium() {
    let Some(browser) = browser_or_skip() else { return };
    let dir = std::env::temp_dir().join(format!("sts-twin-pages-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();

    // Twelve groups: on fewer no candidate can be significant and the ladder names nothing.
    let freqs_hz = [5.0, 20.0, 40.0, 60.0];
    let clean = measurement(&freqs_hz, Vec::new(), 1);
    let fit_config = FitConfig { max_epochs: 6, folds: 3, ..FitConfig::default() };
    let model = fit(&clean, "report test", &fit_config, &mut |_| {}).expect("fit");
    let drift = "thermal-drift:rise_k=1.5,tau_s=60,um_per_k=1".parse().unwrap();
    let drifting = measurement(&freqs_hz, vec![drift], 2);
    let config = ExplainConfig { fit: fit_config, max_effects: 3 };
    let base = Base { model, effects: Vec::new() };
    let e = explain(&drifting, "report test", Some(base), &config, &mut |_| {}).expect("explain");
    assert!(e.steps.iter().any(|s| s.effect == "thermal-drift"), "the ladder names the drift: {}", e.stop.describe());
    let page = dir.join("explain.html");
    std::fs::write(&page, sts_twin::report::explain::render("drifting", &e)).unwrap();
    let dom = dump_dom(&browser, &dir.join("profile-explain"), &page);
    for id in ["id=\"title\"", "id=\"steps\"", "id=\"stop\""] {
        assert!(dom.contains(id), "the explain page's DOM lacks {id}");
    }
    assert!(dom.contains("<svg"), "the explain page has no chart");
    assert!(dom.contains("thermal-drift"), "the explain page names the drift");

    let twin = concat!(env!("CARGO_MANIFEST_DIR"), "/../../hil-tests/fixtures/twin-default-machine.json");
    let page = dir.join("machine.html");
    let out = Command::new(env!("CARGO_BIN_EXE_sts-twin"))
        .args(["machine", "--sim", "--freq", "40", "--twin", twin, "--html"])
        .arg(&page)
        .output()
        .expect("run sts-twin");
    assert!(out.status.success(), "machine failed: {}", String::from_utf8_lossy(&out.stderr));
    let dom = dump_dom(&browser, &dir.join("profile-machine"), &page);
    assert!(dom.contains("id=\"trials\""), "the machine page's DOM lacks its table");
    assert!(dom.contains("with the twin"), "the machine page lacks its cut");
    let svgs = dom.matches("<svg").count();
    assert_eq!(svgs, 2, "the machine page's cut has a surface map and an error map");
    let _ = std::fs::remove_dir_all(&dir);
}
