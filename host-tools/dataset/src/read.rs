//! Reading a dataset: the manifest (serde_json, validated while parsing so errors carry the
//! position) and the group files (a small hand-written CSV scanner over the file's bytes, with
//! the standard library's correctly rounded float parser; groups are read in parallel and the
//! first error in manifest order is reported, so the result does not depend on scheduling).

use crate::{Column, Dataset, DatasetError, GroupData, GroupInfo, Manifest, FORMAT, MANIFEST_FILE};
use rayon::prelude::*;
use serde::de::{Deserializer, Error as _};
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// Tolerated deviation of a time step from `1 / sample_rate_hz`, as a fraction of it.
const STEP_TOLERANCE: f64 = 0.05;

/// Reads a whole dataset directory: the manifest and every group file.
pub fn read(dir: &Path) -> Result<Dataset, DatasetError> {
    let manifest = read_manifest(dir)?;
    let results: Vec<Result<GroupData, DatasetError>> = manifest
        .groups
        .par_iter()
        .enumerate()
        .map(|(index, info)| read_group(dir, index, info, manifest.sample_rate_hz))
        .collect();
    let mut groups = Vec::with_capacity(results.len());
    for result in results {
        groups.push(result?);
    }
    Ok(Dataset { manifest, groups })
}

fn read_group(dir: &Path, index: usize, info: &GroupInfo, sample_rate_hz: f64) -> Result<GroupData, DatasetError> {
    let path = dir.join(&info.file);
    let bytes = match std::fs::read(&path) {
        Ok(bytes) => bytes,
        Err(err) if err.kind() == std::io::ErrorKind::NotFound => {
            return Err(DatasetError::MissingFile { path, group: index })
        }
        Err(source) => return Err(DatasetError::Io { path, source }),
    };
    let mismatch = |message: String| DatasetError::Mismatch { path: path.clone(), group: index, message };
    let data_rows = || bytes.split(|&b| b == b'\n').skip(1).filter(|l| !l.iter().all(u8::is_ascii_whitespace)).count();
    if let Some(expected) = &info.crc32 {
        let found = group_checksum(&bytes);
        if &found != expected {
            let rows = match info.rows {
                Some(rows) if rows != data_rows() => {
                    format!("{} data rows where the manifest says {rows}, ", data_rows())
                }
                _ => String::new(),
            };
            return Err(mismatch(format!(
                "{rows}CRC-32 {found} where the manifest says {expected} (a file of another run, or cut short; \
                 if it was edited on purpose, remove its `crc32` and `rows` from the manifest)"
            )));
        }
    }
    let group = parse_group_csv(&path, &bytes, sample_rate_hz)?;
    match info.rows {
        Some(rows) if rows != group.len() => {
            Err(mismatch(format!("{} data rows where the manifest says {rows}", group.len())))
        }
        _ => Ok(group),
    }
}

/// The checksum the manifest records of a group file: CRC-32 (IEEE) of its bytes, 8 lower-case
/// hex digits.
pub fn group_checksum(bytes: &[u8]) -> String {
    format!("{:08x}", crc32fast::hash(bytes))
}

/// Reads and validates `DIR/manifest.json`.
pub fn read_manifest(dir: &Path) -> Result<Manifest, DatasetError> {
    let path = dir.join(MANIFEST_FILE);
    let text = match std::fs::read(&path) {
        Ok(bytes) => bytes,
        Err(err) if err.kind() == std::io::ErrorKind::NotFound => {
            return Err(DatasetError::Manifest {
                path,
                line: 0,
                column: 0,
                message: "file not found (a dataset directory holds manifest.json)".into(),
            })
        }
        Err(source) => return Err(DatasetError::Io { path, source }),
    };
    let text = match String::from_utf8(text) {
        Ok(text) => text,
        Err(err) => {
            let at = err.utf8_error().valid_up_to();
            let (line, column) = line_column(err.as_bytes(), at);
            return Err(DatasetError::Manifest { path, line, column, message: "not UTF-8".into() });
        }
    };
    parse_manifest(&path, &text)
}

