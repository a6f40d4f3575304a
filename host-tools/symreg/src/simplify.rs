//! Algebraic simplification into a canonical form, so that equivalent expressions look alike
//! (which de-duplication relies on) and no node is wasted.
//!
//! Every rule keeps the value (up to floating-point rounding) on every input where the
//! original is valid, and never increases the complexity.

use crate::expr::{BinaryOp, Expr, UnaryOp};

/// Simplifies bottom-up until nothing changes (bounded number of passes).
///
/// ```
/// use sts_symreg::{simplify, Expr, BinaryOp};
/// // (x0 * 2) * 3  ->  6*x0
/// let e = Expr::binary(
///     BinaryOp::Mul,
///     Expr::binary(BinaryOp::Mul, Expr::Var(0), Expr::Const(2.0)),
///     Expr::Const(3.0),
/// );
/// assert_eq!(simplify(&e).to_string(), "6.0*x0");
/// ```
pub fn simplify(expr: &Expr) -> Expr {
    // Each pass builds its result from a borrowed tree: one new tree a pass, where cloning the
    // tree to compare against would take a second (symbolic regression simplifies every child).
    let mut e = pass(expr);
    if e == *expr {
        return e;
    }
    for _ in 1..8 {
        let next = pass(&e);
        if next == e {
            break;
        }
        e = next;
    }
    e
}

fn c(v: f64) -> Expr {
    Expr::Const(v)
}

fn is_const(e: &Expr, v: f64) -> bool {
    matches!(e, Expr::Const(x) if *x == v)
}

fn const_of(e: &Expr) -> Option<f64> {
    match e {
        Expr::Const(x) => Some(*x),
        _ => None,
    }
}

/// Whether `e` is non-negative for every input (used to drop redundant `abs`).
fn non_negative(e: &Expr) -> bool {
    match e {
        Expr::Const(x) => *x >= 0.0,
        Expr::Var(_) => false,
        Expr::Unary(op, _) => matches!(op, UnaryOp::Abs | UnaryOp::Sqrt | UnaryOp::Exp),
        Expr::Binary(BinaryOp::Pow, ..) => true,
        Expr::Binary(BinaryOp::Mul | BinaryOp::Div, a, b) => non_negative(a) && non_negative(b),
        Expr::Binary(BinaryOp::Add, a, b) => non_negative(a) && non_negative(b),
        Expr::Binary(BinaryOp::Sub, ..) => false,
    }
}

fn pass(e: &Expr) -> Expr {
    match e {
        Expr::Const(_) | Expr::Var(_) => e.clone(),
        Expr::Unary(op, a) => unary(*op, pass(a)),
        Expr::Binary(op, a, b) => binary(*op, pass(a), pass(b)),
    }
}

fn unary(op: UnaryOp, a: Expr) -> Expr {
    if let Expr::Const(x) = a {
        let v = op.apply(x);
        if v.is_finite() {
            return c(v);
        }
        return Expr::unary(op, a);
    }
    match (op, a) {
        // abs of something already non-negative.
        (UnaryOp::Abs, a) if non_negative(&a) => a,
        // sqrt, log and pow already take |a|.
        (UnaryOp::Sqrt | UnaryOp::Log | UnaryOp::Abs, Expr::Unary(UnaryOp::Abs, inner)) => Expr::unary(op, *inner),
        // log(exp(a)) = a; exp(log(a)) = |a| (both valid wherever the original is).
        (UnaryOp::Log, Expr::Unary(UnaryOp::Exp, inner)) => *inner,
        (UnaryOp::Exp, Expr::Unary(UnaryOp::Log, inner)) => unary(UnaryOp::Abs, *inner),
        (op, a) => Expr::unary(op, a),
    }
}

fn binary(op: BinaryOp, a: Expr, b: Expr) -> Expr {
    use BinaryOp::*;
    if let (Expr::Const(x), Expr::Const(y)) = (&a, &b) {
        let v = op.apply(*x, *y);
        if v.is_finite() {
            return c(v);
        }
        return Expr::binary(op, a, b);
    }
    match op {
        Add => add(a, b),
        Sub => sub(a, b),
        Mul => mul(a, b),
        Div => div(a, b),
        Pow => pow(a, b),
    }
}

