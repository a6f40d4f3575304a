//! Expression trees: structure, operator semantics and evaluation; their text in every
//! language the twin is exported to is [`print`]'s.
//!
//! The operator semantics are fixed by the firmware, which evaluates the same formulas in
//! `f32`: `div(a,b) = a/b`, `pow(a,b) = |a|^b`, `sqrt(a) = sqrt(|a|)`, `log(a) = ln|a|`;
//! `exp`, `tanh`, `sin` and `abs` as usual. Any non-finite value anywhere in the evaluation
//! makes the whole evaluation invalid.

use serde::{Deserialize, Serialize};
use std::cmp::Ordering;

mod print;

/// A one-argument operator.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum UnaryOp {
    /// `|a|`.
    Abs,
    /// `sqrt(|a|)`.
    Sqrt,
    /// `e^a`.
    Exp,
    /// `ln|a|`.
    Log,
    /// `tanh(a)`.
    Tanh,
    /// `sin(a)` (radians).
    Sin,
}

/// A two-argument operator.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BinaryOp {
    /// `a + b`.
    Add,
    /// `a - b`.
    Sub,
    /// `a * b`.
    Mul,
    /// `a / b`.
    Div,
    /// `|a|^b`.
    Pow,
}

impl UnaryOp {
    /// Every unary operator, in a fixed order.
    pub const ALL: [UnaryOp; 6] =
        [UnaryOp::Abs, UnaryOp::Sqrt, UnaryOp::Exp, UnaryOp::Log, UnaryOp::Tanh, UnaryOp::Sin];

    /// Applies the operator with the firmware's semantics. `exp`, `log` and `tanh` are the
    /// engine's own ([`crate::fastmath`], within 5.5e-16 of the exact value).
    #[inline]
    pub fn apply(self, a: f64) -> f64 {
        match self {
            UnaryOp::Abs => a.abs(),
            UnaryOp::Sqrt => a.abs().sqrt(),
            UnaryOp::Exp => crate::fastmath::exp(a),
            UnaryOp::Log => crate::fastmath::ln(a),
            UnaryOp::Tanh => crate::fastmath::tanh(a),
            UnaryOp::Sin => a.sin(),
        }
    }

    /// The operator's name as accepted by [`crate::OperatorSet::parse`].
    pub fn name(self) -> &'static str {
        match self {
            UnaryOp::Abs => "abs",
            UnaryOp::Sqrt => "sqrt",
            UnaryOp::Exp => "exp",
            UnaryOp::Log => "log",
            UnaryOp::Tanh => "tanh",
            UnaryOp::Sin => "sin",
        }
    }
}

impl BinaryOp {
    /// Every binary operator, in a fixed order.
    pub const ALL: [BinaryOp; 5] = [BinaryOp::Add, BinaryOp::Sub, BinaryOp::Mul, BinaryOp::Div, BinaryOp::Pow];

    /// Applies the operator with the firmware's semantics. `pow` is the engine's own
    /// ([`crate::fastmath::pow_abs`]).
    #[inline]
    pub fn apply(self, a: f64, b: f64) -> f64 {
        match self {
            BinaryOp::Add => a + b,
            BinaryOp::Sub => a - b,
            BinaryOp::Mul => a * b,
            BinaryOp::Div => a / b,
            BinaryOp::Pow => crate::fastmath::pow_abs(a, b),
        }
    }

    /// The operator's name as accepted by [`crate::OperatorSet::parse`].
    pub fn name(self) -> &'static str {
        match self {
            BinaryOp::Add => "+",
            BinaryOp::Sub => "-",
            BinaryOp::Mul => "*",
            BinaryOp::Div => "/",
            BinaryOp::Pow => "pow",
        }
    }

    /// Whether `a op b == b op a` exactly (also in floating point).
    pub fn is_commutative(self) -> bool {
        matches!(self, BinaryOp::Add | BinaryOp::Mul)
    }
}

/// An expression tree over the input variables `x0, x1, ...`.
///
/// ```
/// use sts_symreg::{Expr, BinaryOp};
/// // 2.5 * x0
/// let e = Expr::binary(BinaryOp::Mul, Expr::Const(2.5), Expr::Var(0));
/// assert_eq!(e.eval_row(&[2.0]), 5.0);
/// assert_eq!(e.to_infix(&["speed"]), "2.5*speed");
/// assert_eq!(e.complexity(), 3);
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Expr {
    /// A constant.
    Const(f64),
    /// Input variable number `i` (column `i` of the data).
    Var(usize),
    /// A unary operator applied to a subexpression.
    Unary(UnaryOp, Box<Expr>),
    /// A binary operator applied to two subexpressions (left, right).
    Binary(BinaryOp, Box<Expr>, Box<Expr>),
}

