//! A recording's mapped channels, row by row, in canonical units: CSV or TSV read record by
//! record, an NI TDMS file's channels and an HDF5 file's datasets read in chunks (the
//! `tdms-rs` and `hdf5-pure` crates), in bounded memory whatever the length; or a MATLAB
//! MAT-file's variables, held whole: v5/v7 through the `matfile` crate (the format compresses
//! each variable as one stream), v7.3 (HDF5 inside, a variable stored transposed) through
//! `hdf5-pure`.

use std::io::BufReader;
use std::path::Path;

use crate::mapping::Resolved;
use crate::ImportError;

/// Where in a recording a value is: a CSV line (the header is line 1) or a MAT sample (1-based).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum At {
    /// A line of a CSV or TSV file.
    Line(u64),
    /// A sample of a MAT-file's variables.
    Sample(u64),
}

impl std::fmt::Display for At {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            At::Line(n) => write!(f, ":{n}"),
            At::Sample(n) => write!(f, " sample {n}"),
        }
    }
}

/// An open recording.
pub enum Source {
    /// CSV or TSV.
    Csv {
        /// The reader.
        reader: csv::Reader<BufReader<std::fs::File>>,
        /// The record being read.
        record: csv::StringRecord,
        /// Columns in the header.
        header_len: usize,
        /// The mapped channels' columns.
        index: Vec<usize>,
    },
    /// A MAT-file: the mapped channels' recorded values.
    Mat {
        /// Per mapped channel, its values.
        columns: Vec<Vec<f64>>,
    },
    /// An NI TDMS file, read a chunk of samples at a time.
    Tdms {
        /// The file (its metadata indexed, the data read on demand).
        file: Box<tdms_rs::TdmsFile>,
        /// Per mapped channel: its group and channel names.
        names: Vec<(String, String)>,
        /// Samples per channel.
        len: usize,
        /// The current chunk's first sample.
        chunk_start: usize,
        /// Per mapped channel, the chunk's values in canonical units.
        chunk: Vec<Vec<f64>>,
        /// The file's size, bytes.
        bytes_len: u64,
    },
    /// An HDF5 file, read a chunk of rows at a time.
    Hdf5 {
        /// The mapped channels' datasets.
        channels: Vec<Hdf5Channel>,
        /// Samples per channel.
        len: usize,
        /// The current chunk's first sample.
        chunk_start: usize,
        /// Per mapped channel, the chunk's values in canonical units.
        chunk: Vec<Vec<f64>>,
        /// The file's size, bytes.
        bytes_len: u64,
    },
}

/// An HDF5 dataset a channel reads, and its column.
pub struct Hdf5Channel {
    /// The dataset.
    dataset: hdf5_pure::Dataset,
    /// Columns per row (1 for a 1-D dataset).
    width: usize,
    /// The column read, from 0.
    col: usize,
}

/// Samples per channel read from a TDMS or HDF5 file at a time.
const CHUNK: usize = 1 << 16;

/// The extensions read.
pub const READ: &str =
    "CSV and TSV (.csv, .tsv, .txt), MATLAB v5, v7 and v7.3 (.mat), NI TDMS (.tdms), HDF5 (.h5, .hdf5)";

fn delimiter(path: &Path, first_line: &str) -> u8 {
    let tsv = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("tsv"));
    if tsv || first_line.contains('\t') {
        b'\t'
    } else if first_line.contains(';') && !first_line.contains(',') {
        b';'
    } else {
        b','
    }
}

impl Source {
    /// Opens `path` and finds the mapped channels in it.
    pub fn open(path: &Path, resolved: &[Resolved]) -> Result<Self, ImportError> {
        let ext = path.extension().map_or(String::new(), |e| e.to_string_lossy().to_ascii_lowercase());
        match ext.as_str() {
            "csv" | "tsv" | "txt" => Self::open_csv(path, resolved),
            "mat" => Self::open_mat(path, resolved),
            "tdms" => Self::open_tdms(path, resolved),
            "h5" | "hdf5" => Self::open_hdf5(path, resolved, false),
            _ => Err(ImportError::Format { path: path.to_path_buf(), extension: ext }),
        }
    }

