//! Expression trees: structure, operator semantics, evaluation, printing and source export.
//!
//! The operator semantics are fixed by the firmware, which evaluates the same formulas in
//! `f32`: `div(a,b) = a/b`, `pow(a,b) = |a|^b`, `sqrt(a) = sqrt(|a|)`, `log(a) = ln|a|`;
//! `exp`, `tanh`, `sin` and `abs` as usual. Any non-finite value anywhere in the evaluation
//! makes the whole evaluation invalid.

use serde::{Deserialize, Serialize};
use std::cmp::Ordering;
use std::fmt::Write as _;

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

    /// Plain infix with the given variable names (`x{i}` for any index past the end of
    /// `var_names`), `**` for powers, and the firmware's semantics spelled out so that
    /// SymPy's `parse_expr` reads the same function: `pow(a,b)` prints as `abs(a)**b`,
    /// `sqrt(a)` as `sqrt(abs(a))` and `log(a)` as `log(abs(a))`. Constants print with
    /// enough digits to round-trip exactly.
    ///
    /// ```
    /// use sts_symreg::{Expr, BinaryOp, UnaryOp};
    /// let e = Expr::binary(
    ///     BinaryOp::Pow,
    ///     Expr::binary(BinaryOp::Div, Expr::Var(0), Expr::Var(1)),
    ///     Expr::Const(-0.5),
    /// );
    /// assert_eq!(e.to_infix(&["a", "b"]), "abs(a/b)**(-0.5)");
    /// let l = Expr::unary(UnaryOp::Log, Expr::Var(0));
    /// assert_eq!(l.to_infix(&["a"]), "log(abs(a))");
    /// ```
    pub fn to_infix<S: AsRef<str>>(&self, var_names: &[S]) -> String {
        self.to_infix_with(var_names, None)
    }

    /// Like [`Expr::to_infix`], with constants rounded to `digits` significant digits
    /// (for display; the result no longer reproduces the loss exactly).
    pub fn to_infix_rounded<S: AsRef<str>>(&self, var_names: &[S], digits: usize) -> String {
        self.to_infix_with(var_names, Some(digits))
    }

    fn to_infix_with<S: AsRef<str>>(&self, var_names: &[S], digits: Option<usize>) -> String {
        let mut s = String::new();
        let style = Style { lang: Lang::Python, digits };
        self.write_infix(&mut s, var_names, &style, 0);
        s
    }

    /// Rust source of a function `pub fn NAME(x: &[T]) -> T` (T = `f32` or `f64`) computing
    /// this expression with the firmware's semantics; `var_names` become comments.
    ///
    /// ```
    /// use sts_symreg::{Expr, BinaryOp, FloatType};
    /// let e = Expr::binary(BinaryOp::Pow, Expr::Var(0), Expr::Const(2.0));
    /// let src = e.to_rust("model", &["speed"], FloatType::F64);
    /// assert!(src.contains("x[0].abs().powf(2.0_f64)"));
    /// ```
    pub fn to_rust<S: AsRef<str>>(&self, fn_name: &str, var_names: &[S], float: FloatType) -> String {
        let ty = match float {
            FloatType::F32 => "f32",
            FloatType::F64 => "f64",
        };
        let style = Style { lang: Lang::Rust(float), digits: None };
        let mut body = String::new();
        let index_names: Vec<String> = (0..self.n_vars_used()).map(|i| format!("x[{i}]")).collect();
        self.write_infix(&mut body, &index_names, &style, 0);
        let mut src = String::new();
        let _ = writeln!(src, "/// {}", self.to_infix(var_names));
        let _ = writeln!(src, "///");
        let _ = writeln!(src, "/// Inputs:");
        for i in 0..self.n_vars_used() {
            let _ = writeln!(src, "/// - `x[{i}]`: {}", var_name(var_names, i));
        }
        let _ = writeln!(src, "pub fn {fn_name}(x: &[{ty}]) -> {ty} {{");
        let _ = writeln!(src, "    {body}");
        let _ = writeln!(src, "}}");
        src
    }

    /// C source of a function `T NAME(const T *x)` (T = `float` or `double`) computing this
    /// expression with the firmware's semantics; needs `<math.h>` (included at the top).
    pub fn to_c<S: AsRef<str>>(&self, fn_name: &str, var_names: &[S], float: FloatType) -> String {
        let ty = match float {
            FloatType::F32 => "float",
            FloatType::F64 => "double",
        };
        let style = Style { lang: Lang::C(float), digits: None };
        let mut body = String::new();
        let index_names: Vec<String> = (0..self.n_vars_used()).map(|i| format!("x[{i}]")).collect();
        self.write_infix(&mut body, &index_names, &style, 0);
        let mut src = String::new();
        let _ = writeln!(src, "#include <math.h>");
        let _ = writeln!(src);
        let _ = writeln!(src, "/* {} */", self.to_infix(var_names).replace("*/", "* /"));
        let _ = writeln!(src, "/* Inputs: */");
        for i in 0..self.n_vars_used() {
            let _ = writeln!(src, "/*   x[{i}]: {} */", var_name(var_names, i).replace("*/", "* /"));
        }
        let _ = writeln!(src, "{ty} {fn_name}(const {ty} *x)");
        let _ = writeln!(src, "{{");
        let _ = writeln!(src, "    return {body};");
        let _ = writeln!(src, "}}");
        src
    }

    /// The expression alone in C (T = `float` or `double`, `<math.h>` functions) with the
    /// firmware's semantics, the variables named by `var_names` (e.g. `f[0]`).
    ///
    /// ```
    /// use sts_symreg::{Expr, UnaryOp, FloatType};
    /// let e = Expr::unary(UnaryOp::Log, Expr::Var(0));
    /// assert_eq!(e.to_c_expr(&["f[0]"], FloatType::F32), "logf(fabsf(f[0]))");
    /// ```
    pub fn to_c_expr<S: AsRef<str>>(&self, var_names: &[S], float: FloatType) -> String {
        let mut body = String::new();
        self.write_infix(&mut body, var_names, &Style { lang: Lang::C(float), digits: None }, 0);
        body
    }

    /// The expression alone in MATLAB (scalar double, usable in a Simulink MATLAB Function
    /// block) with the firmware's semantics: `pow(a,b)` as `power(abs(a), b)`, `sqrt(a)` as
    /// `sqrt(abs(a))`, `log(a)` as `log(abs(a))`.
    ///
    /// ```
    /// use sts_symreg::{Expr, BinaryOp};
    /// let e = Expr::binary(BinaryOp::Pow, Expr::Var(0), Expr::Const(0.5));
    /// assert_eq!(e.to_matlab(&["f(1)"]), "power(abs(f(1)), 0.5)");
    /// ```
    pub fn to_matlab<S: AsRef<str>>(&self, var_names: &[S]) -> String {
        let mut body = String::new();
        self.write_infix(&mut body, var_names, &Style { lang: Lang::Matlab, digits: None }, 0);
        body
    }

    /// LaTeX math of the expression, constants to `digits` significant digits (for a paper;
    /// [`Expr::to_infix`] keeps every digit), the firmware's semantics written out
    /// (`|a|^{b}`, `\sqrt{|a|}`, `\ln|a|`).
    ///
    /// ```
    /// use sts_symreg::{Expr, BinaryOp, UnaryOp};
    /// let e = Expr::binary(BinaryOp::Div, Expr::unary(UnaryOp::Tanh, Expr::Var(0)), Expr::Const(1.23456));
    /// assert_eq!(e.to_latex(&["f_{1}"], 3), "\\frac{\\tanh\\left(f_{1}\\right)}{1.23}");
    /// ```
    pub fn to_latex<S: AsRef<str>>(&self, var_names: &[S], digits: usize) -> String {
        let mut s = String::new();
        self.write_latex(&mut s, var_names, digits, 0);
        s
    }

    /// `parent` is the binding of the surrounding context: 0 anywhere, 1 as the right
    /// operand of `-`, 2 as a factor, 3 as a power's base.
    fn write_latex<S: AsRef<str>>(&self, s: &mut String, names: &[S], digits: usize, parent: u8) {
        let sub = |e: &Expr, p: u8| {
            let mut t = String::new();
            e.write_latex(&mut t, names, digits, p);
            t
        };
        match self {
            Expr::Const(c) => {
                let text = latex_const(*c, digits);
                if *c < 0.0 && parent > 0 {
                    let _ = write!(s, "\\left({text}\\right)");
                } else {
                    s.push_str(&text);
                }
            }
            Expr::Var(i) => s.push_str(&var_name(names, *i)),
            Expr::Unary(op, a) => {
                let inner = sub(a, 0);
                let _ = match op {
                    UnaryOp::Abs => write!(s, "\\left|{inner}\\right|"),
                    UnaryOp::Sqrt => write!(s, "\\sqrt{{\\left|{inner}\\right|}}"),
                    UnaryOp::Exp => write!(s, "e^{{{inner}}}"),
                    UnaryOp::Log => write!(s, "\\ln\\left|{inner}\\right|"),
                    UnaryOp::Tanh => write!(s, "\\tanh\\left({inner}\\right)"),
                    UnaryOp::Sin => write!(s, "\\sin\\left({inner}\\right)"),
                };
            }
            Expr::Binary(op, a, b) => {
                let (text, binding) = match op {
                    BinaryOp::Add => (format!("{} + {}", sub(a, 0), sub(b, 0)), 1),
                    BinaryOp::Sub => (format!("{} - {}", sub(a, 0), sub(b, 1)), 1),
                    BinaryOp::Mul => (format!("{} \\cdot {}", sub(a, 2), sub(b, 2)), 2),
                    BinaryOp::Div => (format!("\\frac{{{}}}{{{}}}", sub(a, 0), sub(b, 0)), 9),
                    BinaryOp::Pow => (format!("\\left|{}\\right|^{{{}}}", sub(a, 0), sub(b, 0)), 9),
                };
                // A sum or difference inside a product or after a minus is parenthesised.
                if binding == 1 && parent >= 1 || binding == 2 && parent >= 3 {
                    let _ = write!(s, "\\left({text}\\right)");
                } else {
                    s.push_str(&text);
                }
            }
        }
    }

    /// Precedence of the top node when printed infix (higher binds tighter).
    fn precedence(&self, lang: Lang) -> u8 {
        match self {
            // Negative constants print parenthesised, so every leaf is atomic.
            Expr::Const(_) | Expr::Var(_) | Expr::Unary(..) => 9,
            Expr::Binary(op, ..) => match (op, lang) {
                (BinaryOp::Add | BinaryOp::Sub, _) => 1,
                (BinaryOp::Mul | BinaryOp::Div, _) => 2,
                (BinaryOp::Pow, Lang::Python) => 3,
                // pow is a function call / method in C and Rust.
                (BinaryOp::Pow, _) => 9,
            },
        }
    }

    fn write_infix<S: AsRef<str>>(&self, s: &mut String, names: &[S], style: &Style, parent_prec: u8) {
        match self {
            Expr::Const(c) => {
                let text = format_const(*c, style);
                if *c < 0.0 || c.to_bits() >> 63 == 1 {
                    // Negative constants are always parenthesised: safe under ** and after -.
                    let _ = write!(s, "({text})");
                } else {
                    s.push_str(&text);
                }
            }
            Expr::Var(i) => s.push_str(&var_name(names, *i)),
            Expr::Unary(op, a) => {
                let mut inner = String::new();
                a.write_infix(&mut inner, names, style, 0);
                let _ = match style.lang {
                    // MATLAB's names for these are Python's.
                    Lang::Python | Lang::Matlab => match op {
                        UnaryOp::Abs => write!(s, "abs({inner})"),
                        UnaryOp::Sqrt => write!(s, "sqrt(abs({inner}))"),
                        UnaryOp::Exp => write!(s, "exp({inner})"),
                        UnaryOp::Log => write!(s, "log(abs({inner}))"),
                        UnaryOp::Tanh => write!(s, "tanh({inner})"),
                        UnaryOp::Sin => write!(s, "sin({inner})"),
                    },
                    Lang::Rust(_) => {
                        let inner = rust_receiver(a, inner);
                        match op {
                            UnaryOp::Abs => write!(s, "{inner}.abs()"),
                            UnaryOp::Sqrt => write!(s, "{inner}.abs().sqrt()"),
                            UnaryOp::Exp => write!(s, "{inner}.exp()"),
                            UnaryOp::Log => write!(s, "{inner}.abs().ln()"),
                            UnaryOp::Tanh => write!(s, "{inner}.tanh()"),
                            UnaryOp::Sin => write!(s, "{inner}.sin()"),
                        }
                    }
                    Lang::C(float) => {
                        let f = if float == FloatType::F32 { "f" } else { "" };
                        match op {
                            UnaryOp::Abs => write!(s, "fabs{f}({inner})"),
                            UnaryOp::Sqrt => write!(s, "sqrt{f}(fabs{f}({inner}))"),
                            UnaryOp::Exp => write!(s, "exp{f}({inner})"),
                            UnaryOp::Log => write!(s, "log{f}(fabs{f}({inner}))"),
                            UnaryOp::Tanh => write!(s, "tanh{f}({inner})"),
                            UnaryOp::Sin => write!(s, "sin{f}({inner})"),
                        }
                    }
                };
                // Rust method calls on a bare leaf like `x[0]` need no extra parentheses, but
                // keeping them is harmless and simple.
                let _ = parent_prec;
            }
            Expr::Binary(op, a, b) => {
                let my = self.precedence(style.lang);
                if *op == BinaryOp::Pow {
                    let mut base = String::new();
                    let mut expo = String::new();
                    a.write_infix(&mut base, names, style, 0);
                    match style.lang {
                        Lang::Python => {
                            // `**` binds tighter than everything but calls and atoms.
                            b.write_infix(&mut expo, names, style, 0);
                            let expo = if b.precedence(style.lang) >= 9 { expo } else { format!("({expo})") };
                            let text = format!("abs({base})**{expo}");
                            if my < parent_prec {
                                let _ = write!(s, "({text})");
                            } else {
                                s.push_str(&text);
                            }
                        }
                        Lang::Rust(_) => {
                            b.write_infix(&mut expo, names, style, 0);
                            let base = rust_receiver(a, base);
                            let _ = write!(s, "{base}.abs().powf({expo})");
                        }
                        Lang::C(float) => {
                            b.write_infix(&mut expo, names, style, 0);
                            let f = if float == FloatType::F32 { "f" } else { "" };
                            let _ = write!(s, "pow{f}(fabs{f}({base}), {expo})");
                        }
                        Lang::Matlab => {
                            b.write_infix(&mut expo, names, style, 0);
                            let _ = write!(s, "power(abs({base}), {expo})");
                        }
                    }
                    return;
                }
                let sym = match op {
                    BinaryOp::Add => "+",
                    BinaryOp::Sub => "-",
                    BinaryOp::Mul => "*",
                    BinaryOp::Div => "/",
                    BinaryOp::Pow => unreachable!("handled above"),
                };
                // Operands parenthesise themselves when they bind looser than this node. The
                // right operand of - and / also at equal precedence (a-(b-c), a/(b*c)); in
                // Rust and C always at equal precedence, to keep the evaluation order.
                let right_prec = b.precedence(style.lang);
                let right_parent = if right_prec == my
                    && (matches!(op, BinaryOp::Sub | BinaryOp::Div) || style.lang != Lang::Python)
                {
                    my + 1
                } else {
                    my
                };
                let open = my < parent_prec;
                if open {
                    s.push('(');
                }
                a.write_infix(s, names, style, my);
                s.push_str(sym);
                b.write_infix(s, names, style, right_parent);
                if open {
                    s.push(')');
                }
            }
        }
    }
}