/// One node of an expression in postfix (reverse Polish) order, as a stack machine runs it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum PostfixNode {
    /// Push a constant.
    Const(f64),
    /// Push input variable `i`.
    Var(usize),
    /// Pop one value, push the operator's result.
    Unary(UnaryOp),
    /// Pop `b` then `a`, push `a op b`.
    Binary(BinaryOp),
}

/// The floating-point type of exported source code.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FloatType {
    /// 32-bit floats (`f32` / `float`), as the firmware evaluates.
    F32,
    /// 64-bit floats (`f64` / `double`), as the search evaluates.
    F64,
}

impl Expr {
    /// Builds a unary node.
    pub fn unary(op: UnaryOp, a: Expr) -> Expr {
        Expr::Unary(op, Box::new(a))
    }

    /// Builds a binary node.
    pub fn binary(op: BinaryOp, a: Expr, b: Expr) -> Expr {
        Expr::Binary(op, Box::new(a), Box::new(b))
    }

    /// Complexity: the number of nodes (constants, variables and operators each count 1).
    pub fn complexity(&self) -> usize {
        match self {
            Expr::Const(_) | Expr::Var(_) => 1,
            Expr::Unary(_, a) => 1 + a.complexity(),
            Expr::Binary(_, a, b) => 1 + a.complexity() + b.complexity(),
        }
    }

    /// Depth: 1 for a leaf.
    pub fn depth(&self) -> usize {
        match self {
            Expr::Const(_) | Expr::Var(_) => 1,
            Expr::Unary(_, a) => 1 + a.depth(),
            Expr::Binary(_, a, b) => 1 + a.depth().max(b.depth()),
        }
    }

    /// The nodes in postfix order (children before their operator, left before right).
    ///
    /// ```
    /// use sts_symreg::{Expr, BinaryOp, PostfixNode};
    /// let e = Expr::binary(BinaryOp::Sub, Expr::Var(0), Expr::Const(1.0));
    /// assert_eq!(
    ///     e.postfix(),
    ///     vec![PostfixNode::Var(0), PostfixNode::Const(1.0), PostfixNode::Binary(BinaryOp::Sub)]
    /// );
    /// ```
    pub fn postfix(&self) -> Vec<PostfixNode> {
        let mut out = Vec::with_capacity(self.complexity());
        self.push_postfix(&mut out);
        out
    }

    fn push_postfix(&self, out: &mut Vec<PostfixNode>) {
        match self {
            Expr::Const(c) => out.push(PostfixNode::Const(*c)),
            Expr::Var(i) => out.push(PostfixNode::Var(*i)),
            Expr::Unary(op, a) => {
                a.push_postfix(out);
                out.push(PostfixNode::Unary(*op));
            }
            Expr::Binary(op, a, b) => {
                a.push_postfix(out);
                b.push_postfix(out);
                out.push(PostfixNode::Binary(*op));
            }
        }
    }

    /// Rebuilds an expression from postfix nodes; `None` if they do not form exactly one tree.
    pub fn from_postfix(nodes: &[PostfixNode]) -> Option<Expr> {
        let mut stack: Vec<Expr> = Vec::new();
        for node in nodes {
            match *node {
                PostfixNode::Const(c) => stack.push(Expr::Const(c)),
                PostfixNode::Var(i) => stack.push(Expr::Var(i)),
                PostfixNode::Unary(op) => {
                    let a = stack.pop()?;
                    stack.push(Expr::unary(op, a));
                }
                PostfixNode::Binary(op) => {
                    let b = stack.pop()?;
                    let a = stack.pop()?;
                    stack.push(Expr::binary(op, a, b));
                }
            }
        }
        if stack.len() == 1 {
            stack.pop()
        } else {
            None
        }
    }

    /// Evaluates on one row of inputs (`x[i]` is variable `i`). Returns NaN when any
    /// intermediate value is non-finite, so that such a formula never passes as valid.
    pub fn eval_row(&self, x: &[f64]) -> f64 {
        let v = match self {
            Expr::Const(c) => *c,
            Expr::Var(i) => x[*i],
            Expr::Unary(op, a) => op.apply(a.eval_row(x)),
            Expr::Binary(op, a, b) => op.apply(a.eval_row(x), b.eval_row(x)),
        };
        if v.is_finite() {
            v
        } else {
            f64::NAN
        }
    }

    /// The largest variable index used plus one (0 if none).
    pub fn n_vars_used(&self) -> usize {
        match self {
            Expr::Const(_) => 0,
            Expr::Var(i) => i + 1,
            Expr::Unary(_, a) => a.n_vars_used(),
            Expr::Binary(_, a, b) => a.n_vars_used().max(b.n_vars_used()),
        }
    }

    /// Whether the expression uses variable `i`.
    pub fn uses_var(&self, i: usize) -> bool {
        match self {
            Expr::Const(_) => false,
            Expr::Var(j) => *j == i,
            Expr::Unary(_, a) => a.uses_var(i),
            Expr::Binary(_, a, b) => a.uses_var(i) || b.uses_var(i),
        }
    }

