#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

pub mod data;
pub mod eval;
pub mod expr;
pub mod fastmath;
mod mutate;
mod operators;
mod optimize;
pub mod planted;
pub mod search;
pub mod select;
pub mod simplify;
pub mod table;

pub use data::{Matrix, SymregError};
pub use eval::{Evaluator, Program};
pub use expr::{BinaryOp, Expr, FloatType, PostfixNode, UnaryOp};
pub use operators::OperatorSet;
pub use search::{fit, FrontMember, Progress, SearchConfig, SearchResult, StopFlag, StopReason};
pub use select::{select_model, Selection, SelectionConfig};
pub use simplify::simplify;