/// Parses and validates a manifest's text (`path` only names it in errors).
pub(crate) fn parse_manifest(path: &Path, text: &str) -> Result<Manifest, DatasetError> {
    let raw: RawManifest = serde_json::from_str(text).map_err(|err| DatasetError::Manifest {
        path: path.to_path_buf(),
        line: err.line(),
        column: err.column(),
        message: err.to_string().split(" at line ").next().unwrap_or_default().to_string(),
    })?;
    let manifest = Manifest {
        format: raw.format,
        sample_rate_hz: raw.sample_rate_hz,
        description: raw.description,
        acc_mps2_per_lsb: raw.acc_mps2_per_lsb,
        groups: raw
            .groups
            .into_iter()
            .map(|g| GroupInfo {
                file: g.file,
                freq_hz: g.freq_hz,
                amp_um: g.amp_um,
                start_s: g.start_s,
                rows: g.rows,
                crc32: g.crc32,
            })
            .collect(),
    };
    let at = |needle: &str, nth: usize| {
        let offset = text.match_indices(needle).nth(nth).map(|(i, _)| i).unwrap_or(0);
        line_column(text.as_bytes(), offset)
    };
    if manifest.groups.is_empty() {
        let (line, column) = at("\"groups\"", 0);
        return Err(DatasetError::Manifest {
            path: path.to_path_buf(),
            line,
            column,
            message: "`groups` is empty".into(),
        });
    }
    let mut names: Vec<&str> = manifest.groups.iter().map(|g| g.file.as_str()).collect();
    names.sort_unstable();
    if let Some(pair) = names.windows(2).find(|w| w[0] == w[1]) {
        let (line, column) = at(&format!("\"{}\"", pair[0]), 1);
        return Err(DatasetError::Manifest {
            path: path.to_path_buf(),
            line,
            column,
            message: format!("group file `{}` listed twice", pair[0]),
        });
    }
    Ok(manifest)
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawManifest {
    #[serde(deserialize_with = "format_tag")]
    format: String,
    #[serde(deserialize_with = "positive")]
    sample_rate_hz: f64,
    #[serde(default)]
    description: String,
    #[serde(default, deserialize_with = "optional_positive")]
    acc_mps2_per_lsb: Option<f64>,
    groups: Vec<RawGroup>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawGroup {
    #[serde(deserialize_with = "file_name")]
    file: String,
    #[serde(deserialize_with = "positive")]
    freq_hz: f64,
    #[serde(deserialize_with = "non_negative")]
    amp_um: f64,
    #[serde(deserialize_with = "finite")]
    start_s: f64,
    #[serde(default)]
    rows: Option<usize>,
    #[serde(default, deserialize_with = "checksum")]
    crc32: Option<String>,
}

fn checksum<'de, D: Deserializer<'de>>(d: D) -> Result<Option<String>, D::Error> {
    let text = String::deserialize(d)?;
    if text.len() != 8 || !text.bytes().all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b)) {
        return Err(D::Error::custom(format!("`crc32` must be 8 lower-case hex digits, found {text:?}")));
    }
    Ok(Some(text))
}

fn format_tag<'de, D: Deserializer<'de>>(d: D) -> Result<String, D::Error> {
    let tag = String::deserialize(d)?;
    if tag != FORMAT {
        return Err(D::Error::custom(format!("`format` is {tag:?}, this tool reads {FORMAT:?}")));
    }
    Ok(tag)
}

fn finite<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    let v = f64::deserialize(d)?;
    if !v.is_finite() {
        return Err(D::Error::custom("not a finite number"));
    }
    Ok(v)
}

fn positive<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    let v = f64::deserialize(d)?;
    if !(v.is_finite() && v > 0.0) {
        return Err(D::Error::custom(format!("must be a positive number, found {v}")));
    }
    Ok(v)
}

