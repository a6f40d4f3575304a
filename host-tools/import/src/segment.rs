//! Finding the test's groups in one long recording: a group is a stretch of command motion
//! between pauses, where the command stays within a tolerance of one value for at least the
//! pause's length. Online, row by row, so that a recording of any length needs memory for one
//! group only.

/// One row, in canonical units.
#[derive(Clone, Copy, Debug, Default)]
pub struct Row {
    /// The recording's time, s.
    pub t_s: f64,
    /// Z command, um.
    pub cmd_um: f64,
    /// Z encoder, um.
    pub enc_um: f64,
    /// The probe at the tool, um.
    pub tcp_um: f64,
    /// The accelerometer, m/s^2.
    pub acc_mps2: f64,
    /// X position, mm.
    pub x_mm: f64,
    /// X acceleration, m/s^2.
    pub x_acc_mps2: f64,
    /// Spindle angle, degrees.
    pub spindle_deg: f64,
    /// Temperature, degC.
    pub temp_c: f64,
}

/// Rows at rest kept to find where a group starts.
const REST_HISTORY: usize = 64;

/// Finds groups as rows arrive.
pub struct Segmenter {
    tolerance_um: f64,
    min_pause: usize,
    /// The value the command holds (at rest), or its last moving value (in motion).
    anchor: Option<f64>,
    /// The last rows at rest, newest last: a group starts at the last of them where its
    /// command leaves the rest level (a sine from rest starts at its zero), though its first
    /// steps may lie within the tolerance.
    rest: std::collections::VecDeque<Row>,
    /// The group so far, while in motion.
    rows: Vec<Row>,
    /// Rows at rest since the last motion, while in motion.
    still: usize,
}

impl Segmenter {
    /// At rest while the command stays within `tolerance_um` of one value; a pause lasts at
    /// least `min_pause` rows.
    pub fn new(tolerance_um: f64, min_pause: usize) -> Self {
        Self {
            tolerance_um,
            min_pause: min_pause.max(1),
            anchor: None,
            rest: Default::default(),
            rows: Vec::new(),
            still: 0,
        }
    }

    /// Takes the next row; returns a group's rows when this row completes its pause.
    pub fn push(&mut self, row: Row) -> Option<Vec<Row>> {
        let anchor = *self.anchor.get_or_insert(row.cmd_um);
        let at_anchor = (row.cmd_um - anchor).abs() <= self.tolerance_um;
        if self.rows.is_empty() {
            if at_anchor {
                if self.rest.len() == REST_HISTORY {
                    self.rest.pop_front();
                }
                self.rest.push_back(row);
            } else {
                // Back from the motion while the command comes nearer the rest level at each
                // step: the group starts where it left it.
                let away = |r: &Row| (r.cmd_um - anchor).abs();
                let mut start = self.rest.len();
                while start > 0 && (start == self.rest.len() || away(&self.rest[start - 1]) < away(&self.rest[start])) {
                    start -= 1;
                }
                self.rows.extend(self.rest.drain(..).skip(start));
                self.rows.push(row);
                self.anchor = Some(row.cmd_um);
                self.still = 1;
            }
            return None;
        }
        self.rows.push(row);
        // A row away from the anchor may be a pause's first: the run of rows at rest counts it.
        if at_anchor {
            self.still += 1;
        } else {
            self.anchor = Some(row.cmd_um);
            self.still = 1;
        }
        if self.still < self.min_pause {
            return None;
        }
        // The pause's rows are not the group's; the last of them is the next group's start.
        let keep = self.rows.len() - self.still;
        let mut group = std::mem::take(&mut self.rows);
        self.rest = group[keep..].iter().rev().take(REST_HISTORY).rev().copied().collect();
        self.anchor = group.last().map(|r| r.cmd_um);
        group.truncate(keep);
        self.still = 0;
        Some(group)
    }

    /// The group in motion when the recording ends, if any (cut short by the recording's end,
    /// its pause not reached).
    pub fn finish(&mut self) -> Option<Vec<Row>> {
        let group = std::mem::take(&mut self.rows);
        self.still = 0;
        (group.len() > 1).then_some(group)
    }
}

/// Cuts groups at given times: a row belongs to the window `[start, start + duration)` that
/// holds its time; rows outside every window are dropped. Windows sorted, not overlapping.
pub struct Scheduler {
    windows: Vec<(f64, f64)>,
    next: usize,
    rows: Vec<Row>,
}

impl Scheduler {
    /// `windows`: `(start_s, end_s)`, sorted and disjoint.
    pub fn new(windows: Vec<(f64, f64)>) -> Self {
        Self { windows, next: 0, rows: Vec::new() }
    }

    /// Takes the next row; returns a window's rows when this row lies past it.
    pub fn push(&mut self, row: Row) -> Option<Vec<Row>> {
        let (start, end) = *self.windows.get(self.next)?;
        if row.t_s >= end {
            self.next += 1;
            let done = std::mem::take(&mut self.rows);
            // The row may open the next window.
            if let Some(&(s, e)) = self.windows.get(self.next)
                && row.t_s >= s
                && row.t_s < e
            {
                self.rows.push(row);
            }
            return (!done.is_empty()).then_some(done);
        }
        if row.t_s >= start {
            self.rows.push(row);
        }
        None
    }

