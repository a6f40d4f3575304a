//! Any numeric CSV table as a regression problem's input (`sts-twin regress`): the header
//! names the columns, every other row is numbers. Errors name the file, the line and the
//! column.

use std::path::{Path, PathBuf};

/// A table read from CSV: column names and row-major values.
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    /// Header names, in file order.
    pub columns: Vec<String>,
    /// Rows of values, each as long as `columns`.
    pub rows: Vec<Vec<f64>>,
}

/// Why a table could not be read. Every variant names the file and, where there is one, the
/// line and the column.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TableError {
    /// The file cannot be opened.
    #[error("cannot open {}", path.display())]
    Open {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: csv::Error,
    },
    /// The header row cannot be read.
    #[error("{}:1: cannot read the header row", path.display())]
    Header {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: csv::Error,
    },
    /// The header row has no names.
    #[error("{}:1: the header row is empty", path.display())]
    EmptyHeader {
        /// The file.
        path: PathBuf,
    },
    /// A column has no name.
    #[error("{}:1: column {column} has an empty name", path.display())]
    EmptyName {
        /// The file.
        path: PathBuf,
        /// 1-based column.
        column: usize,
    },
    /// Two columns have the same name.
    #[error("{}:1: column name `{name}` appears twice", path.display())]
    DuplicateName {
        /// The file.
        path: PathBuf,
        /// The name.
        name: String,
    },
    /// A row has another number of fields than the header.
    #[error("{}:{line}: {len} fields, expected {expected} (columns: {})", path.display(), columns.join(", "))]
    FieldCount {
        /// The file.
        path: PathBuf,
        /// 1-based line.
        line: u64,
        /// Fields on the line.
        len: u64,
        /// Fields in the header.
        expected: u64,
        /// The header's names.
        columns: Vec<String>,
    },
    /// A field is not UTF-8.
    #[error("{}:{line}: column {column}: not valid UTF-8", path.display())]
    Utf8 {
        /// The file.
        path: PathBuf,
        /// 1-based line.
        line: u64,
        /// 1-based column.
        column: usize,
    },
    /// A field is not a number (or not a finite one).
    #[error("{}:{line}: column {column} (`{name}`): `{field}` is not a {expected}", path.display())]
    NotANumber {
        /// The file.
        path: PathBuf,
        /// 1-based line.
        line: u64,
        /// 1-based column.
        column: usize,
        /// The column's name.
        name: String,
        /// The field as written.
        field: String,
        /// What it should be: "number", or "finite number" for an infinity or NaN.
        expected: &'static str,
    },
    /// Another read error of the CSV reader.
    #[error("{}: {source}", path.display())]
    Csv {
        /// The file.
        path: PathBuf,
        /// Why.
        source: csv::Error,
    },
    /// Only a header.
    #[error("{}: no data rows after the header", path.display())]
    NoRows {
        /// The file.
        path: PathBuf,
    },
}

/// Reads a numeric CSV table (fields trimmed; a header row of unique, non-empty names).
pub fn read_table(path: &Path) -> Result<Table, TableError> {
    let owned = || path.to_path_buf();
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(true)
        .trim(csv::Trim::All)
        .from_path(path)
        .map_err(|source| TableError::Open { path: owned(), source })?;
    let columns: Vec<String> = reader
        .headers()
        .map_err(|source| TableError::Header { path: owned(), source })?
        .iter()
        .map(str::to_string)
        .collect();
    if columns.is_empty() || columns.iter().all(String::is_empty) {
        return Err(TableError::EmptyHeader { path: owned() });
    }
    for (i, name) in columns.iter().enumerate() {
        if name.is_empty() {
            return Err(TableError::EmptyName { path: owned(), column: i + 1 });
        }
        if columns[..i].contains(name) {
            return Err(TableError::DuplicateName { path: owned(), name: name.clone() });
        }
    }
    let mut rows = Vec::new();
    for record in reader.records() {
        let record = record.map_err(|e| csv_error(path, &columns, e))?;
        let line = record.position().map_or(0, |p| p.line());
        let mut row = Vec::with_capacity(columns.len());
        for (i, field) in record.iter().enumerate() {
            let bad = |expected: &'static str| TableError::NotANumber {
                path: owned(),
                line,
                column: i + 1,
                name: columns[i].clone(),
                field: field.to_string(),
                expected,
            };
            let value: f64 = field.parse().map_err(|_| bad("number"))?;
            if !value.is_finite() {
                return Err(bad("finite number"));
            }
            row.push(value);
        }
        rows.push(row);
    }
    if rows.is_empty() {
        return Err(TableError::NoRows { path: owned() });
    }
    Ok(Table { columns, rows })
}

fn csv_error(path: &Path, columns: &[String], e: csv::Error) -> TableError {
    let path = path.to_path_buf();
    match e.kind() {
        csv::ErrorKind::UnequalLengths { pos, expected_len, len } => TableError::FieldCount {
            path,
            line: pos.as_ref().map_or(0, |p| p.line()),
            len: *len,
            expected: *expected_len,
            columns: columns.to_vec(),
        },
        csv::ErrorKind::Utf8 { pos, err } => {
            TableError::Utf8 { path, line: pos.as_ref().map_or(0, |p| p.line()), column: err.field() + 1 }
        }
        _ => TableError::Csv { path, source: e },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_csv(name: &str, text: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("sts-symreg-table-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let path = dir.join(name);
        std::fs::write(&path, text).expect("temp file");
        path
    }

    #[test]
    fn reads_names_and_rows() {
        let table = read_table(&temp_csv("ok.csv", "a, y\n1,2\n 2 ,3.5\n")).expect("a table");
        assert_eq!(table.columns, ["a", "y"]);
        assert_eq!(table.rows, [vec![1.0, 2.0], vec![2.0, 3.5]]);
    }

    #[test]
    fn bad_input_names_file_line_and_column() {
        let err = read_table(&temp_csv("bad.csv", "a,b,y\n1,2,3\n4,oops,6\n")).unwrap_err().to_string();
        assert!(err.ends_with("bad.csv:3: column 2 (`b`): `oops` is not a number"), "{err}");
        let err = read_table(&temp_csv("nan.csv", "a,y\n1,2\n2,NaN\n")).unwrap_err().to_string();
        assert!(err.ends_with("nan.csv:3: column 2 (`y`): `NaN` is not a finite number"), "{err}");
        let err = read_table(&temp_csv("short.csv", "a,b,y\n1,2,3\n4,5\n")).unwrap_err().to_string();
        assert!(err.ends_with("short.csv:3: 2 fields, expected 3 (columns: a, b, y)"), "{err}");
        let err = read_table(&temp_csv("twice.csv", "a,a\n1,2\n")).unwrap_err().to_string();
        assert!(err.ends_with("twice.csv:1: column name `a` appears twice"), "{err}");
        let err = read_table(&temp_csv("empty.csv", "a,y\n")).unwrap_err().to_string();
        assert!(err.ends_with("empty.csv: no data rows after the header"), "{err}");
        let err = read_table(Path::new("/nonexistent/dir/x.csv")).unwrap_err().to_string();
        assert_eq!(err, "cannot open /nonexistent/dir/x.csv");
    }
}
