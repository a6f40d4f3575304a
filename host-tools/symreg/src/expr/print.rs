//! An expression's text: infix for people and SymPy, LaTeX, and source code in Rust, C and
//! MATLAB, each with the firmware's operator semantics spelled out.

use std::fmt::Write as _;

use super::{BinaryOp, Expr, FloatType, UnaryOp};

impl Expr {
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