fn add(a: Expr, b: Expr) -> Expr {
    use BinaryOp::*;
    if is_const(&a, 0.0) {
        return b;
    }
    if is_const(&b, 0.0) {
        return a;
    }
    // Constants to the left.
    if const_of(&b).is_some() && const_of(&a).is_none() {
        return add(b, a);
    }
    match (a, b) {
        // c1 + (c2 + f) -> (c1+c2) + f ; c1 + (c2 - f) -> (c1+c2) - f ; c1 + (f - c2) handled by sub.
        (Expr::Const(c1), Expr::Binary(Add, inner_a, inner_b)) if const_of(&inner_a).is_some() => {
            let c2 = const_of(&inner_a).unwrap_or(0.0);
            add(c(c1 + c2), *inner_b)
        }
        (Expr::Const(c1), Expr::Binary(Sub, inner_a, inner_b)) if const_of(&inner_a).is_some() => {
            let c2 = const_of(&inner_a).unwrap_or(0.0);
            sub(c(c1 + c2), *inner_b)
        }
        // c1 + c2*(c3 + f) -> (c1 + c2*c3) + c2*f
        (Expr::Const(c1), Expr::Binary(Mul, ca, inner))
            if const_of(&ca).is_some() && matches!(&*inner, Expr::Binary(Add, cb, _) if const_of(cb).is_some()) =>
        {
            let c2 = const_of(&ca).unwrap_or(1.0);
            let Expr::Binary(_, cb, f) = *inner else { unreachable!("matched above") };
            let c3 = const_of(&cb).unwrap_or(0.0);
            add(c(c1 + c2 * c3), mul(c(c2), *f))
        }
        // (c + f) + g -> c + (f + g) ; f + (c + g) -> c + (f + g): constants bubble up.
        (Expr::Binary(Add, ca, f), g) if const_of(&ca).is_some() && const_of(&g).is_none() => add(*ca, add(*f, g)),
        (f, Expr::Binary(Add, ca, g)) if const_of(&ca).is_some() && const_of(&f).is_none() => add(*ca, add(f, *g)),
        (a, b) => {
            if a == b {
                // f + f -> 2*f
                return mul(c(2.0), a);
            }
            if const_of(&a).is_none() && a.structural_cmp(&b) == std::cmp::Ordering::Greater {
                Expr::binary(Add, b, a)
            } else {
                Expr::binary(Add, a, b)
            }
        }
    }
}

fn sub(a: Expr, b: Expr) -> Expr {
    use BinaryOp::*;
    if is_const(&b, 0.0) {
        return a;
    }
    if a == b {
        return c(0.0);
    }
    match (a, b) {
        // f - c -> (-c) + f
        (f, Expr::Const(c2)) => add(c(-c2), f),
        // c1 - (c2 + f) -> (c1-c2) - f
        (Expr::Const(c1), Expr::Binary(Add, ca, f)) if const_of(&ca).is_some() => {
            let c2 = const_of(&ca).unwrap_or(0.0);
            sub(c(c1 - c2), *f)
        }
        // c1 - (c2 - f) -> (c1-c2) + f
        (Expr::Const(c1), Expr::Binary(Sub, ca, f)) if const_of(&ca).is_some() => {
            let c2 = const_of(&ca).unwrap_or(0.0);
            add(c(c1 - c2), *f)
        }
        // (c + f) - g -> c + (f - g)
        (Expr::Binary(Add, ca, f), g) if const_of(&ca).is_some() && const_of(&g).is_none() => add(*ca, sub(*f, g)),
        // f - (c + g) -> (-c) + (f - g)
        (f, Expr::Binary(Add, ca, g)) if const_of(&ca).is_some() && const_of(&f).is_none() => {
            let c2 = const_of(&ca).unwrap_or(0.0);
            add(c(-c2), sub(f, *g))
        }
        // f - c*g -> f + (-c)*g : keeps scaled terms in one canonical (additive) shape.
        (f, Expr::Binary(Mul, cb, g)) if const_of(&cb).is_some() => {
            let c2 = const_of(&cb).unwrap_or(0.0);
            add(f, mul(c(-c2), *g))
        }
        (a, b) => Expr::binary(Sub, a, b),
    }
}

fn mul(a: Expr, b: Expr) -> Expr {
    use BinaryOp::*;
    if is_const(&a, 1.0) {
        return b;
    }
    if is_const(&b, 1.0) {
        return a;
    }
    if is_const(&a, 0.0) || is_const(&b, 0.0) {
        return c(0.0);
    }
    if const_of(&b).is_some() && const_of(&a).is_none() {
        return mul(b, a);
    }
    match (a, b) {
        // c1 * (c2 * f) -> (c1c2) * f ; c1 * (c2 / f) -> (c1c2) / f
        (Expr::Const(c1), Expr::Binary(Mul, ca, f)) if const_of(&ca).is_some() => {
            let c2 = const_of(&ca).unwrap_or(1.0);
            mul(c(c1 * c2), *f)
        }
        (Expr::Const(c1), Expr::Binary(Div, ca, f)) if const_of(&ca).is_some() => {
            let c2 = const_of(&ca).unwrap_or(1.0);
            div(c(c1 * c2), *f)
        }
        // (c*f)*g -> c*(f*g) ; f*(c*g) -> c*(f*g)
        (Expr::Binary(Mul, ca, f), g) if const_of(&ca).is_some() && const_of(&g).is_none() => mul(*ca, mul(*f, g)),
        (f, Expr::Binary(Mul, ca, g)) if const_of(&ca).is_some() && const_of(&f).is_none() => mul(*ca, mul(f, *g)),
        (a, b) => {
            if const_of(&a).is_none() && a.structural_cmp(&b) == std::cmp::Ordering::Greater {
                Expr::binary(Mul, b, a)
            } else {
                Expr::binary(Mul, a, b)
            }
        }
    }
}

