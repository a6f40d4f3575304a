//! Small inline-SVG charts (no scripts, no network): line charts, heat maps and bar charts.

use std::fmt::Write as _;

/// Colours of successive series.
pub const PALETTE: [&str; 6] = ["#1f5fbf", "#d2552b", "#2a9d55", "#8e44ad", "#b8860b", "#555555"];

const W: f64 = 640.0;
const H: f64 = 300.0;
const LEFT: f64 = 70.0;
const RIGHT: f64 = 20.0;
const TOP: f64 = 34.0;
const BOTTOM: f64 = 46.0;

/// Escapes text for XML: the charts are built as code, outside the templates' autoescaping.
fn esc(text: &str) -> String {
    text.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

/// A short number for axis ticks.
pub fn tick_label(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e4).contains(&a) {
        format!("{v:.1e}")
    } else if a >= 100.0 {
        format!("{v:.0}")
    } else if a >= 1.0 {
        format!("{v:.2}").trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        format!("{v:.4}").trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

fn nice_ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    let span = (hi - lo).abs().max(1e-300);
    let raw = span / n.max(1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0].iter().map(|m| m * mag).find(|s| *s >= raw).unwrap_or(10.0 * mag);
    let first = (lo / step).ceil() * step;
    let mut out = Vec::new();
    let mut v = first;
    while v <= hi + 1e-9 * span && out.len() < 50 {
        out.push(if v.abs() < 1e-12 * span { 0.0 } else { v });
        v += step;
    }
    out
}

fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    if hi - lo < 1e-12 * (hi.abs() + lo.abs()).max(1e-12) {
        let pad = if hi.abs() > 0.0 { hi.abs() * 0.1 } else { 1.0 };
        return (lo - pad, hi + pad);
    }
    let pad = 0.05 * (hi - lo);
    (lo - pad, hi + pad)
}

/// A series of a line chart.
pub struct Series<'a> {
    /// Legend text.
    pub name: String,
    /// x values.
    pub x: &'a [f64],
    /// y values.
    pub y: &'a [f64],
    /// Draw markers instead of a line.
    pub markers: bool,
}

/// Opens a chart: the `<svg>` element of `width` x `height` with CSS class `class`, a white
/// background and the title centred at the top.
pub fn open_chart(out: &mut String, class: &str, id: &str, title: &str, width: f64, height: f64) {
    let _ = write!(
        out,
        r##"<svg xmlns="http://www.w3.org/2000/svg" class="{class}" id="{id}" width="{width}" height="{height}" viewBox="0 0 {width} {height}" role="img" aria-label="{t}"><rect width="{width}" height="{height}" fill="#ffffff"/><text x="{cx}" y="20" text-anchor="middle" font-size="14" font-weight="bold">{t}</text>"##,
        t = esc(title),
        cx = width / 2.0
    );
}

