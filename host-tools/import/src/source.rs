//! A recording's mapped channels, row by row, in canonical units: CSV or TSV read record by
//! record (any length in bounded memory), or a MATLAB v5 MAT-file's variables (the `matfile`
//! crate; the format compresses each variable as one stream, so the mapped variables are held
//! whole).

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
}

/// The extensions read.
pub const READ: &str = "CSV and TSV (.csv, .tsv, .txt), MATLAB v5 and v7 (.mat)";

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
        let index = resolved
            .iter()
            .map(|r| {
                header.iter().position(|h| h == r.channel.name).ok_or_else(|| ImportError::MissingChannel {
                    path: path.to_path_buf(),
                    role: r.role,
                    name: r.channel.name.clone(),
                    available: header.iter().collect::<Vec<_>>().join(", "),
                })
            })
            .collect::<Result<_, _>>()?;
        Ok(Source::Csv { reader, record: csv::StringRecord::new(), header_len: header.len(), index })
    }

    fn open_mat(path: &Path, resolved: &[Resolved]) -> Result<Self, ImportError> {
        let io = |source| ImportError::Io { path: path.to_path_buf(), source };
        let bytes = std::fs::read(path).map_err(io)?;
        let head = String::from_utf8_lossy(&bytes[..bytes.len().min(116)]).into_owned();
        if head.starts_with("MATLAB 7.3") {
            return Err(ImportError::Unreadable {
                path: path.to_path_buf(),
                message:
                    "a MAT-file v7.3 (HDF5 inside) is not read yet: save it with `save(..., '-v7')` or export it to CSV"
                        .into(),
            });
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
            // `name` or `name[col]`, a 1-based column of a matrix with a row per sample.
            let (var, col) = match r.channel.name.strip_suffix(']').and_then(|s| s.split_once('[')) {
                Some((v, c)) => (v, c.trim().parse::<usize>().ok().filter(|c| *c >= 1)),
                None => (r.channel.name.as_str(), Some(1)),
            };
            let missing = || ImportError::MissingChannel {
                path: path.to_path_buf(),
                role: r.role,
                name: r.channel.name.clone(),
                available: available(),
            };
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
        let lengths: Vec<usize> = columns.iter().map(Vec::len).collect();
        if lengths.windows(2).any(|w| w[0] != w[1]) {
            return Err(ImportError::Unreadable {
                path: path.to_path_buf(),
                message: format!(
                    "the mapped variables differ in length ({}): one sample per row is needed",
                    resolved
                        .iter()
                        .zip(&lengths)
                        .map(|(r, n)| format!("{} {n}", r.channel.name))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            });
        }
        Ok(Source::Mat { columns })
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
                let values: Vec<f64> = columns.iter().map(|c| c[k]).collect();
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
        }
    }

    /// Where row `k` is, for errors.
    pub fn at(&self, k: u64) -> At {
        match self {
            Source::Csv { .. } => At::Line(k + 2),
            Source::Mat { .. } => At::Sample(k + 1),
        }
    }

    /// Bytes read so far (CSV; a MAT-file is read whole on opening).
    pub fn bytes_read(&self) -> u64 {
        match self {
            Source::Csv { reader, .. } => reader.position().byte(),
            Source::Mat { .. } => 0,
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
