//! The self-contained HTML report of `compare --html`: inline SVG charts, no scripts, no
//! network. Model against measurement waveforms for the worst and chosen groups, the error map
//! as a heat map, residual spectra, residual against the motion and machine time, and the
//! diagnosis.

pub mod explain;
pub mod svg;
pub mod trial;

use std::fmt::Write as _;

use sts_assess::compare::{Comparison, GroupWaves};
use sts_assess::diagnose::Diagnosis;
use svg::{bar_chart, esc, heat_map, line_chart, tick_label, GridAxis, Series};

/// What goes into a report.
pub struct ReportInput<'a> {
    /// The dataset's name (directory) and description.
    pub dataset: String,
    /// The model's comparison and waveforms.
    pub model: (&'a Comparison, &'a [GroupWaves]),
    /// The model's label (file name).
    pub model_label: String,
    /// A baseline model, side by side.
    pub baseline: Option<(&'a Comparison, &'a [GroupWaves], String)>,
    /// The diagnosis of the model's residual.
    pub diagnosis: Option<&'a Diagnosis>,
    /// Groups whose waveforms are shown besides the worst ones.
    pub chosen_groups: Vec<usize>,
}

fn grid_of(c: &Comparison, value: impl Fn(usize) -> f64) -> (Vec<f64>, Vec<f64>, Vec<Vec<Option<f64>>>) {
    let mut fs: Vec<f64> = c.groups.iter().map(|g| g.freq_hz).collect();
    let mut amps: Vec<f64> = c.groups.iter().map(|g| g.amp_um).collect();
    fs.sort_by(f64::total_cmp);
    fs.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    amps.sort_by(f64::total_cmp);
    amps.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    let mut cells = vec![vec![None; fs.len()]; amps.len()];
    for (i, g) in c.groups.iter().enumerate() {
        let col = fs.iter().position(|f| (f - g.freq_hz).abs() < 1e-9).unwrap_or(0);
        let row = amps.iter().position(|a| (a - g.amp_um).abs() < 1e-9).unwrap_or(0);
        cells[row][col] = Some(value(i));
    }
    (fs, amps, cells)
}

pub(crate) const STYLE: &str = "body{font-family:sans-serif;max-width:1340px;margin:20px auto;color:#222}h1{font-size:22px}h2{font-size:18px;border-bottom:1px solid #ccc;margin-top:28px}table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ccc;padding:3px 7px;text-align:right}th{background:#f2f2f2}td.l,th.l{text-align:left}.charts{display:flex;flex-wrap:wrap;gap:10px}.verdict{font-size:18px;padding:8px 12px;background:#fff6d6;border:1px solid #e0c060;display:inline-block}.small{color:#666;font-size:12px}";

