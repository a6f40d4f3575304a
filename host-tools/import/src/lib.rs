#![doc = include_str!("../README.md")]
pub mod mapping;
pub mod segment;
pub mod source;

use std::path::{Path, PathBuf};

use sts_dataset::{Column, GroupData, GroupInfo, Manifest};

use mapping::{Mapping, Resolved};
use segment::{significant, sine_of, Finder, Row, Scheduler, Segmenter};
use source::{At, Source};

/// Why a recording could not be imported.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ImportError {
    /// A file could not be read or written.
    #[error("{}: {source}", .path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's reason.
        source: std::io::Error,
    },
    /// The mapping file is malformed or names something impossible.
    #[error("{}: {message}", .path.display())]
    Mapping {
        /// The mapping file.
        path: PathBuf,
        /// What is wrong, naming the field.
        message: String,
    },
    /// The recording's format is not one this importer reads.
    #[error("{}: cannot read .{extension} recordings yet (it reads {})", .path.display(), source::READ)]
    Format {
        /// The recording.
        path: PathBuf,
        /// Its extension.
        extension: String,
    },
    /// The recording cannot be read as its format.
    #[error("{}: {message}", .path.display())]
    Unreadable {
        /// The recording.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// A mapped channel is not in the recording.
    #[error("{}: no channel `{name}` (the mapping's {role}); the recording has: {available}", .path.display())]
    MissingChannel {
        /// The recording.
        path: PathBuf,
        /// The role in the mapping.
        role: &'static str,
        /// The channel's name in the mapping.
        name: String,
        /// The recording's channels.
        available: String,
    },
    /// A value is not a number, or a row is short (a truncated file).
    #[error("{}{at}: channel `{channel}`: {message}", .path.display())]
    Value {
        /// The recording.
        path: PathBuf,
        /// Where: the line (the header is line 1) or the sample.
        at: At,
        /// The channel.
        channel: String,
        /// What is wrong.
        message: String,
    },
    /// The time channel does not advance by one sample step.
    #[error("{}{at}: channel `{channel}`: the time advances by {step_s:.6e} s, expected {expected_s:.6e} s (one sample)", .path.display())]
    TimeStep {
        /// The recording.
        path: PathBuf,
        /// Where.
        at: At,
        /// The time channel.
        channel: String,
        /// The step found, s.
        step_s: f64,
        /// The step expected, s.
        expected_s: f64,
    },
    /// A group's command is not a steady sine.
    #[error("{}: the group at {start_s:.4}-{end_s:.4} s: its command (`{channel}`) crosses its mean fewer than twice: not a steady sine (a pause shorter than [segments] min_pause_s inside it?)", .path.display())]
    NotASine {
        /// The recording.
        path: PathBuf,
        /// The command channel.
        channel: String,
        /// The group's start, s.
        start_s: f64,
        /// Its end, s.
        end_s: f64,
    },
    /// No group was found.
    #[error("{}: no group found: the command (`{channel}`) never moves by more than [segments] rest_tolerance_um ({tolerance_um} um) between pauses", .path.display())]
    NoGroups {
        /// The recording.
        path: PathBuf,
        /// The command channel.
        channel: String,
        /// The rest tolerance, um.
        tolerance_um: f64,
    },
    /// Writing the dataset failed.
    #[error(transparent)]
    Dataset(#[from] sts_dataset::DatasetError),
}

/// A group found, as the import reports it.
#[derive(Clone, Debug, PartialEq)]
pub struct FoundGroup {
    /// The recording it came from.
    pub recording: PathBuf,
    /// Its file in the dataset.
    pub file: String,
    /// Its start in machine time (the recordings' times, one after another), s.
    pub start_s: f64,
    /// Its length, s.
    pub duration_s: f64,
    /// The command's frequency, Hz.
    pub freq_hz: f64,
    /// The command's amplitude, um.
    pub amp_um: f64,
    /// The pause before it, s (from the recording's start for its first group).
    pub pause_before_s: f64,
}

/// What an import did.
#[derive(Clone, Debug)]
pub struct Imported {
    /// The groups, in order.
    pub groups: Vec<FoundGroup>,
    /// Samples per second.
    pub sample_rate_hz: f64,
    /// Rows read.
    pub rows: u64,
}

/// Progress: bytes read of all recordings, and their total.
pub type Progress<'a> = &'a mut dyn FnMut(u64, u64);

/// Imports `recordings` (in order) as the dataset directory `out` with `mapping`. The dataset
/// is written into a fresh directory beside `out` that replaces it once whole
/// ([`sts_dataset::output::StagedDir`]); what `out` may be is the caller's check
/// ([`sts_dataset::output::check_dataset_dir`]).
pub fn import(
    recordings: &[PathBuf],
    mapping: &Mapping,
    mapping_path: &Path,
    out: &Path,
    progress: Progress,
) -> Result<Imported, ImportError> {
    let resolved = mapping.resolve(mapping_path)?;
    let staged = sts_dataset::output::StagedDir::new(out)?;
    let out = staged.path();
    let total_bytes: u64 = recordings.iter().map(|p| std::fs::metadata(p).map_or(0, |m| m.len())).sum();
    let mut done_bytes = 0u64;
    let mut groups: Vec<FoundGroup> = Vec::new();
    let mut infos: Vec<GroupInfo> = Vec::new();
    let mut sample_rate_hz = mapping.sample_rate_hz.unwrap_or(0.0);
    let mut rows_read = 0u64;
    // Machine time of the next recording's start: recordings follow one another.
    let mut time_offset_s = 0.0;
    for path in recordings {
        let mut source = Source::open(path, &resolved)?;
        let has_time = resolved[0].role == "time";
        let mut segmenter: Option<Finder> = None;
        // Rows wait here until the sample rate is known (the time channel's first step).
        let mut pending: Vec<Row> = Vec::new();
        let mut k = 0u64;
        let (mut first_t, mut last_t) = (f64::NAN, f64::NAN);
        let mut last_end_s = 0.0;
        let mut found: Vec<Vec<Row>> = Vec::new();
        let mut write = |rows: Vec<Row>, rate: f64| {
            write_group(path, out, rows, rate, time_offset_s, &resolved, &mut groups, &mut infos, &mut last_end_s)
        };
        while let Some(values) = source.next(path, k, &resolved)? {
            let at = source.at(k);
            check_bounds(path, at, &values, &resolved)?;
            let time_channel = || resolved[0].channel.name.clone();
            let t = if has_time { values[0] } else { k as f64 / sample_rate_hz };
            if has_time {
                let step_error = |step_s: f64, expected_s: f64| ImportError::TimeStep {
                    path: path.clone(),
                    at,
                    channel: time_channel(),
                    step_s,
                    expected_s,
                };
                if k == 0 {
                    first_t = t;
                } else if k == 1 {
                    let step = t - first_t;
                    if step.is_nan() || step <= 0.0 {
                        return Err(step_error(step, f64::NAN));
                    }
                    sample_rate_hz = significant(1.0 / step, 9);
                } else {
                    let expected = 1.0 / sample_rate_hz;
                    if ((t - last_t) - expected).abs() > 0.05 * expected {
                        return Err(step_error(t - last_t, expected));
                    }
                }
                last_t = t;
            }
            pending.push(row_of(t, &values[usize::from(has_time)..], &resolved));
            k += 1;
            if k >= 2 || !has_time {
                let seg = segmenter.get_or_insert_with(|| finder(mapping, sample_rate_hz));
                for row in pending.drain(..) {
                    found.extend(seg.push(row));
                }
                for rows in found.drain(..) {
                    write(rows, sample_rate_hz)?;
                }
            }
            if k.is_multiple_of(65_536) {
                progress(done_bytes + source.bytes_read(), total_bytes);
            }
        }
        if let Some(rows) = segmenter.as_mut().and_then(Finder::finish) {
            write(rows, sample_rate_hz)?;
        }
        rows_read += k;
        done_bytes += std::fs::metadata(path).map_or(0, |m| m.len());
        progress(done_bytes, total_bytes);
        if groups.iter().all(|g| &g.recording != path) {
            return Err(ImportError::NoGroups {
                path: path.clone(),
                channel: mapping.channels.command.name.clone(),
                tolerance_um: mapping.segments.rest_tolerance_um,
            });
        }
        let span_s = if has_time { last_t - first_t } else { k as f64 / sample_rate_hz };
        time_offset_s += span_s + 1.0 / sample_rate_hz;
    }
    let mut manifest = Manifest::new(sample_rate_hz, &format!("imported from {}", names(recordings)), infos);
    manifest.acc_mps2_per_lsb = mapping.acc_mps2_per_lsb;
    sts_dataset::write_manifest(out, &manifest)?;
    staged.commit()?;
    Ok(Imported { groups, sample_rate_hz, rows: rows_read })
}

/// The dataset column a mapped role becomes.
fn column_of(role: &str) -> Column {
    match role {
        "time" => Column::TS,
        "command" => Column::ZCmdUm,
        "encoder" => Column::ZEncUm,
        "probe" => Column::ZTcpUm,
        "accelerometer" => Column::AccMps2,
        "x_position" => Column::XMm,
        "x_acceleration" => Column::XAccMps2,
        "spindle" => Column::SpindleDeg,
        _ => Column::TempC,
    }
}

/// Refuses a value (in the canonical unit) beyond what its channel's sensor can produce
/// ([`Column::physical_bounds`]); the time only needs to be finite, its origin is the
/// recording's.
fn check_bounds(path: &Path, at: At, values: &[f64], resolved: &[Resolved]) -> Result<(), ImportError> {
    for (r, v) in resolved.iter().zip(values) {
        let column = column_of(r.role);
        let (min, max) = if column == Column::TS { (f64::MIN, f64::MAX) } else { column.physical_bounds() };
        if !(min..=max).contains(v) {
            return Err(ImportError::Value {
                path: path.to_path_buf(),
                at,
                channel: r.channel.name.clone(),
                message: format!(
                    "{v:e} {} (as `{}`) is beyond what the sensor can produce ({min:e} to {max:e})",
                    unit_of(column),
                    column.name()
                ),
            });
        }
    }
    Ok(())
}

fn unit_of(column: Column) -> &'static str {
    match column {
        Column::TS => "s",
        Column::ZCmdUm | Column::ZEncUm | Column::ZTcpUm => "um",
        Column::AccMps2 | Column::XAccMps2 => "m/s^2",
        Column::XMm => "mm",
        Column::SpindleDeg => "deg",
        Column::TempC => "C",
    }
}