    fn open_csv(path: &Path, resolved: &[Resolved]) -> Result<Self, ImportError> {
        let io = |source| ImportError::Io { path: path.to_path_buf(), source };
        let mut first = String::new();
        std::io::BufRead::read_line(&mut BufReader::new(std::fs::File::open(path).map_err(io)?), &mut first)
            .map_err(io)?;
        let file = std::fs::File::open(path).map_err(io)?;
        let mut reader = csv::ReaderBuilder::new()
            .delimiter(delimiter(path, &first))
            .flexible(true)
            .trim(csv::Trim::All)
            .from_reader(BufReader::with_capacity(1 << 20, file));
        let header = reader.headers().map_err(|e| csv_error(path, e))?.clone();
        for r in resolved {
            let columns: Vec<usize> =
                header.iter().enumerate().filter(|(_, h)| *h == r.channel.name).map(|(i, _)| i + 1).collect();
            if columns.len() > 1 {
                return Err(ImportError::Value {
                    path: path.to_path_buf(),
                    at: At::Line(1),
                    channel: r.channel.name.clone(),
                    message: format!(
                        "the header names it {} times (columns {}): which one is the {}?",
                        columns.len(),
                        columns.iter().map(usize::to_string).collect::<Vec<_>>().join(", "),
                        r.role
                    ),
                });
            }
        }
        let index = resolved
            .iter()
            .map(|r| {
                header
                    .iter()
                    .position(|h| h == r.channel.name)
                    .ok_or_else(|| missing_channel(path, r, header.iter().collect::<Vec<_>>().join(", ")))
            })
            .collect::<Result<_, _>>()?;
        Ok(Source::Csv { reader, record: csv::StringRecord::new(), header_len: header.len(), index })
    }

    fn open_mat(path: &Path, resolved: &[Resolved]) -> Result<Self, ImportError> {
        let io = |source| ImportError::Io { path: path.to_path_buf(), source };
        let bytes = std::fs::read(path).map_err(io)?;
        let head = String::from_utf8_lossy(&bytes[..bytes.len().min(116)]).into_owned();
        if head.starts_with("MATLAB 7.3") {
            return Self::open_hdf5(path, resolved, true);
        }
        if let Err(message) = mat_elements_complete(&bytes) {
            return Err(ImportError::Unreadable { path: path.to_path_buf(), message });
        }
        let mat = matfile::MatFile::parse(bytes.as_slice()).map_err(|e| ImportError::Unreadable {
            path: path.to_path_buf(),
            message: format!("not a MATLAB v5 MAT-file, or truncated: {e}"),
        })?;
        let available =
            || mat.arrays().iter().map(|a| format!("{} {:?}", a.name(), a.size())).collect::<Vec<_>>().join(", ");
        let mut columns = Vec::new();
        for r in resolved {
            let (var, col) = channel_column(&r.channel.name);
            let missing = || missing_channel(path, r, available());
            let array = mat.find_by_name(var).ok_or_else(missing)?;
            let col = col.ok_or_else(missing)?;
            let values = real_values(array.data());
            let size = array.size();
            let rows = if size.len() == 2 && (size[0] == 1 || size[1] == 1) { values.len() } else { size[0] };
            if size.len() != 2 || col > values.len() / rows.max(1) {
                return Err(missing());
            }
            // Column-major: column `col` is one contiguous run.
            columns.push(values[(col - 1) * rows..col * rows].iter().map(|v| r.convert(*v)).collect());
        }
        same_lengths(path, resolved, &columns.iter().map(Vec::len).collect::<Vec<_>>())?;
        Ok(Source::Mat { columns })
    }

