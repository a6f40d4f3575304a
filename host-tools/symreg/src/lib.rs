//! # sts-symreg
//!
//! Deterministic, parallel symbolic regression in the spirit of PySR/SymbolicRegression.jl
//! and Operon: islands of regularised evolution with migration, a hall of fame per
//! complexity, the complexity-accuracy Pareto front, Levenberg-Marquardt constant
//! optimisation with restarts on every offspring, algebraic simplification and
//! de-duplication, and a model-selection rule that explains its choice.
//!
//! Operators: `+ - * / pow abs sqrt exp log tanh sin`, with the firmware's semantics
//! (`pow(a,b) = |a|^b`, `sqrt(a) = sqrt(|a|)`, `log(a) = ln|a|`; any non-finite value makes a
//! formula invalid). See [`expr`] for printing (SymPy-readable infix) and Rust/C export.
//!
//! ```
//! use sts_symreg::{fit, Matrix, SearchConfig};
//! let rows: Vec<Vec<f64>> = (1..30).map(|i| vec![i as f64 * 0.3, 1.0 + (i % 4) as f64]).collect();
//! let y: Vec<f64> = rows.iter().map(|r| 2.0 * r[0] / r[1]).collect();
//! let x = Matrix::from_rows(&rows).unwrap();
//! let cfg = SearchConfig { seed: 1, max_epochs: 30, ..SearchConfig::default() };
//! let result = fit(&x, &y, &cfg, |_| {}).unwrap();
//! let best = result.best();
//! assert!(best.r2 > 0.999999, "{}", result.explanation);
//! println!("{}", best.expr.to_infix(&["a", "b"]));
//! ```
#![deny(missing_docs)]

pub mod data;
pub mod eval;
pub mod expr;
pub mod fastmath;
mod mutate;
mod optimize;
pub mod planted;
pub mod search;
pub mod select;
pub mod simplify;

pub use data::{Matrix, SymregError};
pub use eval::{Evaluator, Program};
pub use expr::{BinaryOp, Expr, FloatType, PostfixNode, UnaryOp};
pub use search::{fit, FrontMember, OperatorSet, Progress, SearchConfig, SearchResult, StopReason};
pub use select::{select_model, Selection, SelectionConfig};
pub use simplify::simplify;