/// A row from the mapped values after the time.
fn row_of(t_s: f64, values: &[f64], resolved: &[Resolved]) -> Row {
    let mut row = Row { t_s, ..Row::default() };
    for (r, v) in resolved.iter().filter(|r| r.role != "time").zip(values) {
        match r.role {
            "command" => row.cmd_um = *v,
            "encoder" => row.enc_um = *v,
            "probe" => row.tcp_um = *v,
            "accelerometer" => row.acc_mps2 = *v,
            "x_position" => row.x_mm = *v,
            "x_acceleration" => row.x_acc_mps2 = *v,
            "spindle" => row.spindle_deg = *v,
            _ => row.temp_c = *v,
        }
    }
    row
}

/// Writes a found group and records it.
#[allow(clippy::too_many_arguments)]
fn write_group(
    path: &Path,
    out: &Path,
    rows: Vec<Row>,
    sample_rate_hz: f64,
    time_offset_s: f64,
    resolved: &[Resolved],
    groups: &mut Vec<FoundGroup>,
    infos: &mut Vec<GroupInfo>,
    last_end_s: &mut f64,
) -> Result<(), ImportError> {
    let (start_s, end_s) = (rows[0].t_s, rows[rows.len() - 1].t_s);
    let (freq_hz, amp_um) = sine_of(&rows, sample_rate_hz).ok_or_else(|| ImportError::NotASine {
        path: path.to_path_buf(),
        channel: resolved.iter().find(|r| r.role == "command").map_or_else(String::new, |r| r.channel.name.clone()),
        start_s,
        end_s,
    })?;
    let has = |role: &str| resolved.iter().any(|r| r.role == role);
    let n = rows.len();
    let mut g = GroupData::with_len(n);
    g.x_mm = has("x_position").then(|| vec![0.0; n]);
    g.x_acc_mps2 = has("x_acceleration").then(|| vec![0.0; n]);
    g.spindle_deg = has("spindle").then(|| vec![0.0; n]);
    g.temp_c = has("temperature").then(|| vec![0.0; n]);
    for (k, r) in rows.iter().enumerate() {
        g.t_s[k] = k as f64 / sample_rate_hz;
        g.z_cmd_um[k] = r.cmd_um;
        g.z_enc_um[k] = r.enc_um;
        g.z_tcp_um[k] = r.tcp_um;
        g.acc_mps2[k] = r.acc_mps2;
        for (col, v) in [
            (&mut g.x_mm, r.x_mm),
            (&mut g.x_acc_mps2, r.x_acc_mps2),
            (&mut g.spindle_deg, r.spindle_deg),
            (&mut g.temp_c, r.temp_c),
        ] {
            if let Some(c) = col {
                c[k] = v;
            }
        }
    }
    let file = format!("g{:03}.csv", infos.len());
    let mut info = GroupInfo::new(&file, significant(freq_hz, 6), significant(amp_um, 6), time_offset_s + start_s);
    sts_dataset::write_group(out, &mut info, &g)?;
    groups.push(FoundGroup {
        recording: path.to_path_buf(),
        file,
        start_s: info.start_s,
        duration_s: n as f64 / sample_rate_hz,
        freq_hz: info.freq_hz,
        amp_um: info.amp_um,
        pause_before_s: start_s - *last_end_s,
    });
    *last_end_s = end_s + 1.0 / sample_rate_hz;
    infos.push(info);
    Ok(())
}

fn names(recordings: &[PathBuf]) -> String {
    recordings
        .iter()
        .map(|p| p.file_name().map_or_else(|| p.display().to_string(), |n| n.to_string_lossy().into_owned()))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The mapping's way of finding groups: its schedule (times in each recording's own time), or
/// the command's motion between pauses.
fn finder(mapping: &Mapping, sample_rate_hz: f64) -> Finder {
    if mapping.schedule.is_empty() {
        let pause = (mapping.segments.min_pause_s * sample_rate_hz).ceil() as usize;
        Finder::Motion(Segmenter::new(mapping.segments.rest_tolerance_um, pause))
    } else {
        let mut windows: Vec<(f64, f64)> =
            mapping.schedule.iter().map(|s| (s.start_s, s.start_s + s.duration_s)).collect();
        windows.sort_by(|a, b| a.0.total_cmp(&b.0));
        Finder::Schedule(Scheduler::new(windows))
    }
}