    /// An HDF5 file, or a MAT-file v7.3 (`matlab`: a variable of MATLAB's N x k is stored as
    /// k x N, so a column is a row of the dataset, and is read whole).
    fn open_hdf5(path: &Path, resolved: &[Resolved], matlab: bool) -> Result<Self, ImportError> {
        let unreadable = |message: String| ImportError::Unreadable { path: path.to_path_buf(), message };
        let bytes_len =
            std::fs::metadata(path).map_err(|source| ImportError::Io { path: path.to_path_buf(), source })?.len();
        let file = hdf5_pure::File::open_streaming(path).map_err(|e| {
            unreadable(format!("not an HDF5 file{}, or truncated: {e}", if matlab { " (MAT v7.3)" } else { "" }))
        })?;
        // The superblock states where the file ends: a file that stops short of it was cut,
        // whatever the reader makes of the rest. (Writers with a user block, as MATLAB's, store
        // it from the file's start; others from the superblock's: the smaller is the test, so
        // a cut within the user block's length of the end may pass.)
        let stated = file.superblock().eof_address;
        let eof = stated.min(hdf5_superblock_at(path)?.saturating_add(stated));
        if eof > bytes_len {
            return Err(unreadable(format!(
                "truncated: the HDF5 superblock says the file ends at byte {eof}, it has {bytes_len}"
            )));
        }
        let available = || hdf5_datasets(&file).join(", ");
        let mut channels = Vec::new();
        let mut columns = Vec::new();
        for r in resolved {
            let (var, col) = channel_column(&r.channel.name);
            let missing = || missing_channel(path, r, available());
            let dataset = file.dataset(var).map_err(|_| missing())?;
            let shape = dataset.shape().map_err(|e| unreadable(format!("dataset {var}: {e}")))?;
            let col = col.ok_or_else(missing)?;
            let read_error = |e: hdf5_pure::Error| unreadable(format!("dataset {var}: {e} (truncated?)"));
            if matlab {
                // MATLAB's N x k is the dataset's k x N: column `col` is row `col - 1`.
                let [k, _] = shape[..] else { return Err(missing()) };
                if col as u64 > k {
                    return Err(missing());
                }
                let values = dataset.read_f64_rows(col as u64 - 1, 1).map_err(read_error)?;
                columns.push(values.into_iter().map(|v| r.convert(v)).collect::<Vec<f64>>());
            } else {
                let width = match shape[..] {
                    [_] => 1,
                    [_, k] => k as usize,
                    _ => return Err(missing()),
                };
                if col > width {
                    return Err(missing());
                }
                channels.push((shape[0] as usize, Hdf5Channel { dataset, width, col: col - 1 }));
            }
        }
        let lengths: Vec<usize> =
            if matlab { columns.iter().map(Vec::len).collect() } else { channels.iter().map(|(n, _)| *n).collect() };
        let len = same_lengths(path, resolved, &lengths)?;
        if matlab {
            return Ok(Source::Mat { columns });
        }
        let channels = channels.into_iter().map(|(_, c)| c).collect();
        Ok(Source::Hdf5 { channels, len, chunk_start: 0, chunk: Vec::new(), bytes_len })
    }

    fn open_tdms(path: &Path, resolved: &[Resolved]) -> Result<Self, ImportError> {
        let unreadable = |message: String| ImportError::Unreadable { path: path.to_path_buf(), message };
        let bytes_len =
            std::fs::metadata(path).map_err(|source| ImportError::Io { path: path.to_path_buf(), source })?.len();
        tdms_segments_complete(path, bytes_len).map_err(unreadable)?;
        let file = tdms_rs::TdmsFile::open(path).map_err(|e| unreadable(format!("not a TDMS file: {e}")))?;
        let available = || {
            file.groups()
                .flat_map(|g| {
                    g.channels().map(move |c| format!("{}/{} [{}]", g.name(), c.name(), c.len())).collect::<Vec<_>>()
                })
                .collect::<Vec<_>>()
                .join(", ")
        };
        let mut names = Vec::new();
        let mut lengths = Vec::new();
        for r in resolved {
            // `group/channel`: the group's name up to the first `/` (a DAQmx channel's own name,
            // `Dev1/ai0`, keeps its `/`).
            let found = r.channel.name.split_once('/').and_then(|(g, c)| {
                file.group(g).and_then(|group| group.channel(c)).map(|ch| ((g.to_string(), c.to_string()), ch.len()))
            });
            let ((g, c), len) = found.ok_or_else(|| missing_channel(path, r, available()))?;
            names.push((g, c));
            lengths.push(len);
        }
        let len = same_lengths(path, resolved, &lengths)?;
        Ok(Source::Tdms { file: Box::new(file), names, len, chunk_start: 0, chunk: Vec::new(), bytes_len })
    }