fn non_negative<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    let v = f64::deserialize(d)?;
    if !(v.is_finite() && v >= 0.0) {
        return Err(D::Error::custom(format!("must be zero or positive, found {v}")));
    }
    Ok(v)
}

fn optional_positive<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
    positive(d).map(Some)
}

fn file_name<'de, D: Deserializer<'de>>(d: D) -> Result<String, D::Error> {
    let name = String::deserialize(d)?;
    let plain =
        !name.is_empty() && name != "." && name != ".." && !name.contains(['/', '\\', '\0']) && name != MANIFEST_FILE;
    if !plain {
        return Err(D::Error::custom(format!(
            "group `file` {name:?} must be a plain file name inside the dataset directory"
        )));
    }
    Ok(name)
}

/// 1-based line and column (in characters) of a byte offset.
fn line_column(bytes: &[u8], offset: usize) -> (usize, usize) {
    let offset = offset.min(bytes.len());
    let before = &bytes[..offset];
    let line = 1 + before.iter().filter(|&&b| b == b'\n').count();
    let line_start = before.iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1);
    let column = 1 + String::from_utf8_lossy(&before[line_start..]).chars().count();
    (line, column)
}

/// Parses one group file's bytes (`path` only names it in errors). Checks the header, that
/// every value is a finite number within its column's [`Column::physical_bounds`], and that
/// `t_s` advances by `1 / sample_rate_hz`.
pub fn parse_group_csv(path: &Path, bytes: &[u8], sample_rate_hz: f64) -> Result<GroupData, DatasetError> {
    let path_buf = || PathBuf::from(path);
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF".as_slice()).unwrap_or(bytes);
    let mut lines = LineIter { bytes, pos: 0, number: 0 };
    let Some((header_line, header)) = lines.next() else {
        return Err(DatasetError::BadHeader {
            path: path_buf(),
            line: 1,
            column: 1,
            message: "empty file, expected the header `t_s,z_cmd_um,z_enc_um,z_tcp_um,acc_mps2`".into(),
        });
    };
    let columns = parse_header(path, header_line, header)?;
    let width = columns.len();
    let mut group = GroupData::default();
    let estimate = bytes.len() / (width * 9).max(1);
    let mut storage: Vec<Vec<f64>> = (0..width).map(|_| Vec::with_capacity(estimate)).collect();
    let t_index = columns.iter().position(|c| *c == Column::TS).unwrap_or(0);
    let step_s = 1.0 / sample_rate_hz;
    let mut previous_t: Option<f64> = None;
    let mut rows = 0usize;
    while let Some((line_number, line)) = lines.next() {
        if line.iter().all(|b| b.is_ascii_whitespace()) && lines.rest_is_blank() {
            break;
        }
        let mut field_start = 0usize;
        for (index, column) in columns.iter().enumerate() {
            if field_start > line.len() {
                return Err(DatasetError::MissingValue {
                    path: path_buf(),
                    line: line_number,
                    column: char_column(line, line.len()),
                    field: column.name().into(),
                    found: index,
                    expected: width,
                });
            }
            let rest = &line[field_start..];
            let end = rest.iter().position(|&b| b == b',').unwrap_or(rest.len());
            let field = &rest[..end];
            let value = parse_field(field).map_err(|empty| {
                if empty {
                    DatasetError::MissingValue {
                        path: path_buf(),
                        line: line_number,
                        column: char_column(line, field_start),
                        field: column.name().into(),
                        found: index,
                        expected: width,
                    }
                } else {
                    DatasetError::BadValue {
                        path: path_buf(),
                        line: line_number,
                        column: char_column(line, field_start),
                        field: column.name().into(),
                        text: String::from_utf8_lossy(field).into_owned(),
                    }
                }
            })?;
            let (min, max) = column.physical_bounds();
            if !(min..=max).contains(&value) {
                return Err(DatasetError::OutOfRange {
                    path: path_buf(),
                    line: line_number,
                    column: char_column(line, field_start),
                    field: column.name().into(),
                    value,
                    min,
                    max,
                });
            }
            storage[index].push(value);
            if index == t_index {
                if let Some(prev) = previous_t {
                    let step = value - prev;
                    if (step - step_s).abs() > STEP_TOLERANCE * step_s {
                        return Err(DatasetError::NonUniformStep {
                            path: path_buf(),
                            line: line_number,
                            column: char_column(line, field_start),
                            found_s: step,
                            expected_s: step_s,
                        });
                    }
                }
                previous_t = Some(value);
            }
            field_start += end + 1;
        }
        if field_start <= line.len() {
            return Err(DatasetError::ExtraValue {
                path: path_buf(),
                line: line_number,
                column: char_column(line, field_start),
                expected: width,
            });
        }
        rows += 1;
    }
    if rows < 2 {
        return Err(DatasetError::TooShort { path: path_buf(), rows });
    }
    for (column, values) in columns.iter().zip(storage) {
        *group.column_mut(*column) = values;
    }
    Ok(group)
}