    /// The window open when the recording ends, if any.
    pub fn finish(&mut self) -> Option<Vec<Row>> {
        let rows = std::mem::take(&mut self.rows);
        (rows.len() > 1).then_some(rows)
    }
}

/// How groups are found: from the command's motion, or at given times.
pub enum Finder {
    /// From the command's motion between pauses.
    Motion(Segmenter),
    /// At the mapping's schedule.
    Schedule(Scheduler),
}

impl Finder {
    /// Takes the next row; returns a group's rows when one is complete.
    pub fn push(&mut self, row: Row) -> Option<Vec<Row>> {
        match self {
            Finder::Motion(s) => s.push(row),
            Finder::Schedule(s) => s.push(row),
        }
    }

    /// The group open when the recording ends, if any.
    pub fn finish(&mut self) -> Option<Vec<Row>> {
        match self {
            Finder::Motion(s) => s.finish(),
            Finder::Schedule(s) => s.finish(),
        }
    }
}

/// A group's command as a sine: frequency from its upward zero crossings (interpolated) about
/// its mean, amplitude by least squares at that frequency. `None` without two crossings.
pub fn sine_of(rows: &[Row], sample_rate_hz: f64) -> Option<(f64, f64)> {
    let n = rows.len();
    if n < 4 {
        return None;
    }
    let mean = rows.iter().map(|r| r.cmd_um).sum::<f64>() / n as f64;
    let mut crossings = Vec::new();
    for k in 1..n {
        let (a, b) = (rows[k - 1].cmd_um - mean, rows[k].cmd_um - mean);
        if a < 0.0 && b >= 0.0 {
            crossings.push((k - 1) as f64 + a / (a - b));
        }
    }
    if crossings.len() < 2 {
        return None;
    }
    let periods = (crossings.len() - 1) as f64;
    let freq_hz = periods * sample_rate_hz / (crossings[crossings.len() - 1] - crossings[0]);
    // The amplitude at that frequency, by the sine fit of the analysis (time in samples).
    let t: Vec<f64> = (0..n).map(|k| k as f64 / sample_rate_hz).collect();
    let cmd: Vec<f64> = rows.iter().map(|r| r.cmd_um).collect();
    let fit = sts_analysis::sine::fit_sine(&t, &cmd, freq_hz)?;
    Some((freq_hz, fit.amp))
}

/// `x` to `digits` significant digits (what a test's nominal frequency or stroke looks like).
pub fn significant(x: f64, digits: i32) -> f64 {
    if x == 0.0 || !x.is_finite() {
        return x;
    }
    let scale = 10f64.powi(digits - 1 - x.abs().log10().floor() as i32);
    (x * scale).round() / scale
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rows(cmd: impl Iterator<Item = f64>) -> Vec<Row> {
        cmd.enumerate().map(|(k, c)| Row { t_s: k as f64 / 8000.0, cmd_um: c, ..Row::default() }).collect()
    }

    #[test]
    fn groups_start_at_the_sines_zero_and_end_before_the_pause() {
        // Rest, 2 s of 3 Hz at 4 um from its zero, rest, 1 s of 10 Hz at 2 um, rest.
        let sine = |f: f64, a: f64, n: usize| {
            (0..n).map(move |k| a * (2.0 * std::f64::consts::PI * f * k as f64 / 8000.0).sin())
        };
        let cmd: Vec<f64> = std::iter::repeat_n(0.0, 3000)
            .chain(sine(3.0, 4.0, 16000))
            .chain(std::iter::repeat_n(0.0, 3000))
            .chain(sine(10.0, 2.0, 8000))
            .chain(std::iter::repeat_n(0.0, 3000))
            .collect();
        let mut s = Segmenter::new(0.001, 2000);
        let groups: Vec<Vec<Row>> = rows(cmd.into_iter()).into_iter().filter_map(|r| s.push(r)).collect();
        assert!(s.finish().is_none());
        assert_eq!(groups.len(), 2);
        assert_eq!(groups[0].len(), 16000);
        assert_eq!(groups[0][0].t_s, 3000.0 / 8000.0, "the group starts at its sine's zero");
        assert_eq!(groups[1].len(), 8000);
        let (f, a) = sine_of(&groups[0], 8000.0).unwrap();
        assert!((f - 3.0).abs() < 1e-6 && (a - 4.0).abs() < 1e-6, "{f} {a}");
        let (f, a) = sine_of(&groups[1], 8000.0).unwrap();
        assert!((f - 10.0).abs() < 1e-6 && (a - 2.0).abs() < 1e-6, "{f} {a}");
    }

    #[test]
    fn significant_digits() {
        assert_eq!(significant(4.999_999_7, 6), 5.0);
        assert_eq!(significant(0.123_456_78, 3), 0.123);
    }
}