impl std::fmt::Display for Expr {
    /// Infix with variables named `x0, x1, ...`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let names: [&str; 0] = [];
        f.write_str(&self.to_infix(&names))
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Lang {
    Python,
    Rust(FloatType),
    C(FloatType),
    /// MATLAB (and Simulink's MATLAB Function block): scalar double arithmetic.
    Matlab,
}

struct Style {
    lang: Lang,
    digits: Option<usize>,
}

/// Parenthesises a method-call receiver unless it is atomic (a leaf, a call or a method chain).
fn rust_receiver(e: &Expr, text: String) -> String {
    match e {
        Expr::Binary(op, ..) if *op != BinaryOp::Pow => format!("({text})"),
        _ => text,
    }
}

fn var_name<S: AsRef<str>>(names: &[S], i: usize) -> String {
    names.get(i).map(|n| n.as_ref().to_string()).unwrap_or_else(|| format!("x{i}"))
}

/// Formats a constant: shortest round-trip decimal, always with a decimal point or exponent
/// so that C and Rust read it as a float.
fn format_const(c: f64, style: &Style) -> String {
    let c = match (style.lang, style.digits) {
        (Lang::Python, Some(d)) if c != 0.0 => {
            let text = format!("{:.*e}", d.saturating_sub(1), c);
            text.parse::<f64>().unwrap_or(c)
        }
        _ => c,
    };
    match style.lang {
        Lang::Rust(FloatType::F32) => {
            let v = c as f32;
            let mut t = format!("{v:?}");
            if !t.contains('.') && !t.contains('e') {
                t.push_str(".0");
            }
            format!("{t}_f32")
        }
        Lang::Rust(FloatType::F64) => format!("{}_f64", float_text(c)),
        Lang::C(FloatType::F32) => {
            let v = c as f32;
            let mut t = format!("{v:?}");
            if !t.contains('.') && !t.contains('e') {
                t.push_str(".0");
            }
            format!("{t}f")
        }
        Lang::C(FloatType::F64) | Lang::Python | Lang::Matlab => float_text(c),
    }
}

/// A constant for LaTeX: `digits` significant digits, powers of ten as `\times 10^{n}`.
fn latex_const(c: f64, digits: usize) -> String {
    if c == 0.0 || !c.is_finite() {
        return format!("{c}");
    }
    let exponent = c.abs().log10().floor() as i32;
    if (-3..=4).contains(&exponent) {
        let decimals = (digits as i32 - 1 - exponent).max(0) as usize;
        let text = format!("{c:.decimals$}");
        // Trailing zeros after the point say nothing.
        if text.contains('.') {
            text.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            text
        }
    } else {
        let mantissa = c / 10f64.powi(exponent);
        format!("{} \\times 10^{{{exponent}}}", latex_const(mantissa, digits))
    }
}

fn float_text(c: f64) -> String {
    let mut t = format!("{c:?}");
    if !t.contains('.') && !t.contains('e') && !t.contains("inf") && !t.contains("NaN") {
        t.push_str(".0");
    }
    t
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