/// The report as one HTML document.
pub fn render(input: &ReportInput) -> String {
    let (c, waves) = input.model;
    let mut h = String::new();
    let _ = write!(
        h,
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>sts-twin compare: {}</title><style>{STYLE}</style></head><body>",
        esc(&input.dataset)
    );
    let _ = write!(
        h,
        "<h1 id=\"title\">Dynamic error: model against measurement</h1><p>Dataset <b>{}</b>; model <b>{}</b> ({}).</p>",
        esc(&input.dataset),
        esc(&input.model_label),
        esc(&c.model)
    );

    // Summary.
    h.push_str("<h2>Summary</h2><table id=\"summary\"><tr><th class=\"l\">model</th><th>waveform RMS (nm)</th><th>waveform MAE (nm)</th><th>amplitude R<sup>2</sup></th><th>phase R<sup>2</sup></th><th>measured RMS (nm)</th></tr>");
    let mut row = |label: &str, c: &Comparison| {
        let _ = write!(
            h,
            "<tr><td class=\"l\">{}</td><td class=\"rms\">{:.1}</td><td>{:.1}</td><td>{:.4}</td><td>{:.4}</td><td>{:.1}</td></tr>",
            esc(label),
            c.waveform_rms_um * 1e3,
            c.waveform_mae_um * 1e3,
            c.amplitude_r2,
            c.phase_r2,
            c.measured_rms_um * 1e3
        );
    };
    row(&input.model_label, c);
    if let Some((b, _, label)) = &input.baseline {
        row(label, b);
    }
    h.push_str("</table>");
    if let Some((b, _, label)) = &input.baseline {
        let fall = 1.0 - c.waveform_rms_um / b.waveform_rms_um.max(1e-300);
        let _ = write!(
            h,
            "<p id=\"fall\">Waveform RMS error {} by {:.0}% against {}.</p>",
            if fall >= 0.0 { "falls" } else { "rises" },
            fall.abs() * 100.0,
            esc(label)
        );
    }
    if let Some(text) = c.describe_acc_blind() {
        let _ = write!(h, "<p id=\"acc-blind\"><b>Accelerometer:</b> {}</p>", esc(&text));
    }

    // Diagnosis.
    if let Some(d) = input.diagnosis {
        h.push_str("<h2>Diagnosis</h2>");
        let _ = write!(
            h,
            "<p class=\"verdict\" id=\"verdict\">Missing effect: <b>{}</b></p><p>{}</p>",
            esc(&d.verdict),
            esc(&d.summary)
        );
        if let Some(text) = &d.not_repeating {
            let _ = write!(h, "<p id=\"not-repeating\"><b>Not repeating:</b> {}</p>", esc(text));
        }
        if let Some(text) = &d.unexplained {
            let _ = write!(h, "<p id=\"unexplained\"><b>Unexplained:</b> {}</p>", esc(text));
        }
        h.push_str("<table id=\"ranking\"><tr><th>rank</th><th class=\"l\">effect</th><th>explained (held out)</th><th>p-value</th><th class=\"l\">parameters</th><th class=\"l\">evidence</th></tr>");
        for (i, r) in d.ranking.iter().enumerate() {
            let params: Vec<String> = r.params.iter().map(|(k, v)| format!("{k} = {}", tick_label(*v))).collect();
            let _ = write!(
                h,
                "<tr><td>{}</td><td class=\"l\">{}</td><td>{:.1}%</td><td>{}</td><td class=\"l\">{}</td><td class=\"l\">{}</td></tr>",
                i + 1,
                esc(&r.effect),
                r.explained_fraction * 100.0,
                if r.p_value.is_finite() { format!("{:.1e}", r.p_value) } else { "-".into() },
                esc(&params.join(", ")),
                esc(&r.evidence)
            );
        }
        h.push_str("</table>");
        let _ = write!(h, "<p class=\"small\">{}</p>", esc(&d.test));
    }

    // Error map.
    h.push_str("<h2>Error map</h2><div class=\"charts\">");
    let (fs, amps, cells) = grid_of(c, |i| c.groups[i].waveform_rms_um * 1e3);
    h.push_str(&heat_map(
        "map-model",
        &format!("waveform RMS error, {}", input.model_label),
        GridAxis { label: "command frequency (Hz)", values: &fs },
        GridAxis { label: "command amplitude (um)", values: &amps },
        &cells,
        "nm",
    ));
    if let Some((b, _, label)) = &input.baseline {
        let (fs, amps, cells) = grid_of(b, |i| b.groups[i].waveform_rms_um * 1e3);
        h.push_str(&heat_map(
            "map-baseline",
            &format!("waveform RMS error, {label}"),
            GridAxis { label: "command frequency (Hz)", values: &fs },
            GridAxis { label: "command amplitude (um)", values: &amps },
            &cells,
            "nm",
        ));
    }
    h.push_str("</div>");

    // Waveforms.
    h.push_str("<h2>Waveforms: measured against predicted (last second)</h2><div class=\"charts\">");
    let mut shown: Vec<usize> = c.worst(3);
    for g in &input.chosen_groups {
        if *g < c.groups.len() && !shown.contains(g) {
            shown.push(*g);
        }
    }
    for &gi in &shown {
        let g = &c.groups[gi];
        let w = &waves[gi];
        // Four command periods (or the whole window at low frequency).
        let n = w.t_s.len();
        let keep = ((4.0 / g.freq_hz.max(1e-9)) / (w.t_s.get(1).map_or(1.0, |t1| t1 - w.t_s[0]))).ceil() as usize;
        let keep = keep.clamp(2, n.max(2)).min(n);
        let mut series = vec![
            Series { name: "measured".into(), x: &w.t_s[..keep], y: &w.measured_um[..keep], markers: false },
            Series { name: input.model_label.clone(), x: &w.t_s[..keep], y: &w.predicted_um[..keep], markers: false },
        ];
        if let Some((_, bw, label)) = &input.baseline {
            series.push(Series {
                name: label.clone(),
                x: &bw[gi].t_s[..keep],
                y: &bw[gi].predicted_um[..keep],
                markers: false,
            });
        }
        let title = format!(
            "{} ({} Hz, {} um): RMS {:.1} nm",
            g.file,
            tick_label(g.freq_hz),
            tick_label(g.amp_um),
            g.waveform_rms_um * 1e3
        );
        h.push_str(&line_chart(&format!("wave-{gi}"), &title, "time in group (s)", "dynamic error (um)", &series));
    }
    h.push_str("</div>");

    // Spectra.
    h.push_str("<h2>Residual spectrum</h2><div class=\"charts\">");
    let labels: Vec<String> = (1..=c.harmonics_um.len()).map(|k| format!("{k}f")).collect();
    let mut series = vec![(input.model_label.clone(), c.harmonics_um.iter().map(|v| v * 1e3).collect::<Vec<f64>>())];
    if let Some((b, _, label)) = &input.baseline {
        series.push((label.clone(), b.harmonics_um.iter().map(|v| v * 1e3).collect()));
    }
    h.push_str(&bar_chart(
        "harmonics",
        "residual at harmonics of the command frequency (mean over groups)",
        "harmonic order",
        "amplitude (nm)",
        &labels,
        &series,
    ));
    if !c.other_lines.is_empty() {
        let labels: Vec<String> = c.other_lines.iter().map(|l| format!("{} Hz", tick_label(l.freq_hz))).collect();
        let values: Vec<f64> = c.other_lines.iter().map(|l| l.amp_um * 1e3).collect();
        h.push_str(&bar_chart(
            "other-lines",
            "residual lines that are not harmonics",
            "frequency",
            "amplitude (nm)",
            &labels,
            &[(input.model_label.clone(), values)],
        ));
    }
    h.push_str("</div>");

    // Residual against time and motion.
    h.push_str("<h2>Residual against machine time and motion</h2><div class=\"charts\">");
    let start: Vec<f64> = c.groups.iter().map(|g| g.start_s).collect();
    let mean: Vec<f64> = c.groups.iter().map(|g| g.residual_mean_um * 1e3).collect();
    let rms: Vec<f64> = c.groups.iter().map(|g| g.waveform_rms_um * 1e3).collect();
    h.push_str(&line_chart(
        "time",
        "residual per group against machine time",
        "machine time at group start (s)",
        "nm",
        &[
            Series { name: "mean".into(), x: &start, y: &mean, markers: true },
            Series { name: "RMS".into(), x: &start, y: &rms, markers: true },
        ],
    ));
    for (i, b) in c.binned.iter().enumerate() {
        let rms: Vec<f64> = b.rms_um.iter().map(|v| v * 1e3).collect();
        let mean: Vec<f64> = b.mean_um.iter().map(|v| v * 1e3).collect();
        h.push_str(&line_chart(
            &format!("binned-{i}"),
            &format!("residual against {}", b.signal),
            &b.signal,
            "nm",
            &[
                Series { name: "RMS".into(), x: &b.centres, y: &rms, markers: false },
                Series { name: "mean".into(), x: &b.centres, y: &mean, markers: false },
            ],
        ));
    }
    h.push_str("</div>");

    // Worst groups and all groups.
    h.push_str("<h2>Groups</h2><table id=\"groups\"><tr><th class=\"l\">file</th><th>f (Hz)</th><th>A (um)</th><th>measured amp (um)</th><th>predicted amp (um)</th><th>measured phase (deg)</th><th>predicted phase (deg)</th><th>RMS (nm)</th>");
    if input.baseline.is_some() {
        h.push_str("<th>baseline RMS (nm)</th>");
    }
    h.push_str("</tr>");
    for (i, g) in c.groups.iter().enumerate() {
        let _ = write!(
            h,
            "<tr><td class=\"l\">{}</td><td>{}</td><td>{}</td><td>{:.4}</td><td>{:.4}</td><td>{:.2}</td><td>{:.2}</td><td>{:.1}</td>",
            esc(&g.file),
            tick_label(g.freq_hz),
            tick_label(g.amp_um),
            g.measured_amp_um,
            g.predicted_amp_um,
            g.measured_phase_deg,
            g.predicted_phase_deg,
            g.waveform_rms_um * 1e3
        );
        if let Some((b, _, _)) = &input.baseline {
            let _ = write!(h, "<td>{:.1}</td>", b.groups.get(i).map_or(f64::NAN, |g| g.waveform_rms_um * 1e3));
        }
        h.push_str("</tr>");
    }
    h.push_str("</table><p class=\"small\">Generated by sts-twin compare. Predictions are the model's firmware program and per-tick terms as the board computes them; scores over each group's last second.</p></body></html>\n");
    h
}
