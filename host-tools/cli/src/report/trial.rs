//! The machining trial's report: one self-contained HTML page (inline SVG, no scripts, no
//! network) with the figures and, for each cut, the surface map and the error map over the
//! disc.

use std::f64::consts::PI;
use std::fmt::Write as _;

use super::svg::{colour_scale, open_chart, tick_label};
use sts_rig::trial::{CutMaps, TrialReport};

const SIZE: f64 = 360.0;
const PAD: f64 = 40.0;

/// Blue (negative) -> white (0) -> red (positive) for -1..1.
fn diverging(f: f64) -> String {
    let f = f.clamp(-1.0, 1.0);
    let (r, g, b) = if f < 0.0 {
        let t = -f;
        (255.0 - 225.0 * t, 255.0 - 160.0 * t, 255.0 - 55.0 * t)
    } else {
        (255.0 - 55.0 * f, 255.0 - 225.0 * f, 255.0 - 225.0 * f)
    };
    format!("#{:02x}{:02x}{:02x}", r as u8, g as u8, b as u8)
}

/// A polar map of `values[radial][angular]` over the disc of radius `r_max_mm`, coloured by
/// `colour(value)`, with a legend from `lo` to `hi`.
fn polar_map(
    id: &str,
    title: &str,
    r_max_mm: f64,
    values: &[Vec<Option<f64>>],
    lo: f64,
    hi: f64,
    colour: impl Fn(f64) -> String,
) -> String {
    let (w, h) = (SIZE + 2.0 * PAD + 90.0, SIZE + 2.0 * PAD + 10.0);
    let (cx, cy, radius) = (PAD + SIZE / 2.0, PAD + 10.0 + SIZE / 2.0, SIZE / 2.0);
    let mut out = String::new();
    open_chart(&mut out, "chart polar", id, title, w, h);
    let rings = values.len().max(1);
    for (ri, row) in values.iter().enumerate() {
        let (r0, r1) = (radius * ri as f64 / rings as f64, radius * (ri + 1) as f64 / rings as f64);
        let sectors = row.len().max(1);
        for (ai, value) in row.iter().enumerate() {
            let Some(v) = value else { continue };
            // Spindle angle counter-clockwise from the +x axis (SVG's y points down).
            let (a0, a1) = (2.0 * PI * ai as f64 / sectors as f64, 2.0 * PI * (ai + 1) as f64 / sectors as f64);
            let p = |r: f64, a: f64| (cx + r * a.cos(), cy - r * a.sin());
            let ((x0, y0), (x1, y1), (x2, y2), (x3, y3)) = (p(r1, a0), p(r1, a1), p(r0, a1), p(r0, a0));
            let _ = write!(
                out,
                r##"<path class="cell" d="M{x0:.1},{y0:.1}A{r1:.1},{r1:.1} 0 0 0 {x1:.1},{y1:.1}L{x2:.1},{y2:.1}A{r0:.1},{r0:.1} 0 0 1 {x3:.1},{y3:.1}Z" fill="{fill}"><title>r {rr:.3} mm, C {cc:.0} deg: {val} um</title></path>"##,
                fill = colour(*v),
                rr = r_max_mm * (ri as f64 + 0.5) / rings as f64,
                cc = 360.0 * (ai as f64 + 0.5) / sectors as f64,
                val = tick_label(*v)
            );
        }
    }
    let _ = write!(
        out,
        r##"<circle cx="{cx}" cy="{cy}" r="{radius}" fill="none" stroke="#888"/><text x="{cx}" y="{ty:.1}" text-anchor="middle" font-size="11">r = {r} mm</text>"##,
        ty = cy + radius + 16.0,
        r = tick_label(r_max_mm)
    );
    let bx = PAD + SIZE + 25.0;
    for i in 0..20 {
        let v = lo + (hi - lo) * i as f64 / 19.0;
        let _ = write!(
            out,
            r##"<rect x="{bx:.1}" y="{:.1}" width="14" height="{:.1}" fill="{}"/>"##,
            cy + radius - (i + 1) as f64 * SIZE / 20.0,
            SIZE / 20.0 + 0.5,
            colour(v)
        );
    }
    let _ = write!(
        out,
        r##"<text x="{tx:.1}" y="{t0:.1}" font-size="11">{hi} um</text><text x="{tx:.1}" y="{t1:.1}" font-size="11">{lo} um</text></svg>"##,
        tx = bx + 18.0,
        t0 = cy - radius + 10.0,
        t1 = cy + radius,
        hi = tick_label(hi),
        lo = tick_label(lo)
    );
    out
}

