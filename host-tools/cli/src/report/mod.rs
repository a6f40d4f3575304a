//! The self-contained HTML report of `compare --html`: inline SVG charts, no scripts, no
//! network. Model against measurement waveforms for the worst and chosen groups, the error map
//! as a heat map, residual spectra, residual against the motion and machine time, and the
//! diagnosis.
//!
//! The pages are askama templates (`templates/`, on a base that holds the style) filled from
//! views of formatted strings: the layout reads as HTML and is checked when the crate compiles,
//! askama escapes all text; the SVG charts of [`svg`] go in as built.

pub mod explain;
pub mod svg;
pub mod trial;

use sts_assess::compare::{Comparison, GroupWaves};
use sts_assess::diagnose::Diagnosis;
use svg::{bar_chart, heat_map, line_chart, tick_label, GridAxis, Series};

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

/// The report as one HTML document.
pub fn render(input: &ReportInput) -> String {
    let (c, _) = input.model;
    let page = ComparePage {
        dataset: &input.dataset,
        model_label: &input.model_label,
        model: &c.model,
        summary: summary_rows(input),
        fall: fall(input),
        acc_blind: c.describe_acc_blind(),
        diagnosis: input.diagnosis.map(diagnosis_view),
        charts: charts(input),
        with_baseline: input.baseline.is_some(),
        groups: group_rows(input),
    };
    // A template is `Display`, failing only where a field's `Display` fails: the views hold
    // strings and numbers, which never do.
    page.to_string()
}

/// The page of `compare --html` (templates/compare.html): every number formatted as shown.
#[derive(askama::Template)]
#[template(path = "compare.html")]
struct ComparePage<'a> {
    dataset: &'a str,
    model_label: &'a str,
    /// The model's own description.
    model: &'a str,
    summary: Vec<SummaryRow<'a>>,
    fall: Option<Fall<'a>>,
    acc_blind: Option<String>,
    diagnosis: Option<DiagnosisView<'a>>,
    charts: Charts,
    with_baseline: bool,
    groups: Vec<GroupRow<'a>>,
}

/// One model's line in the summary table.
struct SummaryRow<'a> {
    label: &'a str,
    rms_nm: String,
    mae_nm: String,
    amplitude_r2: String,
    phase_r2: String,
    measured_nm: String,
}

/// How the model's waveform error compares with the baseline's.
struct Fall<'a> {
    falls: bool,
    percent: String,
    baseline: &'a str,
}

/// The diagnosis section.
struct DiagnosisView<'a> {
    verdict: &'a str,
    summary: &'a str,
    not_repeating: Option<&'a str>,
    unexplained: Option<&'a str>,
    ranking: Vec<RankRow<'a>>,
    test: &'a str,
}

/// One candidate effect of the diagnosis, in rank order.
struct RankRow<'a> {
    effect: &'a str,
    explained_pct: String,
    p_value: String,
    params: String,
    evidence: &'a str,
}

/// The SVG charts of each section, in order.
struct Charts {
    error_maps: Vec<String>,
    waveforms: Vec<String>,
    spectra: Vec<String>,
    residuals: Vec<String>,
}

/// One group's line in the groups table; the baseline's RMS when there is a baseline.
struct GroupRow<'a> {
    file: &'a str,
    freq_hz: String,
    amp_um: String,
    measured_amp_um: String,
    predicted_amp_um: String,
    measured_phase_deg: String,
    predicted_phase_deg: String,
    rms_nm: String,
    baseline_rms_nm: Option<String>,
}

fn summary_row<'a>(label: &'a str, c: &Comparison) -> SummaryRow<'a> {
    SummaryRow {
        label,
        rms_nm: format!("{:.1}", c.waveform_rms_um * 1e3),
        mae_nm: format!("{:.1}", c.waveform_mae_um * 1e3),
        amplitude_r2: format!("{:.4}", c.amplitude_r2),
        phase_r2: format!("{:.4}", c.phase_r2),
        measured_nm: format!("{:.1}", c.measured_rms_um * 1e3),
    }
}

fn summary_rows<'a>(input: &'a ReportInput) -> Vec<SummaryRow<'a>> {
    let mut rows = vec![summary_row(&input.model_label, input.model.0)];
    if let Some((b, _, label)) = &input.baseline {
        rows.push(summary_row(label, b));
    }
    rows
}

fn fall<'a>(input: &'a ReportInput) -> Option<Fall<'a>> {
    let (b, _, label) = input.baseline.as_ref()?;
    let fall = 1.0 - input.model.0.waveform_rms_um / b.waveform_rms_um.max(1e-300);
    Some(Fall { falls: fall >= 0.0, percent: format!("{:.0}", fall.abs() * 100.0), baseline: label })
}

fn diagnosis_view(d: &Diagnosis) -> DiagnosisView<'_> {
    let ranking = d
        .ranking
        .iter()
        .map(|r| RankRow {
            effect: &r.effect,
            explained_pct: format!("{:.1}", r.explained_fraction * 100.0),
            p_value: if r.p_value.is_finite() { format!("{:.1e}", r.p_value) } else { "-".into() },
            params: r.params.iter().map(|(k, v)| format!("{k} = {}", tick_label(*v))).collect::<Vec<_>>().join(", "),
            evidence: &r.evidence,
        })
        .collect();
    DiagnosisView {
        verdict: &d.verdict,
        summary: &d.summary,
        not_repeating: d.not_repeating.as_deref(),
        unexplained: d.unexplained.as_deref(),
        ranking,
        test: &d.test,
    }
}