    /// The `k`-th row's mapped values in canonical units (in the mapping's channel order), or
    /// `None` at the end.
    pub fn next(&mut self, path: &Path, k: u64, resolved: &[Resolved]) -> Result<Option<Vec<f64>>, ImportError> {
        match self {
            Source::Csv { reader, record, header_len, index } => {
                if !reader.read_record(record).map_err(|e| csv_error(path, e))? {
                    return Ok(None);
                }
                // One record per line after the header (the csv crate's own count is one short
                // after a CRLF header, as Python's csv module writes them).
                let at = At::Line(k + 2);
                resolved
                    .iter()
                    .zip(index.iter())
                    .map(|(r, &i)| {
                        let value_error = |message: String| ImportError::Value {
                            path: path.to_path_buf(),
                            at,
                            channel: r.channel.name.clone(),
                            message,
                        };
                        let text = record.get(i).ok_or_else(|| {
                            value_error(format!(
                                "the row has {} values, the header {header_len} (a truncated file?)",
                                record.len()
                            ))
                        })?;
                        let v: f64 = text
                            .parse()
                            .ok()
                            .filter(|v: &f64| v.is_finite())
                            .ok_or_else(|| value_error(format!("`{text}` is not a finite number")))?;
                        Ok(r.convert(v))
                    })
                    .collect::<Result<Vec<f64>, _>>()
                    .map(Some)
            }
            Source::Mat { columns } => {
                let k = k as usize;
                if columns.first().is_none_or(|c| k >= c.len()) {
                    return Ok(None);
                }
                chunk_row(path, k, 0, columns, resolved)
            }
            Source::Tdms { file, names, len, chunk_start, chunk, .. } => {
                let k = k as usize;
                if k >= *len {
                    return Ok(None);
                }
                refill(k, *len, chunk_start, chunk, |range| {
                    names
                        .iter()
                        .zip(resolved)
                        .map(|((g, c), r)| {
                            let channel = file.group(g).and_then(|group| group.channel(c)).ok_or_else(|| {
                                ImportError::Unreadable {
                                    path: path.to_path_buf(),
                                    message: format!("channel {g}/{c} vanished"),
                                }
                            })?;
                            read_tdms(&channel, range.clone())
                                .map(|v| v.into_iter().map(|x| r.convert(x)).collect())
                                .map_err(|message| chunk_error(path, range.start, r, message))
                        })
                        .collect()
                })?;
                chunk_row(path, k, *chunk_start, chunk, resolved)
            }
            Source::Hdf5 { channels, len, chunk_start, chunk, .. } => {
                let k = k as usize;
                if k >= *len {
                    return Ok(None);
                }
                refill(k, *len, chunk_start, chunk, |range| {
                    channels
                        .iter()
                        .zip(resolved)
                        .map(|(c, r)| {
                            let raw = c
                                .dataset
                                .read_f64_rows(range.start as u64, range.len() as u64)
                                .map_err(|e| chunk_error(path, range.start, r, format!("{e} (truncated?)")))?;
                            Ok(raw.iter().skip(c.col).step_by(c.width).map(|v| r.convert(*v)).collect())
                        })
                        .collect()
                })?;
                chunk_row(path, k, *chunk_start, chunk, resolved)
            }
        }
    }

    /// Where row `k` is, for errors.
    pub fn at(&self, k: u64) -> At {
        match self {
            Source::Csv { .. } => At::Line(k + 2),
            Source::Mat { .. } | Source::Tdms { .. } | Source::Hdf5 { .. } => At::Sample(k + 1),
        }
    }