fn range(values: &[Vec<Option<f64>>]) -> (f64, f64) {
    values.iter().flatten().flatten().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(*v), hi.max(*v)))
}

/// The surface map (TCP height) and the error map (deviation from the design) of one cut.
pub fn cut_maps(id: &str, maps: &CutMaps) -> [String; 2] {
    let (lo, hi) = range(&maps.surface_um);
    let span = (hi - lo).max(1e-9);
    let surface =
        polar_map(&format!("{id}-surface"), "surface: TCP height (um)", maps.r_max_mm, &maps.surface_um, lo, hi, |v| {
            colour_scale((v - lo) / span)
        });
    let (dlo, dhi) = range(&maps.deviation_um);
    let extent = dlo.abs().max(dhi.abs()).max(1e-9);
    let error = polar_map(
        &format!("{id}-error"),
        "error: TCP minus design (um)",
        maps.r_max_mm,
        &maps.deviation_um,
        -extent,
        extent,
        |v| diverging(v / extent),
    );
    [surface, error]
}

/// The page of `machine --html` (templates/trial.html): every number formatted as shown.
#[derive(askama::Template)]
#[template(path = "trial.html")]
struct TrialPage<'a> {
    title: &'a str,
    cuts: Vec<Cut<'a>>,
}

/// One cut: its line in the table and its two maps.
struct Cut<'a> {
    /// Cut with the twin (or on the bare machine).
    twin: bool,
    freq_hz: String,
    pv_um: String,
    rms_um: String,
    phase_deg: String,
    points: usize,
    coprocessor: &'a str,
    faults: u32,
    surface: String,
    error: String,
}

/// The whole report for the trials of one command (e.g. without and with the twin).
pub fn render(title: &str, reports: &[TrialReport]) -> String {
    let cuts = reports
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let [surface, error] = cut_maps(&format!("cut{i}"), &r.maps);
            Cut {
                twin: r.twin,
                freq_hz: format!("{:.1}", r.freq_hz),
                pv_um: format!("{:.3}", r.form_error_pv_um),
                rms_um: format!("{:.3}", r.form_error_rms_um),
                phase_deg: format!("{:+.2}", r.phase_error_deg),
                points: r.points,
                coprocessor: &r.coprocessor,
                faults: r.fault_count,
                surface,
                error,
            }
        })
        .collect();
    // A template is `Display`, failing only where a field's `Display` fails: the view holds
    // strings and numbers, which never do.
    TrialPage { title, cuts }.to_string()
}

#[cfg(test)]
mod tests {
    use super::*;
    use sts_emulator::PlantParams;
    use sts_rig::machine_params;
    use sts_rig::trial::{run_trial, TrialConfig, MAP_ANGULAR_BINS};
    use sts_rig::SimCoprocessor;

    #[test]
    fn a_bare_cut_gives_both_maps_over_the_whole_disc() {
        let plant = PlantParams::default();
        let config = TrialConfig { freq_hz: 40.0, r_start_mm: 0.1, r_eval_mm: 0.1, ..TrialConfig::default() };
        let report =
            run_trial(&mut SimCoprocessor::boot(&[]), &plant, &[], None, machine_params(&plant, 0.012), &config)
                .unwrap();
        let maps = &report.maps;
        // 0.1 mm at 5 um per revolution: 10 rings of two revolutions each.
        assert_eq!(maps.surface_um.len(), 10);
        assert!(maps.surface_um.iter().all(|row| row.len() == MAP_ANGULAR_BINS));
        // Every bin of the disc is cut.
        assert!(maps.surface_um.iter().flatten().all(Option::is_some));
        // The bicuspid's two cusps: the surface at r = 0.1 mm swings about 0.6 um peak to
        // peak around the disc; the bare machine's deviation is mostly the dynamic error.
        let (lo, hi) = range(&maps.surface_um[9..]);
        assert!(hi - lo > 0.8, "{lo} {hi}");
        let html = render("test", &[report]);
        assert!(html.starts_with("<!DOCTYPE html>") && html.ends_with("</html>"));
        assert_eq!(html.matches("<svg").count(), 2);
        assert_eq!(html.matches("class=\"cell\"").count(), 2 * 10 * MAP_ANGULAR_BINS);
        assert!(!html.contains("NaN"));
        // Self-contained: the only address is the SVG namespace.
        assert_eq!(html.matches("http").count(), html.matches("http://www.w3.org/2000/svg").count());
    }
}