fn parse_header(path: &Path, line_number: usize, header: &[u8]) -> Result<Vec<Column>, DatasetError> {
    let bad = |offset: usize, message: String| DatasetError::BadHeader {
        path: path.to_path_buf(),
        line: line_number,
        column: char_column(header, offset),
        message,
    };
    let mut columns = Vec::new();
    let mut offset = 0usize;
    for raw in header.split(|&b| b == b',') {
        let name = String::from_utf8_lossy(raw);
        let name = name.trim();
        match Column::from_name(name) {
            Some(column) if columns.contains(&column) => {
                return Err(bad(offset, format!("column `{name}` appears twice")));
            }
            Some(column) => columns.push(column),
            None => {
                let known: Vec<&str> = Column::ALL.iter().map(|c| c.name()).collect();
                return Err(bad(offset, format!("unknown column {name:?} (known: {})", known.join(", "))));
            }
        }
        offset += raw.len() + 1;
    }
    if let Some(missing) = crate::REQUIRED_COLUMNS.iter().find(|c| !columns.contains(c)) {
        return Err(bad(
            header.len(),
            format!("required column `{}` missing (required: t_s,z_cmd_um,z_enc_um,z_tcp_um,acc_mps2)", missing.name()),
        ));
    }
    Ok(columns)
}

/// A finite number, or `Err(true)` for an empty field, `Err(false)` for anything else.
fn parse_field(field: &[u8]) -> Result<f64, bool> {
    let text = std::str::from_utf8(field).map_err(|_| false)?.trim();
    if text.is_empty() {
        return Err(true);
    }
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(false),
    }
}

fn char_column(line: &[u8], offset: usize) -> usize {
    let offset = offset.min(line.len());
    if line[..offset].is_ascii() {
        offset + 1
    } else {
        String::from_utf8_lossy(&line[..offset]).chars().count() + 1
    }
}

/// Lines of a byte buffer without their `\n` / `\r\n`, numbered from 1.
struct LineIter<'a> {
    bytes: &'a [u8],
    pos: usize,
    number: usize,
}

impl<'a> LineIter<'a> {
    fn next(&mut self) -> Option<(usize, &'a [u8])> {
        if self.pos >= self.bytes.len() {
            return None;
        }
        let rest = &self.bytes[self.pos..];
        let end = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        self.pos += end + 1;
        self.number += 1;
        let line = &rest[..end];
        Some((self.number, line.strip_suffix(b"\r").unwrap_or(line)))
    }

    fn rest_is_blank(&self) -> bool {
        self.bytes.get(self.pos..).is_none_or(|r| r.iter().all(|b| b.is_ascii_whitespace()))
    }
}
