//! The model file `sts-twin-model/1`: a written model reads back to the same program, and
//! every kind of bad file is rejected with the file, the line and column or the field.

use std::path::PathBuf;
use std::sync::OnceLock;

use sts_emulator::measure::{run, MeasureConfig};
use sts_fit::{fit, FitConfig};
use sts_model::{ModelFile, ModelFileError, MODEL_FORMAT};

/// A quick model: 12 groups, a short search.
fn model() -> &'static ModelFile {
    static MODEL: OnceLock<ModelFile> = OnceLock::new();
    MODEL.get_or_init(|| {
        let config = MeasureConfig {
            freqs_hz: vec![10.0, 20.0, 30.0, 40.0],
            amps_um: vec![2.0, 6.0, 10.0],
            ..MeasureConfig::default()
        };
        let data = run(&config, &|_| {}).unwrap();
        let fit_config = FitConfig { seed: 3, max_epochs: 8, folds: 2, ..FitConfig::default() };
        fit(&data, "12 groups", &fit_config, &mut |_| {}).unwrap()
    })
}

fn text() -> String {
    serde_json::to_string_pretty(model()).unwrap()
}

fn path(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sts-twin-model-file-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d.join(name)
}

/// Writes `text` to a file and reads it as a model; returns the error message.
fn read_error(name: &str, text: &str) -> String {
    let p = path(name);
    std::fs::write(&p, text).unwrap();
    let e = ModelFile::read(&p).expect_err("a bad model file must be rejected");
    let message = format!("{e:#}");
    assert!(message.contains(&p.display().to_string()), "the error names the file: {message}");
    message
}

#[test]
fn a_written_model_reads_back_with_the_same_program() {
    let p = path("ok.json");
    model().write(&p).unwrap();
    let back = ModelFile::read(&p).unwrap();
    assert_eq!(back.firmware_program().unwrap(), model().firmware_program().unwrap());
    assert_eq!(back.amplitude.formula, model().amplitude.formula);
    assert_eq!(back.format, MODEL_FORMAT);
    // serde_json parses decimals to within an ulp (no float_roundtrip feature): the
    // formulas read back compute the same values to 1e-14.
    let row = [30.0, 0.2, 0.05, 0.35, 0.22, 1.5, 0.001, 1.5, 1.7, 1.1, 30.0, 0.04];
    for (a, b) in [(&back.amplitude.expr, &model().amplitude.expr), (&back.phase.expr, &model().phase.expr)] {
        let (x, y) = (a.eval_row(&row), b.eval_row(&row));
        assert!((x - y).abs() <= 1e-14 * (1.0 + y.abs()), "{x} vs {y}");
    }
}

#[test]
fn bad_json_is_reported_with_line_and_column() {
    // Cut the file in the middle of line 10.
    let good = text();
    let cut: String = good.lines().take(9).map(|l| format!("{l}\n")).collect::<String>() + "  \"oops\": [1, 2,";
    let message = read_error("cut.json", &cut);
    assert!(message.contains("cut.json:10:"), "{message}");

    let bad = good.replacen("\"complexity\": ", "\"complexity\": x", 1);
    let line = bad.lines().position(|l| l.contains("\"complexity\": x")).unwrap() + 1;
    let message = read_error("bad_value.json", &bad);
    assert!(message.contains(&format!("bad_value.json:{line}:")), "{message}");
}

#[test]
fn a_missing_field_is_named() {
    let mut value: serde_json::Value = serde_json::from_str(&text()).unwrap();
    value.as_object_mut().unwrap().remove("validation");
    let message = read_error("missing.json", &serde_json::to_string_pretty(&value).unwrap());
    assert!(message.contains("missing field `validation`"), "{message}");
}

#[test]
fn another_format_is_named() {
    let message = read_error("dataset.json", &text().replace(MODEL_FORMAT, "sts-twin-dataset/1"));
    assert!(message.contains("field `format`") && message.contains("sts-twin-dataset/1"), "{message}");
    let message = read_error("no_format.json", "{\"sample_rate_hz\": 8000}");
    assert!(message.contains("field `format`"), "{message}");
    // A JSON array is not a model file either.
    let e = ModelFile::from_json("[1, 2]").unwrap_err();
    assert!(matches!(e, ModelFileError::Field { field: "format", .. }), "{e}");
}

#[test]
fn a_corrupt_program_is_named() {
    let hex = &model().program_postcard_hex;
    for (name, replacement, expect) in [
        ("not_hex.json", "zz".to_string() + &hex[2..], "not hexadecimal"),
        ("odd.json", hex[1..].to_string(), "not hexadecimal"),
        ("truncated.json", hex[..(hex.len() / 2) & !1].to_string(), "program"),
        ("trailing.json", hex.clone() + "00", "after the program"),
        // A twin of an earlier release (its program's first byte is the format version).
        ("version1.json", "01".to_string() + &hex[2..], "format version 1, this release reads version 2"),
    ] {
        let message = read_error(name, &text().replace(hex.as_str(), &replacement));
        assert!(message.contains("field `program_postcard_hex` ") && message.contains(expect), "{name}: {message}");
        if name == "truncated.json" {
            assert!(
                message.contains("not a postcard-encoded program") || message.contains("invalid program"),
                "{message}"
            );
        }
    }
}

#[test]
fn a_missing_file_is_named() {
    let p = path("does-not-exist.json");
    let message = format!("{:#}", ModelFile::read(&p).unwrap_err());
    assert!(message.contains("does-not-exist.json"), "{message}");
}