fn group_rows<'a>(input: &'a ReportInput) -> Vec<GroupRow<'a>> {
    let (c, _) = input.model;
    c.groups
        .iter()
        .enumerate()
        .map(|(i, g)| GroupRow {
            file: &g.file,
            freq_hz: tick_label(g.freq_hz),
            amp_um: tick_label(g.amp_um),
            measured_amp_um: format!("{:.4}", g.measured_amp_um),
            predicted_amp_um: format!("{:.4}", g.predicted_amp_um),
            measured_phase_deg: format!("{:.2}", g.measured_phase_deg),
            predicted_phase_deg: format!("{:.2}", g.predicted_phase_deg),
            rms_nm: format!("{:.1}", g.waveform_rms_um * 1e3),
            baseline_rms_nm: input
                .baseline
                .as_ref()
                .map(|(b, _, _)| format!("{:.1}", b.groups.get(i).map_or(f64::NAN, |g| g.waveform_rms_um * 1e3))),
        })
        .collect()
}

fn charts(input: &ReportInput) -> Charts {
    Charts {
        error_maps: error_maps(input),
        waveforms: waveform_charts(input),
        spectra: spectrum_charts(input),
        residuals: residual_charts(input.model.0),
    }
}

/// The groups on the grid of command frequencies (columns) and amplitudes (rows), with
/// `value(i)` of group `i` in its cell.
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

/// The waveform RMS error over the grid: the model's, and the baseline's beside it.
fn error_maps(input: &ReportInput) -> Vec<String> {
    let map = |id: &str, c: &Comparison, label: &str| {
        let (fs, amps, cells) = grid_of(c, |i| c.groups[i].waveform_rms_um * 1e3);
        heat_map(
            id,
            &format!("waveform RMS error, {label}"),
            GridAxis { label: "command frequency (Hz)", values: &fs },
            GridAxis { label: "command amplitude (um)", values: &amps },
            &cells,
            "nm",
        )
    };
    let mut maps = vec![map("map-model", input.model.0, &input.model_label)];
    if let Some((b, _, label)) = &input.baseline {
        maps.push(map("map-baseline", b, label));
    }
    maps
}

/// Measured against predicted over four command periods of the worst three groups and the
/// chosen ones.
fn waveform_charts(input: &ReportInput) -> Vec<String> {
    let (c, waves) = input.model;
    let mut shown: Vec<usize> = c.worst(3);
    for g in &input.chosen_groups {
        if *g < c.groups.len() && !shown.contains(g) {
            shown.push(*g);
        }
    }
    shown
        .into_iter()
        .map(|gi| {
            let g = &c.groups[gi];
            let w = &waves[gi];
            // Four command periods (or the whole window at low frequency).
            let n = w.t_s.len();
            let keep = ((4.0 / g.freq_hz.max(1e-9)) / (w.t_s.get(1).map_or(1.0, |t1| t1 - w.t_s[0]))).ceil() as usize;
            let keep = keep.clamp(2, n.max(2)).min(n);
            let mut series = vec![
                Series { name: "measured".into(), x: &w.t_s[..keep], y: &w.measured_um[..keep], markers: false },
                Series {
                    name: input.model_label.clone(),
                    x: &w.t_s[..keep],
                    y: &w.predicted_um[..keep],
                    markers: false,
                },
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
            line_chart(&format!("wave-{gi}"), &title, "time in group (s)", "dynamic error (um)", &series)
        })
        .collect()
}

/// The residual at the harmonics of the command frequency, and at other lines when there are.
fn spectrum_charts(input: &ReportInput) -> Vec<String> {
    let c = input.model.0;
    let labels: Vec<String> = (1..=c.harmonics_um.len()).map(|k| format!("{k}f")).collect();
    let mut series = vec![(input.model_label.clone(), c.harmonics_um.iter().map(|v| v * 1e3).collect::<Vec<f64>>())];
    if let Some((b, _, label)) = &input.baseline {
        series.push((label.clone(), b.harmonics_um.iter().map(|v| v * 1e3).collect()));
    }
    let mut charts = vec![bar_chart(
        "harmonics",
        "residual at harmonics of the command frequency (mean over groups)",
        "harmonic order",
        "amplitude (nm)",
        &labels,
        &series,
    )];
    if !c.other_lines.is_empty() {
        let labels: Vec<String> = c.other_lines.iter().map(|l| format!("{} Hz", tick_label(l.freq_hz))).collect();
        let values: Vec<f64> = c.other_lines.iter().map(|l| l.amp_um * 1e3).collect();
        charts.push(bar_chart(
            "other-lines",
            "residual lines that are not harmonics",
            "frequency",
            "amplitude (nm)",
            &labels,
            &[(input.model_label.clone(), values)],
        ));
    }
    charts
}

/// Each group's residual against machine time, and the residual binned by each motion signal.
fn residual_charts(c: &Comparison) -> Vec<String> {
    let start: Vec<f64> = c.groups.iter().map(|g| g.start_s).collect();
    let mean: Vec<f64> = c.groups.iter().map(|g| g.residual_mean_um * 1e3).collect();
    let rms: Vec<f64> = c.groups.iter().map(|g| g.waveform_rms_um * 1e3).collect();
    let mut charts = vec![line_chart(
        "time",
        "residual per group against machine time",
        "machine time at group start (s)",
        "nm",
        &[
            Series { name: "mean".into(), x: &start, y: &mean, markers: true },
            Series { name: "RMS".into(), x: &start, y: &rms, markers: true },
        ],
    )];
    for (i, b) in c.binned.iter().enumerate() {
        let rms: Vec<f64> = b.rms_um.iter().map(|v| v * 1e3).collect();
        let mean: Vec<f64> = b.mean_um.iter().map(|v| v * 1e3).collect();
        charts.push(line_chart(
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
    charts
}
