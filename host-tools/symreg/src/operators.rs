//! The operators a search may use, parsed from the names people write.

use serde::{Deserialize, Serialize};

use crate::data::SymregError;
use crate::expr::{BinaryOp, UnaryOp};

/// The operators the search may use.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct OperatorSet {
    /// Unary operators.
    pub unary: Vec<UnaryOp>,
    /// Binary operators.
    pub binary: Vec<BinaryOp>,
}

impl OperatorSet {
    /// All operators: `+ - * / pow abs sqrt exp log tanh sin`.
    pub fn all() -> OperatorSet {
        OperatorSet { unary: UnaryOp::ALL.to_vec(), binary: BinaryOp::ALL.to_vec() }
    }

    /// Parses a comma- or space-separated list such as `"+,-,*,/,pow,tanh"`.
    ///
    /// ```
    /// use sts_symreg::OperatorSet;
    /// let ops = OperatorSet::parse("+, -, *, tanh").unwrap();
    /// assert_eq!(ops.binary.len(), 3);
    /// assert!(OperatorSet::parse("+,cosh").is_err());
    /// ```
    pub fn parse(list: &str) -> Result<OperatorSet, SymregError> {
        let mut set = OperatorSet { unary: Vec::new(), binary: Vec::new() };
        for name in list.split([',', ' ']).map(str::trim).filter(|s| !s.is_empty()) {
            if let Some(op) = UnaryOp::ALL.iter().find(|o| o.name() == name) {
                if !set.unary.contains(op) {
                    set.unary.push(*op);
                }
            } else if let Some(op) =
                BinaryOp::ALL.iter().find(|o| o.name() == name || (name == "**" && **o == BinaryOp::Pow))
            {
                if !set.binary.contains(op) {
                    set.binary.push(*op);
                }
            } else {
                return Err(SymregError::UnknownOperator(name.to_string()));
            }
        }
        Ok(set)
    }

    /// The names, comma-separated (the inverse of [`OperatorSet::parse`]).
    pub fn names(&self) -> String {
        let mut v: Vec<&str> = self.binary.iter().map(|o| o.name()).collect();
        v.extend(self.unary.iter().map(|o| o.name()));
        v.join(",")
    }
}
