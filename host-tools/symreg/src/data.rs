//! Input data: a row-major matrix of features and the errors for bad input.

/// Errors for input the engine cannot search on.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SymregError {
    /// The row-major data length is not `n_rows * n_cols`.
    #[error("matrix data has {len} values, expected {n_rows} rows x {n_cols} columns")]
    Shape {
        /// Rows requested.
        n_rows: usize,
        /// Columns requested.
        n_cols: usize,
        /// Values given.
        len: usize,
    },
    /// A row has a different length from the first.
    #[error("row {row} has {len} values, expected {expected}")]
    RaggedRow {
        /// 0-based row index.
        row: usize,
        /// Its length.
        len: usize,
        /// The first row's length.
        expected: usize,
    },
    /// `x` and `y` disagree on the number of rows.
    #[error("x has {x_rows} rows but y has {y_len} values")]
    RowCount {
        /// Rows of `x`.
        x_rows: usize,
        /// Length of `y`.
        y_len: usize,
    },
    /// Too few rows to fit anything.
    #[error("need at least {min} rows, got {got}")]
    TooFewRows {
        /// Minimum.
        min: usize,
        /// Given.
        got: usize,
    },
    /// A feature value is NaN or infinite.
    #[error("feature value at row {row}, column {col} is not finite ({value})")]
    NonFiniteX {
        /// 0-based row.
        row: usize,
        /// 0-based column.
        col: usize,
        /// The value.
        value: f64,
    },
    /// A target value is NaN or infinite.
    #[error("target value at row {row} is not finite ({value})")]
    NonFiniteY {
        /// 0-based row.
        row: usize,
        /// The value.
        value: f64,
    },
    /// The target does not vary, so there is nothing to explain.
    #[error("the target is constant ({value}); nothing to regress")]
    ConstantTarget {
        /// Its value.
        value: f64,
    },
    /// The search was stopped through [`crate::search::StopFlag`] before it finished.
    #[error("stopped before the search finished")]
    Stopped,
    /// The configuration cannot work.
    #[error("invalid search configuration: {0}")]
    Config(String),
    /// An operator name is unknown.
    #[error("unknown operator `{0}` (known: + - * / abs pow sqrt exp log tanh sin)")]
    UnknownOperator(String),
}

/// A dense row-major matrix of `f64` (rows are samples, columns are features).
///
/// ```
/// use sts_symreg::Matrix;
/// let m = Matrix::from_rows(&[vec![1.0, 2.0], vec![3.0, 4.0]]).unwrap();
/// assert_eq!(m.get(1, 0), 3.0);
/// assert_eq!(m.column(1), vec![2.0, 4.0]);
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct Matrix {
    n_rows: usize,
    n_cols: usize,
    data: Vec<f64>,
}

impl Matrix {
    /// From row-major data of `n_rows * n_cols` values.
    pub fn from_row_major(n_rows: usize, n_cols: usize, data: Vec<f64>) -> Result<Self, SymregError> {
        if data.len() != n_rows * n_cols {
            return Err(SymregError::Shape { n_rows, n_cols, len: data.len() });
        }
        Ok(Self { n_rows, n_cols, data })
    }

    /// From a list of equally long rows.
    pub fn from_rows(rows: &[Vec<f64>]) -> Result<Self, SymregError> {
        let n_cols = rows.first().map_or(0, Vec::len);
        let mut data = Vec::with_capacity(rows.len() * n_cols);
        for (row, r) in rows.iter().enumerate() {
            if r.len() != n_cols {
                return Err(SymregError::RaggedRow { row, len: r.len(), expected: n_cols });
            }
            data.extend_from_slice(r);
        }
        Ok(Self { n_rows: rows.len(), n_cols, data })
    }

    /// From equally long columns.
    pub fn from_columns(columns: &[Vec<f64>]) -> Result<Self, SymregError> {
        let n_rows = columns.first().map_or(0, Vec::len);
        for (col, c) in columns.iter().enumerate() {
            if c.len() != n_rows {
                return Err(SymregError::RaggedRow { row: col, len: c.len(), expected: n_rows });
            }
        }
        let n_cols = columns.len();
        let mut data = Vec::with_capacity(n_rows * n_cols);
        for r in 0..n_rows {
            for c in columns {
                data.push(c[r]);
            }
        }
        Ok(Self { n_rows, n_cols, data })
    }

    /// Number of rows (samples).
    pub fn n_rows(&self) -> usize {
        self.n_rows
    }

    /// Number of columns (features).
    pub fn n_cols(&self) -> usize {
        self.n_cols
    }

    /// The value at `(row, col)`.
    pub fn get(&self, row: usize, col: usize) -> f64 {
        self.data[row * self.n_cols + col]
    }

    /// Row `r` as a slice.
    pub fn row(&self, r: usize) -> &[f64] {
        &self.data[r * self.n_cols..(r + 1) * self.n_cols]
    }

    /// Column `c` as a new vector.
    pub fn column(&self, c: usize) -> Vec<f64> {
        (0..self.n_rows).map(|r| self.get(r, c)).collect()
    }

    /// All columns (column-major copy), the layout the evaluator runs on.
    pub fn columns(&self) -> Vec<Vec<f64>> {
        (0..self.n_cols).map(|c| self.column(c)).collect()
    }

    /// The row-major values.
    pub fn as_slice(&self) -> &[f64] {
        &self.data
    }
}