/// The plot's frame, its axis labels and the y ticks; numeric x ticks over `xr` where given
/// (a chart of categories labels its own).
fn frame(
    out: &mut String,
    id: &str,
    title: &str,
    x_label: &str,
    y_label: &str,
    xr: Option<(f64, f64)>,
    yr: (f64, f64),
) {
    open_chart(out, "chart", id, title, W, H);
    let (pw, ph) = (W - LEFT - RIGHT, H - TOP - BOTTOM);
    let _ = write!(out, r##"<rect x="{LEFT}" y="{TOP}" width="{pw}" height="{ph}" fill="none" stroke="#888"/>"##);
    let x_ticks = xr.map(|xr| nice_ticks(xr.0, xr.1, 8).into_iter().map(move |t| (t, xr)));
    for (t, xr) in x_ticks.into_iter().flatten() {
        let x = LEFT + (t - xr.0) / (xr.1 - xr.0) * pw;
        let _ = write!(
            out,
            r##"<line x1="{x:.1}" y1="{TOP}" x2="{x:.1}" y2="{b:.1}" stroke="#eee"/><text x="{x:.1}" y="{ty:.1}" text-anchor="middle" font-size="11">{l}</text>"##,
            b = TOP + ph,
            ty = TOP + ph + 15.0,
            l = tick_label(t)
        );
    }
    for t in nice_ticks(yr.0, yr.1, 6) {
        let y = TOP + ph - (t - yr.0) / (yr.1 - yr.0) * ph;
        let _ = write!(
            out,
            r##"<line x1="{LEFT}" y1="{y:.1}" x2="{r:.1}" y2="{y:.1}" stroke="#eee"/><text x="{tx:.1}" y="{ty:.1}" text-anchor="end" font-size="11">{l}</text>"##,
            r = LEFT + pw,
            tx = LEFT - 5.0,
            ty = y + 4.0,
            l = tick_label(t)
        );
    }
    let _ = write!(
        out,
        r##"<text x="{cx:.1}" y="{by:.1}" text-anchor="middle" font-size="12">{xl}</text><text transform="translate(14,{cy:.1}) rotate(-90)" text-anchor="middle" font-size="12">{yl}</text>"##,
        cx = LEFT + pw / 2.0,
        by = H - 8.0,
        cy = TOP + ph / 2.0,
        xl = esc(x_label),
        yl = esc(y_label)
    );
}

/// A line (or marker) chart of several series.
pub fn line_chart(id: &str, title: &str, x_label: &str, y_label: &str, series: &[Series]) -> String {
    let xr = range(series.iter().flat_map(|s| s.x.iter().copied()));
    let yr = range(series.iter().flat_map(|s| s.y.iter().copied()));
    let mut out = String::new();
    frame(&mut out, id, title, x_label, y_label, Some(xr), yr);
    let (pw, ph) = (W - LEFT - RIGHT, H - TOP - BOTTOM);
    let px = |x: f64| LEFT + (x - xr.0) / (xr.1 - xr.0) * pw;
    let py = |y: f64| TOP + ph - (y - yr.0) / (yr.1 - yr.0) * ph;
    for (i, s) in series.iter().enumerate() {
        let colour = PALETTE[i % PALETTE.len()];
        let n = s.x.len().min(s.y.len());
        // At most ~1500 points per series: decimate evenly (min/max would be nicer; fine here).
        let step = (n / 1500).max(1);
        if s.markers {
            for k in (0..n).step_by(step) {
                if s.x[k].is_finite() && s.y[k].is_finite() {
                    let _ = write!(
                        out,
                        r##"<circle cx="{:.1}" cy="{:.1}" r="2.5" fill="{colour}"/>"##,
                        px(s.x[k]),
                        py(s.y[k])
                    );
                }
            }
        } else {
            let mut d = String::new();
            for k in (0..n).step_by(step) {
                if s.x[k].is_finite() && s.y[k].is_finite() {
                    let _ = write!(d, "{}{:.1},{:.1}", if d.is_empty() { "M" } else { "L" }, px(s.x[k]), py(s.y[k]));
                }
            }
            let _ = write!(out, r##"<path d="{d}" fill="none" stroke="{colour}" stroke-width="1.4"/>"##);
        }
        let ly = TOP + 14.0 + 15.0 * i as f64;
        let _ = write!(
            out,
            r##"<rect x="{lx:.1}" y="{ry:.1}" width="12" height="4" fill="{colour}"/><text x="{tx:.1}" y="{ty:.1}" font-size="11" class="legend">{name}</text>"##,
            lx = LEFT + 10.0,
            ry = ly - 6.0,
            tx = LEFT + 27.0,
            ty = ly,
            name = esc(&s.name)
        );
    }
    out.push_str("</svg>");
    out
}

/// One axis of a [`heat_map`]: its label and the value of each column (or row).
pub struct GridAxis<'a> {
    /// Axis label, with its unit.
    pub label: &'a str,
    /// The value of each cell along the axis.
    pub values: &'a [f64],
}

/// A heat map of `values[row][col]` (rows: `y` values, columns: `x` values), with a colour bar.
pub fn heat_map(id: &str, title: &str, x: GridAxis, y: GridAxis, values: &[Vec<Option<f64>>], unit: &str) -> String {
    let (x_label, xs, y_label, ys) = (x.label, x.values, y.label, y.values);
    let vmax = values.iter().flatten().flatten().fold(0.0f64, |m, v| m.max(*v)).max(1e-12);
    let mut out = String::new();
    open_chart(&mut out, "chart heatmap", id, title, W, H);
    let (pw, ph) = (W - LEFT - RIGHT - 70.0, H - TOP - BOTTOM);
    let cw = pw / xs.len().max(1) as f64;
    let ch = ph / ys.len().max(1) as f64;
    for (r, row) in values.iter().enumerate() {
        for (c, v) in row.iter().enumerate() {
            let x = LEFT + c as f64 * cw;
            let y = TOP + ph - (r + 1) as f64 * ch;
            let fill = match v {
                Some(v) => colour_scale(v / vmax),
                None => "#dddddd".to_string(),
            };
            let tip = v.map_or("no group".to_string(), |v| format!("{} {unit}", tick_label(v)));
            let _ = write!(
                out,
                r##"<rect class="cell" x="{x:.1}" y="{y:.1}" width="{w:.1}" height="{h:.1}" fill="{fill}" stroke="#fff" stroke-width="0.5"><title>{fx} Hz, {fy} um: {tip}</title></rect>"##,
                w = cw,
                h = ch,
                fx = tick_label(xs[c]),
                fy = tick_label(ys[r]),
                tip = esc(&tip)
            );
        }
    }
    for (c, x) in xs.iter().enumerate() {
        let _ = write!(
            out,
            r##"<text x="{:.1}" y="{:.1}" text-anchor="middle" font-size="11">{}</text>"##,
            LEFT + (c as f64 + 0.5) * cw,
            TOP + ph + 15.0,
            tick_label(*x)
        );
    }
    for (r, y) in ys.iter().enumerate() {
        let _ = write!(
            out,
            r##"<text x="{:.1}" y="{:.1}" text-anchor="end" font-size="11">{}</text>"##,
            LEFT - 5.0,
            TOP + ph - (r as f64 + 0.5) * ch + 4.0,
            tick_label(*y)
        );
    }
    // Colour bar.
    let bx = LEFT + pw + 20.0;
    for i in 0..20 {
        let f = i as f64 / 19.0;
        let _ = write!(
            out,
            r##"<rect x="{bx:.1}" y="{:.1}" width="14" height="{:.1}" fill="{}"/>"##,
            TOP + ph - (i + 1) as f64 * ph / 20.0,
            ph / 20.0 + 0.5,
            colour_scale(f)
        );
    }
    let _ = write!(
        out,
        r##"<text x="{tx:.1}" y="{t0:.1}" font-size="11">{top} {unit}</text><text x="{tx:.1}" y="{t1:.1}" font-size="11">0</text>"##,
        tx = bx + 18.0,
        t0 = TOP + 10.0,
        t1 = TOP + ph,
        top = tick_label(vmax)
    );
    let _ = write!(
        out,
        r##"<text x="{cx:.1}" y="{by:.1}" text-anchor="middle" font-size="12">{xl}</text><text transform="translate(14,{cy:.1}) rotate(-90)" text-anchor="middle" font-size="12">{yl}</text></svg>"##,
        cx = LEFT + pw / 2.0,
        by = H - 8.0,
        cy = TOP + ph / 2.0,
        xl = esc(x_label),
        yl = esc(y_label)
    );
    out
}

/// White -> yellow -> red -> dark red for 0..1.
pub fn colour_scale(f: f64) -> String {
    let f = f.clamp(0.0, 1.0);
    let (r, g, b) = if f < 0.5 {
        let t = f / 0.5;
        (255.0, 255.0 - 55.0 * t, 255.0 - 225.0 * t)
    } else {
        let t = (f - 0.5) / 0.5;
        (255.0 - 115.0 * t, 200.0 - 200.0 * t, 30.0 - 30.0 * t)
    };
    format!("#{:02x}{:02x}{:02x}", r as u8, g as u8, b as u8)
}

/// Grouped bars: one group per label, one bar per series.
pub fn bar_chart(
    id: &str,
    title: &str,
    x_label: &str,
    y_label: &str,
    labels: &[String],
    series: &[(String, Vec<f64>)],
) -> String {
    let ymax =
        series.iter().flat_map(|s| s.1.iter().copied()).filter(|v| v.is_finite()).fold(0.0f64, f64::max).max(1e-12)
            * 1.08;
    let mut out = String::new();
    frame(&mut out, id, title, x_label, y_label, None, (0.0, ymax));
    let (pw, ph) = (W - LEFT - RIGHT, H - TOP - BOTTOM);
    let slot = pw / labels.len().max(1) as f64;
    let bw = slot * 0.8 / series.len().max(1) as f64;
    for (i, label) in labels.iter().enumerate() {
        for (j, (_, values)) in series.iter().enumerate() {
            let v = values.get(i).copied().unwrap_or(0.0).max(0.0);
            let h = v / ymax * ph;
            let _ = write!(
                out,
                r##"<rect class="bar" x="{:.1}" y="{:.1}" width="{bw:.1}" height="{h:.1}" fill="{}"><title>{}: {}</title></rect>"##,
                LEFT + i as f64 * slot + 0.1 * slot + j as f64 * bw,
                TOP + ph - h,
                PALETTE[j % PALETTE.len()],
                esc(label),
                tick_label(v)
            );
        }
        let _ = write!(
            out,
            r##"<text x="{:.1}" y="{:.1}" text-anchor="middle" font-size="11" fill="#333">{}</text>"##,
            LEFT + (i as f64 + 0.5) * slot,
            TOP + ph + 15.0,
            esc(label)
        );
    }
    for (j, (name, _)) in series.iter().enumerate() {
        let ly = TOP + 14.0 + 15.0 * j as f64;
        let _ = write!(
            out,
            r##"<rect x="{:.1}" y="{:.1}" width="12" height="8" fill="{}"/><text x="{:.1}" y="{ly:.1}" font-size="11">{}</text>"##,
            W - RIGHT - 200.0,
            ly - 8.0,
            PALETTE[j % PALETTE.len()],
            W - RIGHT - 184.0,
            esc(name)
        );
    }
    out.push_str("</svg>");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn charts_are_well_formed_and_escape_text() {
        let x = [0.0, 1.0, 2.0];
        let y = [1.0, -1.0, 0.5];
        let svg = line_chart("c", "a < b", "x", "y", &[Series { name: "m&p".into(), x: &x, y: &y, markers: false }]);
        assert!(svg.starts_with("<svg") && svg.ends_with("</svg>"));
        assert!(svg.contains("a &lt; b") && svg.contains("m&amp;p"));
        let hm = heat_map(
            "h",
            "map",
            GridAxis { label: "f", values: &[1.0, 2.0] },
            GridAxis { label: "A", values: &[1.0] },
            &[vec![Some(0.5), None]],
            "um",
        );
        assert_eq!(hm.matches("class=\"cell\"").count(), 2);
        assert_eq!(colour_scale(0.0), "#ffffff");
        assert_eq!(nice_ticks(0.0, 1.0, 5).len(), 6);
        // A bar chart's x axis shows its categories, no numbers between them.
        let bars = bar_chart(
            "b",
            "bars",
            "rung",
            "nm",
            &["start".into(), "+ drift".into()],
            &[("rms".into(), vec![3.0, 1.0])],
        );
        let x_texts: Vec<&str> = bars
            .split("<text ")
            .filter(|t| t.contains("text-anchor=\"middle\" font-size=\"11\""))
            .filter_map(|t| t.split('>').nth(1)?.split('<').next())
            .collect();
        assert_eq!(x_texts, ["start", "+ drift"]);
    }
}
