//! The HTML report of `explain --html`: the error falling rung by rung, with each rung's
//! evidence and identified parameters, and the last diagnosis with its test.

use std::fmt::Write as _;

use sts_assess::explain::Explanation;

use super::svg::{bar_chart, esc};

/// The page for the ladder of dataset `name`.
pub fn render(name: &str, e: &Explanation) -> String {
    let mut h = String::new();
    let _ = write!(
        h,
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>sts-twin explain: {t}</title><style>{style}</style></head><body><h1 id=\"title\">What the twin of {t} was missing</h1>",
        t = esc(name),
        style = super::STYLE
    );
    let mut labels = vec!["start".to_string()];
    let mut rms_nm = vec![e.start_waveform_rms_um * 1e3];
    for s in &e.steps {
        labels.push(format!("+ {}", s.effect));
        rms_nm.push(s.waveform_rms_um_after * 1e3);
    }
    let floor_nm = e.last.repeatability.floor_um * 1e3;
    h.push_str(&bar_chart(
        "ladder",
        "the twin's waveform error, rung by rung",
        "effect added",
        "waveform RMS (nm)",
        &labels,
        &[("waveform RMS".to_string(), rms_nm), ("the data's floor".to_string(), vec![floor_nm; labels.len()])],
    ));
    h.push_str("<h2>The ladder</h2><table id=\"steps\"><tr><th>rung</th><th class=\"l\">effect</th><th>explained</th><th>p</th><th>before (nm)</th><th>after (nm)</th><th class=\"l\">identified</th><th class=\"l\">evidence</th></tr>");
    for (i, s) in e.steps.iter().enumerate() {
        let params: Vec<String> = s.params.iter().map(|(k, v)| format!("{} = {:.4}", esc(k), v)).collect();
        let _ = write!(
            h,
            "<tr><td>{}</td><td class=\"l\">{}</td><td>{:.0}%</td><td>{:.1e}</td><td>{:.1}</td><td>{:.1}</td><td class=\"l\">{}</td><td class=\"l\">{}</td></tr>",
            i + 1,
            esc(&s.effect),
            s.explained_fraction * 100.0,
            s.p_value,
            s.waveform_rms_um_before * 1e3,
            s.waveform_rms_um_after * 1e3,
            params.join("<br>"),
            esc(&s.evidence)
        );
    }
    h.push_str("</table>");
    let _ = write!(
        h,
        "<h2>Where it stopped</h2><p class=\"verdict\" id=\"stop\">{}</p><p>{}</p>",
        esc(&e.stop.describe()),
        esc(&e.last.summary)
    );
    for note in [&e.last.not_repeating, &e.last.unexplained].into_iter().flatten() {
        let _ = write!(h, "<p>{}</p>", esc(note));
    }
    let _ = write!(
        h,
        "<p>Final twin: waveform RMS {:.1} nm against the data's floor of {:.1} nm (what does not repeat from one command period to the next).</p><p class=\"small\">{}</p></body></html>",
        e.waveform_rms_um * 1e3,
        floor_nm,
        esc(&e.last.test)
    );
    h
}
