//! Writing a dataset: fixed decimal places per column ([`Column::write_decimals`]), formatted
//! by integer arithmetic, so the bytes depend only on the values (same data, same files).

use crate::output::{write_file, StagedDir};
use crate::{group_checksum, Column, Dataset, DatasetError, GroupData, GroupInfo, Manifest, MANIFEST_FILE};
use rayon::prelude::*;
use std::path::Path;

/// Writes a whole dataset as the directory `dir`, replacing it as a unit: every group file and
/// the manifest (with each file's row count and checksum) go into a fresh directory beside
/// it, which then takes its place ([`crate::output::StagedDir`]). Checks nothing about what
/// `dir` held: [`crate::output::check_dataset_dir`] does.
pub fn write(dir: &Path, dataset: &Dataset) -> Result<(), DatasetError> {
    if dataset.groups.len() != dataset.manifest.groups.len() {
        return Err(DatasetError::InvalidData {
            path: dir.join(MANIFEST_FILE),
            message: format!(
                "{} groups of data for {} manifest entries",
                dataset.groups.len(),
                dataset.manifest.groups.len()
            ),
        });
    }
    let staged = StagedDir::new(dir)?;
    let mut manifest = dataset.manifest.clone();
    let results: Vec<Result<(), DatasetError>> = manifest
        .groups
        .par_iter_mut()
        .zip(dataset.groups.par_iter())
        .map(|(info, group)| write_group(staged.path(), info, group))
        .collect();
    results.into_iter().collect::<Result<Vec<()>, _>>()?;
    write_manifest(staged.path(), &manifest)?;
    staged.commit()
}

/// Writes `DIR/manifest.json` whole or not at all (after validating it as the reader would).
pub fn write_manifest(dir: &Path, manifest: &Manifest) -> Result<(), DatasetError> {
    let path = dir.join(MANIFEST_FILE);
    let mut text = serde_json::to_string_pretty(manifest)
        .map_err(|e| DatasetError::InvalidData { path: path.clone(), message: e.to_string() })?;
    text.push('\n');
    if let Err(err) = crate::read::parse_manifest(&path, &text) {
        return Err(DatasetError::InvalidData { path, message: err.to_string() });
    }
    std::fs::create_dir_all(dir).map_err(|source| DatasetError::Io { path: dir.to_path_buf(), source })?;
    write_file(&path, text.as_bytes())
}

/// Writes `info.file` in `dir` whole or not at all, and records its row count and checksum in
/// `info` (for the manifest).
pub fn write_group(dir: &Path, info: &mut GroupInfo, group: &GroupData) -> Result<(), DatasetError> {
    let path = dir.join(&info.file);
    let bytes = format_group_csv(group).map_err(|message| DatasetError::InvalidData { path: path.clone(), message })?;
    write_file(&path, &bytes)?;
    info.rows = Some(group.len());
    info.crc32 = Some(group_checksum(&bytes));
    Ok(())
}

/// The CSV bytes of a group: header with the present columns in canonical order, then one row
/// per sample. Errors (as text) on columns of unequal length, non-finite values or values
/// beyond the column's [`Column::physical_bounds`] (the reader would refuse them).
pub fn format_group_csv(group: &GroupData) -> Result<Vec<u8>, String> {
    let columns = group.present_columns();
    let data: Vec<(Column, &[f64])> = columns.iter().filter_map(|c| group.column(*c).map(|v| (*c, v))).collect();
    let len = group.len();
    for (column, values) in &data {
        if values.len() != len {
            return Err(format!("column `{}` has {} samples, `t_s` has {len}", column.name(), values.len()));
        }
        if let Some(row) = values.iter().position(|v| !v.is_finite()) {
            return Err(format!("column `{}` sample {row} is not finite", column.name()));
        }
        let (min, max) = column.physical_bounds();
        if let Some(row) = values.iter().position(|v| !(min..=max).contains(v)) {
            return Err(format!(
                "column `{}` sample {row}: {:e} is beyond what the sensor can produce ({min:e} to {max:e})",
                column.name(),
                values[row]
            ));
        }
    }
    let names: Vec<&str> = columns.iter().map(|c| c.name()).collect();
    let mut out = Vec::with_capacity(64 + len * columns.len() * 11);
    out.extend_from_slice(names.join(",").as_bytes());
    out.push(b'\n');
    for row in 0..len {
        for (i, (column, values)) in data.iter().enumerate() {
            if i > 0 {
                out.push(b',');
            }
            write_fixed(&mut out, values[row], column.write_decimals());
        }
        out.push(b'\n');
    }
    Ok(out)
}

const POW10: [f64; 10] = [1.0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9];

/// Appends `value` with exactly `decimals` decimal places (at most 9); never `-0`.
fn write_fixed(out: &mut Vec<u8>, value: f64, decimals: usize) {
    let decimals = decimals.min(9);
    let scaled = (value * POW10[decimals]).round();
    if scaled.abs() >= 9.0e18 {
        out.extend_from_slice(format!("{value:.decimals$}").as_bytes());
        return;
    }
    let scaled = scaled as i64;
    if scaled < 0 {
        out.push(b'-');
    }
    let magnitude = scaled.unsigned_abs();
    let divisor = POW10[decimals] as u64;
    let whole = magnitude / divisor;
    let frac = magnitude % divisor;
    let mut digits = [0u8; 20];
    let mut n = 0;
    let mut w = whole;
    loop {
        digits[n] = b'0' + (w % 10) as u8;
        n += 1;
        w /= 10;
        if w == 0 {
            break;
        }
    }
    out.extend(digits[..n].iter().rev());
    if decimals > 0 {
        out.push(b'.');
        let mut f = frac;
        for d in (0..decimals).rev() {
            digits[d] = b'0' + (f % 10) as u8;
            f /= 10;
        }
        out.extend_from_slice(&digits[..decimals]);
    }
}

#[cfg(test)]
mod tests {
    use super::write_fixed;

    fn fixed(v: f64, d: usize) -> String {
        let mut out = Vec::new();
        write_fixed(&mut out, v, d);
        String::from_utf8(out).unwrap()
    }

    #[test]
    fn fixed_formatting_matches_std() {
        for &v in &[0.0, -0.0, 1.5, -1.25, 0.000125, 5.999875, -123.456789, 1e-9, -1e-9, 42.0] {
            for d in [0, 3, 5, 7] {
                let expected = format!("{:.*}", d, v);
                let expected = if expected.trim_start_matches('-').chars().all(|c| c == '0' || c == '.') {
                    expected.trim_start_matches('-').to_string()
                } else {
                    expected
                };
                assert_eq!(fixed(v, d), expected, "{v} with {d} decimals");
            }
        }
    }
}