    /// Bytes read so far (a MAT-file is read whole on opening).
    pub fn bytes_read(&self) -> u64 {
        match self {
            Source::Csv { reader, .. } => reader.position().byte(),
            Source::Mat { .. } => 0,
            // The file's share read, as the samples' share.
            Source::Tdms { len, chunk_start, bytes_len, .. } | Source::Hdf5 { len, chunk_start, bytes_len, .. } => {
                (*chunk_start as f64 / (*len).max(1) as f64 * *bytes_len as f64) as u64
            }
        }
    }
}

/// Whether a MAT v5 file holds every data element its tags announce: the parser reads what
/// comes before a cut and ignores the rest, so a truncated file would look like a file with
/// fewer variables. Walks the top-level tags after the 128-byte header (type and byte count,
/// 8-byte aligned but for compressed elements).
fn mat_elements_complete(bytes: &[u8]) -> Result<(), String> {
    if bytes.len() < 128 {
        return Err(format!("{} bytes: shorter than a MAT-file's 128-byte header (truncated?)", bytes.len()));
    }
    let little = match &bytes[126..128] {
        b"IM" => true,
        b"MI" => false,
        _ => return Err("not a MATLAB v5 MAT-file: no endian indicator at bytes 126-127".into()),
    };
    let word = |at: usize| {
        let b: [u8; 4] = bytes[at..at + 4].try_into().unwrap_or([0; 4]);
        if little {
            u32::from_le_bytes(b)
        } else {
            u32::from_be_bytes(b)
        }
    };
    let (mut at, mut element) = (128usize, 0usize);
    while at < bytes.len() {
        if at + 8 > bytes.len() {
            return Err(format!("truncated: data element {element} at byte {at} has no complete tag"));
        }
        let kind = word(at);
        // A small data element packs its size into the type word and its data into the tag.
        let size = if kind >> 16 != 0 { 0 } else { word(at + 4) as usize };
        let padded = if kind == 15 { size } else { size.div_ceil(8) * 8 };
        let next = at + 8 + padded;
        if next > bytes.len() {
            return Err(format!(
                "truncated: data element {element} at byte {at} announces {size} bytes, the file has {} after its tag",
                bytes.len() - at - 8
            ));
        }
        at = next;
        element += 1;
    }
    Ok(())
}

/// Reads the chunk that holds row `k` (of `len`) when the current one does not: `read` gives
/// each mapped channel's values over a range of rows.
fn refill(
    k: usize,
    len: usize,
    chunk_start: &mut usize,
    chunk: &mut Vec<Vec<f64>>,
    read: impl FnOnce(std::ops::Range<usize>) -> Result<Vec<Vec<f64>>, ImportError>,
) -> Result<(), ImportError> {
    if chunk.is_empty() || k < *chunk_start || k >= *chunk_start + chunk[0].len() {
        *chunk = read(k..(k + CHUNK).min(len))?;
        *chunk_start = k;
    }
    Ok(())
}

/// A chunk's read failing, at the chunk's first sample.
fn chunk_error(path: &Path, start: usize, r: &Resolved, message: String) -> ImportError {
    ImportError::Value {
        path: path.to_path_buf(),
        at: At::Sample(start as u64 + 1),
        channel: r.channel.name.clone(),
        message,
    }
}

/// A mapped channel the recording lacks, with what the recording has.
fn missing_channel(path: &Path, r: &Resolved, available: String) -> ImportError {
    ImportError::MissingChannel { path: path.to_path_buf(), role: r.role, name: r.channel.name.clone(), available }
}