fn div(a: Expr, b: Expr) -> Expr {
    use BinaryOp::*;
    if is_const(&b, 1.0) {
        return a;
    }
    if is_const(&a, 0.0) {
        return c(0.0);
    }
    if a == b {
        return c(1.0);
    }
    match (a, b) {
        // f / c -> (1/c) * f
        (f, Expr::Const(c2)) => {
            let inv = 1.0 / c2;
            if inv.is_finite() {
                mul(c(inv), f)
            } else {
                Expr::binary(Div, f, c(c2))
            }
        }
        // (c*f) / g -> c * (f/g)
        (Expr::Binary(Mul, ca, f), g) if const_of(&ca).is_some() => mul(*ca, div(*f, g)),
        // c1 / (c2*f) -> (c1/c2) / f
        (Expr::Const(c1), Expr::Binary(Mul, ca, f)) if const_of(&ca).is_some() => {
            let c2 = const_of(&ca).unwrap_or(1.0);
            let q = c1 / c2;
            if q.is_finite() {
                div(c(q), *f)
            } else {
                Expr::binary(Div, c(c1), Expr::binary(Mul, c(c2), *f))
            }
        }
        // f / (c*g) -> (1/c) * (f/g)
        (f, Expr::Binary(Mul, ca, g)) if const_of(&ca).is_some() => {
            let c2 = const_of(&ca).unwrap_or(1.0);
            let inv = 1.0 / c2;
            if inv.is_finite() {
                mul(c(inv), div(f, *g))
            } else {
                Expr::binary(Div, f, Expr::binary(Mul, c(c2), *g))
            }
        }
        (a, b) => Expr::binary(Div, a, b),
    }
}

fn pow(a: Expr, b: Expr) -> Expr {
    use BinaryOp::*;
    if is_const(&b, 1.0) {
        return unary(UnaryOp::Abs, a);
    }
    if is_const(&b, 0.0) {
        return c(1.0);
    }
    match (a, b) {
        // pow takes |a| itself.
        (Expr::Unary(UnaryOp::Abs, inner), b) => pow(*inner, b),
        (a, Expr::Const(0.5)) => unary(UnaryOp::Sqrt, a),
        (a, b) => Expr::binary(Pow, a, b),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use BinaryOp::*;

    fn x(i: usize) -> Expr {
        Expr::Var(i)
    }

    fn same_values(a: &Expr, b: &Expr) {
        for r in 0..20 {
            let row = [0.3 + r as f64 * 0.37, 2.1 - r as f64 * 0.29, 0.7 + r as f64 * 0.05];
            let (va, vb) = (a.eval_row(&row), b.eval_row(&row));
            if va.is_finite() {
                assert!((va - vb).abs() <= 1e-9 * (1.0 + va.abs()), "{a} = {va} but {b} = {vb}");
            }
        }
    }

    #[test]
    fn rules_keep_values_and_never_grow() {
        let cases = vec![
            Expr::binary(Sub, x(0), c(2.0)),
            Expr::binary(Add, Expr::binary(Add, c(1.0), x(0)), Expr::binary(Add, c(2.0), x(1))),
            Expr::binary(Div, Expr::binary(Mul, c(3.0), x(0)), Expr::binary(Mul, c(2.0), x(1))),
            Expr::binary(Pow, Expr::unary(UnaryOp::Abs, x(0)), c(1.0)),
            Expr::unary(UnaryOp::Log, Expr::unary(UnaryOp::Exp, x(1))),
            Expr::binary(Sub, c(1.95), Expr::binary(Mul, c(1.23), Expr::unary(UnaryOp::Tanh, x(0)))),
            Expr::binary(Mul, x(1), Expr::binary(Mul, c(2.0), x(0))),
            Expr::binary(Add, x(2), x(2)),
            Expr::unary(UnaryOp::Sqrt, Expr::unary(UnaryOp::Abs, Expr::binary(Sub, x(0), x(1)))),
            Expr::binary(Pow, x(0), c(0.5)),
        ];
        for e in cases {
            let s = simplify(&e);
            assert!(s.complexity() <= e.complexity(), "{e} grew into {s}");
            same_values(&e, &s);
        }
    }

    #[test]
    fn commutative_forms_meet() {
        let a = Expr::binary(Mul, Expr::binary(Mul, c(2.5), x(0)), x(1));
        let b = Expr::binary(Mul, x(1), Expr::binary(Mul, x(0), c(2.5)));
        assert_eq!(simplify(&a), simplify(&b));
        let a = Expr::binary(Add, x(1), Expr::binary(Add, x(0), c(1.0)));
        let b = Expr::binary(Add, Expr::binary(Add, c(1.0), x(1)), x(0));
        assert_eq!(simplify(&a), simplify(&b));
    }

    #[test]
    fn constant_subtrees_fold() {
        let e = Expr::binary(Add, Expr::binary(Mul, c(2.0), c(3.0)), x(0));
        assert_eq!(simplify(&e).to_string(), "6.0+x0");
        // Invalid constant subtrees are left alone (the candidate stays invalid).
        let e = Expr::unary(UnaryOp::Log, c(0.0));
        assert_eq!(simplify(&e), e);
    }
}