    /// The constants in postfix order.
    pub fn constants(&self) -> Vec<f64> {
        self.postfix()
            .into_iter()
            .filter_map(|n| match n {
                PostfixNode::Const(c) => Some(c),
                _ => None,
            })
            .collect()
    }

    /// Replaces the constants, in postfix order; extra values are ignored.
    pub fn set_constants(&mut self, values: &[f64]) {
        let mut it = values.iter();
        self.set_constants_inner(&mut it);
    }

    fn set_constants_inner(&mut self, it: &mut std::slice::Iter<'_, f64>) {
        match self {
            Expr::Const(c) => {
                if let Some(v) = it.next() {
                    *c = *v;
                }
            }
            Expr::Var(_) => {}
            Expr::Unary(_, a) => a.set_constants_inner(it),
            Expr::Binary(_, a, b) => {
                a.set_constants_inner(it);
                b.set_constants_inner(it);
            }
        }
    }

    /// The number of constants.
    pub fn n_constants(&self) -> usize {
        match self {
            Expr::Const(_) => 1,
            Expr::Var(_) => 0,
            Expr::Unary(_, a) => a.n_constants(),
            Expr::Binary(_, a, b) => a.n_constants() + b.n_constants(),
        }
    }

    /// A total order on structure and constants, used to put commutative operands in a
    /// canonical order and to break ties deterministically.
    pub fn structural_cmp(&self, other: &Expr) -> Ordering {
        fn rank(e: &Expr) -> u8 {
            match e {
                Expr::Const(_) => 0,
                Expr::Var(_) => 1,
                Expr::Unary(..) => 2,
                Expr::Binary(..) => 3,
            }
        }
        match (self, other) {
            (Expr::Const(a), Expr::Const(b)) => a.total_cmp(b),
            (Expr::Var(a), Expr::Var(b)) => a.cmp(b),
            (Expr::Unary(o1, a1), Expr::Unary(o2, a2)) => o1.cmp(o2).then_with(|| a1.structural_cmp(a2)),
            (Expr::Binary(o1, a1, b1), Expr::Binary(o2, a2, b2)) => {
                o1.cmp(o2).then_with(|| a1.structural_cmp(a2)).then_with(|| b1.structural_cmp(b2))
            }
            _ => rank(self).cmp(&rank(other)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(v: f64) -> Expr {
        Expr::Const(v)
    }
    fn x(i: usize) -> Expr {
        Expr::Var(i)
    }
    fn b(op: BinaryOp, l: Expr, r: Expr) -> Expr {
        Expr::binary(op, l, r)
    }

    #[test]
    fn infix_parenthesises_only_where_needed() {
        use BinaryOp::*;
        let e = b(Sub, x(0), b(Sub, x(1), x(2)));
        assert_eq!(e.to_string(), "x0-(x1-x2)");
        let e = b(Mul, b(Add, x(0), x(1)), x(2));
        assert_eq!(e.to_string(), "(x0+x1)*x2");
        let e = b(Div, x(0), b(Mul, x(1), x(2)));
        assert_eq!(e.to_string(), "x0/(x1*x2)");
        let e = b(Add, c(-1.5), x(0));
        assert_eq!(e.to_string(), "(-1.5)+x0");
        let e = b(Mul, c(2.5), b(Pow, b(Div, x(1), x(2)), c(0.78)));
        assert_eq!(e.to_string(), "2.5*abs(x1/x2)**0.78");
        let e = b(Pow, b(Pow, x(0), c(2.0)), x(1));
        assert_eq!(e.to_string(), "abs(abs(x0)**2.0)**x1");
    }

    #[test]
    fn postfix_round_trips() {
        use BinaryOp::*;
        let e = b(Sub, c(1.95), b(Mul, c(1.23), Expr::unary(UnaryOp::Tanh, b(Add, x(0), c(1.08)))));
        assert_eq!(Expr::from_postfix(&e.postfix()), Some(e.clone()));
        assert_eq!(e.complexity(), e.postfix().len());
        assert_eq!(Expr::from_postfix(&[PostfixNode::Binary(Add)]), None);
    }

    #[test]
    fn semantics_follow_the_firmware() {
        assert_eq!(BinaryOp::Pow.apply(-4.0, 0.5), 2.0);
        assert_eq!(UnaryOp::Sqrt.apply(-9.0), 3.0);
        assert_eq!(UnaryOp::Log.apply(-1.0), 0.0);
        assert!(Expr::unary(UnaryOp::Log, c(0.0)).eval_row(&[]).is_nan());
    }

    #[test]
    fn constants_set_in_postfix_order() {
        use BinaryOp::*;
        let mut e = b(Add, b(Mul, c(1.0), x(0)), c(2.0));
        assert_eq!(e.constants(), vec![1.0, 2.0]);
        e.set_constants(&[3.0, 4.0]);
        assert_eq!(e.to_string(), "3.0*x0+4.0");
    }
}