/// The mapped channels' common length, refused where they differ (one sample per row).
fn same_lengths(path: &Path, resolved: &[Resolved], lengths: &[usize]) -> Result<usize, ImportError> {
    if lengths.windows(2).any(|w| w[0] != w[1]) {
        return Err(ImportError::Unreadable {
            path: path.to_path_buf(),
            message: format!(
                "the mapped channels differ in length ({}): one sample per row is needed",
                resolved
                    .iter()
                    .zip(lengths)
                    .map(|(r, n)| format!("{} {n}", r.channel.name))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        });
    }
    Ok(lengths.first().copied().unwrap_or(0))
}

/// `name` or `name[col]`: a variable (or dataset) and a 1-based column of a matrix with a row
/// per sample (`None` for a column that is not a positive number).
fn channel_column(name: &str) -> (&str, Option<usize>) {
    match name.strip_suffix(']').and_then(|s| s.split_once('[')) {
        Some((v, c)) => (v, c.trim().parse::<usize>().ok().filter(|c| *c >= 1)),
        None => (name, Some(1)),
    }
}

/// Row `k` of a chunk (or of the whole columns) that starts at `chunk_start`, refused where a
/// value is not finite.
fn chunk_row(
    path: &Path,
    k: usize,
    chunk_start: usize,
    chunk: &[Vec<f64>],
    resolved: &[Resolved],
) -> Result<Option<Vec<f64>>, ImportError> {
    let values: Vec<f64> = chunk.iter().map(|c| c[k - chunk_start]).collect();
    if let Some((r, _)) = resolved.iter().zip(&values).find(|(_, v)| !v.is_finite()) {
        return Err(ImportError::Value {
            path: path.to_path_buf(),
            at: At::Sample(k as u64 + 1),
            channel: r.channel.name.clone(),
            message: "not a finite number (NaN or infinite)".into(),
        });
    }
    Ok(Some(values))
}

/// Where an HDF5 file's superblock starts (0, or past a user block: 512, 1024, ...), the base
/// its addresses count from.
fn hdf5_superblock_at(path: &Path) -> Result<u64, ImportError> {
    use std::io::{Read, Seek, SeekFrom};
    let io = |source| ImportError::Io { path: path.to_path_buf(), source };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let len = file.metadata().map_err(io)?.len();
    let mut at = 0u64;
    while at + 8 <= len {
        let mut signature = [0u8; 8];
        file.seek(SeekFrom::Start(at)).and_then(|_| file.read_exact(&mut signature)).map_err(io)?;
        if &signature == b"\x89HDF\r\n\x1a\n" {
            return Ok(at);
        }
        at = if at == 0 { 512 } else { at * 2 };
    }
    Err(ImportError::Unreadable {
        path: path.to_path_buf(),
        message: "no HDF5 signature at byte 0, 512, 1024, ...".into(),
    })
}

/// The datasets of an HDF5 file with their shapes, three groups deep, for errors.
fn hdf5_datasets(file: &hdf5_pure::File) -> Vec<String> {
    fn walk(group: &hdf5_pure::Group, prefix: &str, depth: usize, out: &mut Vec<String>) {
        for name in group.datasets().unwrap_or_default() {
            let shape = group.dataset(&name).and_then(|d| d.shape()).map(|s| format!("{s:?}")).unwrap_or_default();
            out.push(format!("{prefix}{name} {shape}"));
        }
        if depth < 3 {
            for name in group.groups().unwrap_or_default() {
                if let Ok(g) = group.group(&name) {
                    walk(&g, &format!("{prefix}{name}/"), depth + 1, out);
                }
            }
        }
    }
    let mut out = Vec::new();
    walk(&file.root(), "", 0, &mut out);
    out
}

/// A TDMS channel's samples in `range` as f64, whatever its numeric type.
fn read_tdms(channel: &tdms_rs::TdmsChannel, range: std::ops::Range<usize>) -> Result<Vec<f64>, String> {
    use tdms_rs::DataType as T;
    fn read<P: tdms_rs::api::reader::Pod + Default + Copy>(
        channel: &tdms_rs::TdmsChannel,
        range: std::ops::Range<usize>,
        to_f64: impl Fn(P) -> f64,
    ) -> Result<Vec<f64>, String> {
        let mut buf = vec![P::default(); range.len()];
        channel.read(range, &mut buf).map_err(|e| e.to_string())?;
        Ok(buf.into_iter().map(to_f64).collect())
    }
    match channel.dtype() {
        T::Double => read(channel, range, |v: f64| v),
        T::Float => read(channel, range, |v: f32| f64::from(v)),
        T::I8 => read(channel, range, |v: i8| f64::from(v)),
        T::I16 => read(channel, range, |v: i16| f64::from(v)),
        T::I32 => read(channel, range, |v: i32| f64::from(v)),
        T::I64 => read(channel, range, |v: i64| v as f64),
        T::U8 => read(channel, range, |v: u8| f64::from(v)),
        T::U16 => read(channel, range, |v: u16| f64::from(v)),
        T::U32 => read(channel, range, |v: u32| f64::from(v)),
        T::U64 => read(channel, range, |v: u64| v as f64),
        other => Err(format!("a channel of {other:?} values, not numbers")),
    }
}

/// Whether every segment of a TDMS file is complete: the reader stops quietly at a cut
/// segment, so a truncated file would look like a shorter recording. Walks the segments'
/// lead-ins (`TDSm`, the table of contents, the version, the next segment's offset).
fn tdms_segments_complete(path: &Path, len: u64) -> Result<(), String> {
    use std::io::{Read, Seek, SeekFrom};
    let mut file = std::fs::File::open(path).map_err(|e| e.to_string())?;
    let (mut at, mut segment) = (0u64, 0usize);
    while at < len {
        let mut lead = [0u8; 28];
        if at + 28 > len {
            return Err(format!("truncated: segment {segment} at byte {at} has no complete lead-in"));
        }
        file.seek(SeekFrom::Start(at)).and_then(|_| file.read_exact(&mut lead)).map_err(|e| e.to_string())?;
        if &lead[..4] != b"TDSm" {
            return Err(format!("not a TDMS file: no `TDSm` tag at byte {at} (segment {segment})"));
        }
        let toc = u32::from_le_bytes(lead[4..8].try_into().unwrap_or([0; 4]));
        let word: [u8; 8] = lead[12..20].try_into().unwrap_or([0; 8]);
        let next = if toc & (1 << 6) != 0 { u64::from_be_bytes(word) } else { u64::from_le_bytes(word) };
        let end = at.saturating_add(28).saturating_add(next);
        if next == u64::MAX || end > len {
            return Err(format!(
                "truncated: segment {segment} at byte {at} announces {next} bytes, the file has {} after its lead-in",
                len - at - 28
            ));
        }
        at = end;
        segment += 1;
    }
    Ok(())
}

/// An array's real part as f64.
fn real_values(data: &matfile::NumericData) -> Vec<f64> {
    use matfile::NumericData as D;
    match data {
        D::Int8 { real, .. } => real.iter().map(|v| f64::from(*v)).collect(),
        D::UInt8 { real, .. } => real.iter().map(|v| f64::from(*v)).collect(),
        D::Int16 { real, .. } => real.iter().map(|v| f64::from(*v)).collect(),
        D::UInt16 { real, .. } => real.iter().map(|v| f64::from(*v)).collect(),
        D::Int32 { real, .. } => real.iter().map(|v| f64::from(*v)).collect(),
        D::UInt32 { real, .. } => real.iter().map(|v| f64::from(*v)).collect(),
        D::Int64 { real, .. } => real.iter().map(|v| *v as f64).collect(),
        D::UInt64 { real, .. } => real.iter().map(|v| *v as f64).collect(),
        D::Single { real, .. } => real.iter().map(|v| f64::from(*v)).collect(),
        D::Double { real, .. } => real.clone(),
    }
}

pub(crate) fn csv_error(path: &Path, e: csv::Error) -> ImportError {
    let line = e.position().map_or(0, |p| p.line());
    match e.into_kind() {
        csv::ErrorKind::Io(source) => ImportError::Io { path: path.to_path_buf(), source },
        other => ImportError::Value {
            path: path.to_path_buf(),
            at: At::Line(line),
            channel: "(row)".into(),
            message: format!("{other:?}"),
        },
    }
}
