//! The HTML report of `explain --html`: the error falling rung by rung, with each rung's
//! evidence and identified parameters, and the last diagnosis with its test.

use sts_assess::explain::Explanation;

use super::svg::bar_chart;

/// The page of `explain --html` (templates/explain.html): every number formatted as shown.
#[derive(askama::Template)]
#[template(path = "explain.html")]
struct ExplainPage<'a> {
    /// The dataset's name.
    name: &'a str,
    ladder_chart: String,
    steps: Vec<Step<'a>>,
    /// Why the loop stopped.
    stop: String,
    summary: &'a str,
    /// The last diagnosis's notes: what does not repeat, what no candidate explains.
    notes: Vec<&'a str>,
    final_nm: String,
    floor_nm: String,
    test: &'a str,
}

/// One rung of the ladder: the effect added, and the error before and after it.
struct Step<'a> {
    effect: &'a str,
    explained_pct: String,
    p_value: String,
    before_nm: String,
    after_nm: String,
    /// The identified parameters, `name = value` each.
    params: Vec<String>,
    evidence: &'a str,
}

/// The page for the ladder of dataset `name`.
pub fn render(name: &str, e: &Explanation) -> String {
    let floor_nm = e.last.repeatability.floor_um * 1e3;
    let steps = e
        .steps
        .iter()
        .map(|s| Step {
            effect: &s.effect,
            explained_pct: format!("{:.0}", s.explained_fraction * 100.0),
            p_value: format!("{:.1e}", s.p_value),
            before_nm: format!("{:.1}", s.waveform_rms_um_before * 1e3),
            after_nm: format!("{:.1}", s.waveform_rms_um_after * 1e3),
            params: s.params.iter().map(|(k, v)| format!("{k} = {v:.4}")).collect(),
            evidence: &s.evidence,
        })
        .collect();
    let page = ExplainPage {
        name,
        ladder_chart: ladder_chart(e, floor_nm),
        steps,
        stop: e.stop.describe(),
        summary: &e.last.summary,
        notes: [&e.last.not_repeating, &e.last.unexplained].into_iter().flatten().map(String::as_str).collect(),
        final_nm: format!("{:.1}", e.waveform_rms_um * 1e3),
        floor_nm: format!("{floor_nm:.1}"),
        test: &e.last.test,
    };
    // A template is `Display`, failing only where a field's `Display` fails: the view holds
    // strings, which never do.
    page.to_string()
}

/// The waveform error at the start and after each rung, against the data's floor.
fn ladder_chart(e: &Explanation, floor_nm: f64) -> String {
    let mut labels = vec!["start".to_string()];
    let mut rms_nm = vec![e.start_waveform_rms_um * 1e3];
    for s in &e.steps {
        labels.push(format!("+ {}", s.effect));
        rms_nm.push(s.waveform_rms_um_after * 1e3);
    }
    bar_chart(
        "ladder",
        "the twin's waveform error, rung by rung",
        "effect added",
        "waveform RMS (nm)",
        &labels,
        &[("waveform RMS".to_string(), rms_nm), ("the data's floor".to_string(), vec![floor_nm; labels.len()])],
    )
}
