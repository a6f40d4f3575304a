//! Fast column-wise evaluation of expressions, and forward-mode derivatives with respect to
//! the constants (the Jacobian that Levenberg-Marquardt needs).

use crate::expr::{BinaryOp, Expr, PostfixNode, UnaryOp};
use crate::fastmath;

/// One instruction of a compiled program. A binary operator whose right operand is a leaf is
/// fused with it, which saves one buffer fill per leaf.
#[derive(Clone, Copy, Debug)]
enum Instr {
    Const(f64),
    Var(usize),
    Unary(UnaryOp),
    Binary(BinaryOp),
    BinaryConst(BinaryOp, f64),
    BinaryVar(BinaryOp, usize),
}

/// An expression compiled for repeated evaluation on columns of data.
#[derive(Clone, Debug)]
pub struct Program {
    fused: Vec<Instr>,
    postfix: Vec<PostfixNode>,
    n_constants: usize,
    max_stack: usize,
}

impl Program {
    /// Compiles an expression.
    pub fn compile(expr: &Expr) -> Program {
        let postfix = expr.postfix();
        let mut fused: Vec<Instr> = Vec::with_capacity(postfix.len());
        for node in &postfix {
            match *node {
                PostfixNode::Const(c) => fused.push(Instr::Const(c)),
                PostfixNode::Var(i) => fused.push(Instr::Var(i)),
                PostfixNode::Unary(op) => fused.push(Instr::Unary(op)),
                PostfixNode::Binary(op) => {
                    // The right operand was pushed last; if it is a leaf and the left operand
                    // is already on the stack (the previous instruction is not the left
                    // operand's only push), fuse. The left operand always precedes, so a leaf
                    // right operand is exactly the last instruction.
                    match fused.last().copied() {
                        Some(Instr::Const(c)) if fused.len() >= 2 => {
                            fused.pop();
                            fused.push(Instr::BinaryConst(op, c));
                        }
                        Some(Instr::Var(i)) if fused.len() >= 2 => {
                            fused.pop();
                            fused.push(Instr::BinaryVar(op, i));
                        }
                        _ => fused.push(Instr::Binary(op)),
                    }
                }
            }
        }
        let mut depth = 0usize;
        let mut max_stack = 0usize;
        for node in &postfix {
            match node {
                PostfixNode::Const(_) | PostfixNode::Var(_) => depth += 1,
                PostfixNode::Unary(_) => {}
                PostfixNode::Binary(_) => depth -= 1,
            }
            max_stack = max_stack.max(depth);
        }
        let n_constants = postfix.iter().filter(|n| matches!(n, PostfixNode::Const(_))).count();
        Program { fused, postfix, n_constants, max_stack }
    }

    /// Replaces the constants (postfix order, as [`Expr::constants`]) without recompiling:
    /// the same program as compiling the expression with those constants.
    ///
    /// # Panics
    /// If `values` does not hold [`Program::n_constants`] values.
    pub fn set_constants(&mut self, values: &[f64]) {
        assert_eq!(values.len(), self.n_constants, "one value per constant");
        let mut it = values.iter();
        for node in &mut self.postfix {
            if let PostfixNode::Const(c) = node {
                *c = *it.next().expect("counted");
            }
        }
        let mut it = values.iter();
        for instr in &mut self.fused {
            if let Instr::Const(c) | Instr::BinaryConst(_, c) = instr {
                *c = *it.next().expect("counted");
            }
        }
    }

    /// Number of constants (the parameters of [`Evaluator::eval_with_jacobian`]).
    pub fn n_constants(&self) -> usize {
        self.n_constants
    }
}

/// Reusable evaluation buffers for a fixed number of rows.
#[derive(Clone, Debug)]
pub struct Evaluator {
    n_rows: usize,
    stack: Vec<Vec<f64>>,
    /// Value and derivative rows, and the range of constants the entry depends on.
    jac_stack: Vec<(Vec<f64>, usize, usize)>,
    tmp_value: Vec<f64>,
    tmp_fa: Vec<f64>,
    tmp_fb: Vec<f64>,
}

/// Whether the CPU has AVX2 (detected once, then cached by std). The AVX2 variants of the
/// evaluator do the same IEEE operations in the same order as the generic ones (FMA is not
/// enabled, and Rust never contracts `a * b + c`), so they give the same bits.
#[cfg(target_arch = "x86_64")]
#[inline]
fn has_avx2() -> bool {
    std::arch::is_x86_feature_detected!("avx2")
}

/// Whether every value is finite. A branch-free fold, so that it vectorises.
#[inline(always)]
fn all_finite(v: &[f64]) -> bool {
    v.iter().fold(true, |ok, x| ok & x.is_finite())
}

#[inline(always)]
fn apply_binary(op: BinaryOp, a: &mut [f64], b: &[f64]) {
    let b = &b[..a.len()];
    match op {
        BinaryOp::Add => {
            for (x, y) in a.iter_mut().zip(b) {
                *x += *y;
            }
        }
        BinaryOp::Sub => {
            for (x, y) in a.iter_mut().zip(b) {
                *x -= *y;
            }
        }
        BinaryOp::Mul => {
            for (x, y) in a.iter_mut().zip(b) {
                *x *= *y;
            }
        }
        BinaryOp::Div => {
            for (x, y) in a.iter_mut().zip(b) {
                *x /= *y;
            }
        }
        BinaryOp::Pow => fastmath::pow_abs_in_place(a, b),
    }
}

#[inline(always)]
fn apply_binary_const(op: BinaryOp, a: &mut [f64], c: f64) {
    match op {
        BinaryOp::Add => {
            for x in a.iter_mut() {
                *x += c;
            }
        }
        BinaryOp::Sub => {
            for x in a.iter_mut() {
                *x -= c;
            }
        }
        BinaryOp::Mul => {
            for x in a.iter_mut() {
                *x *= c;
            }
        }
        BinaryOp::Div => {
            for x in a.iter_mut() {
                *x /= c;
            }
        }
        BinaryOp::Pow => fastmath::pow_abs_const_in_place(a, c),
    }
}

#[inline(always)]
fn apply_unary(op: UnaryOp, a: &mut [f64]) {
    match op {
        UnaryOp::Abs => {
            for x in a.iter_mut() {
                *x = x.abs();
            }
        }
        UnaryOp::Sqrt => {
            for x in a.iter_mut() {
                *x = x.abs().sqrt();
            }
        }
        UnaryOp::Exp => fastmath::exp_in_place(a),
        UnaryOp::Log => fastmath::ln_in_place(a),
        UnaryOp::Tanh => fastmath::tanh_in_place(a),
        UnaryOp::Sin => {
            for x in a.iter_mut() {
                *x = x.sin();
            }
        }
    }
}

/// `fa = d op(a) / da`, given `v = op(a)`, column-wise.
#[inline(always)]
fn unary_derivative(op: UnaryOp, a: &[f64], v: &[f64], fa: &mut [f64]) {
    let (a, v) = (&a[..fa.len()], &v[..fa.len()]);
    let it = fa.iter_mut().zip(a.iter().zip(v));
    match op {
        UnaryOp::Abs => {
            for (f, (x, _)) in it {
                *f = if *x > 0.0 {
                    1.0
                } else if *x < 0.0 {
                    -1.0
                } else {
                    0.0
                };
            }
        }
        UnaryOp::Sqrt => {
            for (f, (x, v)) in it {
                *f = 0.5 * v / x;
            }
        }
        UnaryOp::Exp => fa.copy_from_slice(v),
        UnaryOp::Log => {
            for (f, (x, _)) in it {
                *f = 1.0 / x;
            }
        }
        UnaryOp::Tanh => {
            for (f, (_, v)) in it {
                *f = 1.0 - v * v;
            }
        }
        UnaryOp::Sin => {
            for (f, (x, _)) in it {
                *f = x.cos();
            }
        }
    }
}

/// `fa = d op(a, b) / da`, `fb = d op(a, b) / db`, given `v = op(a, b)`, column-wise.
#[inline(always)]
fn binary_derivatives(op: BinaryOp, a: &[f64], b: &[f64], v: &[f64], fa: &mut [f64], fb: &mut [f64]) {
    let n = fa.len();
    let (a, b, v, fb) = (&a[..n], &b[..n], &v[..n], &mut fb[..n]);
    let it = fa.iter_mut().zip(fb.iter_mut()).zip(a.iter().zip(b).zip(v));
    match op {
        BinaryOp::Add => {
            fa.fill(1.0);
            fb.fill(1.0);
        }
        BinaryOp::Sub => {
            fa.fill(1.0);
            fb.fill(-1.0);
        }
        BinaryOp::Mul => {
            fa.copy_from_slice(b);
            fb.copy_from_slice(a);
        }
        BinaryOp::Div => {
            for ((da, db), ((_, y), v)) in it {
                (*da, *db) = (1.0 / y, -v / y);
            }
        }
        // d|x|^y/dx = y |x|^y / x, d|x|^y/dy = |x|^y ln|x|; both 0 where |x|^y is 0.
        BinaryOp::Pow => {
            for ((da, db), ((x, y), v)) in it {
                let (ga, gb) = (y * v / x, v * fastmath::ln(*x));
                (*da, *db) = if *v == 0.0 { (0.0, 0.0) } else { (ga, gb) };
            }
        }
    }
}

impl Evaluator {
    /// Buffers for `n_rows` rows.
    pub fn new(n_rows: usize) -> Evaluator {
        Evaluator {
            n_rows,
            stack: Vec::new(),
            jac_stack: Vec::new(),
            tmp_value: vec![0.0; n_rows],
            tmp_fa: vec![0.0; n_rows],
            tmp_fb: vec![0.0; n_rows],
        }
    }

    /// Number of rows this evaluator is sized for.
    pub fn n_rows(&self) -> usize {
        self.n_rows
    }

    /// Evaluates `program` on `columns` (each `n_rows` long) into `out`. Returns `false` (and
    /// leaves `out` unspecified) if any intermediate value is non-finite.
    ///
    /// ```
    /// use sts_symreg::{Evaluator, Expr, Program, BinaryOp};
    /// let p = Program::compile(&Expr::binary(BinaryOp::Mul, Expr::Var(0), Expr::Const(3.0)));
    /// let mut ev = Evaluator::new(2);
    /// let mut out = [0.0; 2];
    /// assert!(ev.eval(&p, &[&[1.0, 2.0]], &mut out));
    /// assert_eq!(out, [3.0, 6.0]);
    /// ```
    pub fn eval(&mut self, program: &Program, columns: &[&[f64]], out: &mut [f64]) -> bool {
        #[cfg(target_arch = "x86_64")]
        {
            if has_avx2() {
                // SAFETY: the CPU supports AVX2 (checked just above).
                return unsafe { self.eval_avx2(program, columns, out) };
            }
        }
        self.eval_generic(program, columns, out)
    }

    /// [`Evaluator::eval`] compiled for AVX2 (4 lanes instead of SSE2's 2).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn eval_avx2(&mut self, program: &Program, columns: &[&[f64]], out: &mut [f64]) -> bool {
        self.eval_generic(program, columns, out)
    }

    /// The body of [`Evaluator::eval`], for every instruction set.
    #[inline(always)]
    fn eval_generic(&mut self, program: &Program, columns: &[&[f64]], out: &mut [f64]) -> bool {
        let n = self.n_rows;
        assert_eq!(out.len(), n, "output length must equal the evaluator's row count");
        while self.stack.len() < program.max_stack {
            self.stack.push(vec![0.0; n]);
        }
        let mut sp = 0usize;
        for instr in &program.fused {
            match *instr {
                Instr::Const(c) => {
                    self.stack[sp].fill(c);
                    sp += 1;
                    continue;
                }
                Instr::Var(i) => {
                    self.stack[sp].copy_from_slice(&columns[i][..n]);
                    sp += 1;
                    continue;
                }
                Instr::Unary(op) => apply_unary(op, &mut self.stack[sp - 1]),
                Instr::Binary(op) => {
                    let (lo, hi) = self.stack.split_at_mut(sp - 1);
                    apply_binary(op, &mut lo[sp - 2], &hi[0]);
                    sp -= 1;
                }
                Instr::BinaryConst(op, c) => apply_binary_const(op, &mut self.stack[sp - 1], c),
                Instr::BinaryVar(op, i) => apply_binary(op, &mut self.stack[sp - 1], &columns[i][..n]),
            }
            if !all_finite(&self.stack[sp - 1]) {
                return false;
            }
        }
        debug_assert_eq!(sp, 1);
        out.copy_from_slice(&self.stack[0]);
        // A lone constant or variable was never checked.
        all_finite(out)
    }

    /// Evaluates `program` and the derivatives of its value with respect to each of its
    /// constants (postfix order). `jacobian` holds `n_constants * n_rows` values, the
    /// derivatives for constant `j` at `jacobian[j * n_rows..(j + 1) * n_rows]`. Returns
    /// `false` if any value or derivative is non-finite.
    pub fn eval_with_jacobian(
        &mut self,
        program: &Program,
        columns: &[&[f64]],
        out: &mut [f64],
        jacobian: &mut [f64],
    ) -> bool {
        #[cfg(target_arch = "x86_64")]
        {
            if has_avx2() {
                // SAFETY: the CPU supports AVX2 (checked just above).
                return unsafe { self.eval_with_jacobian_avx2(program, columns, out, jacobian) };
            }
        }
        self.eval_with_jacobian_generic(program, columns, out, jacobian)
    }

    /// [`Evaluator::eval_with_jacobian`] compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn eval_with_jacobian_avx2(
        &mut self,
        program: &Program,
        columns: &[&[f64]],
        out: &mut [f64],
        jacobian: &mut [f64],
    ) -> bool {
        self.eval_with_jacobian_generic(program, columns, out, jacobian)
    }

    /// The body of [`Evaluator::eval_with_jacobian`], for every instruction set.
    #[inline(always)]
    fn eval_with_jacobian_generic(
        &mut self,
        program: &Program,
        columns: &[&[f64]],
        out: &mut [f64],
        jacobian: &mut [f64],
    ) -> bool {
        // Each stack entry holds its value (rows 0..n) and its derivatives with respect to
        // the constants of its subtree only. In postfix order a subtree's constants are a
        // contiguous range, and the two operands of a binary operator own adjacent disjoint
        // ranges, so no derivative row is ever zero-filled or summed: row j of the result
        // is `fa * da_j` or `fb * db_j`. Row j lives at `(j + 1) * n` in every buffer.
        let n = self.n_rows;
        let k = program.n_constants;
        let width = (k + 1) * n;
        assert_eq!(out.len(), n);
        assert_eq!(jacobian.len(), k * n);
        while self.jac_stack.len() < program.max_stack {
            self.jac_stack.push((Vec::new(), 0, 0));
        }
        for (buf, _, _) in &mut self.jac_stack {
            if buf.len() < width {
                buf.resize(width, 0.0);
            }
        }
        let mut sp = 0usize;
        let mut const_idx = 0usize;
        for node in &program.postfix {
            match *node {
                PostfixNode::Const(c) => {
                    let (buf, lo, hi) = &mut self.jac_stack[sp];
                    buf[..n].fill(c);
                    let row = (const_idx + 1) * n;
                    buf[row..row + n].fill(1.0);
                    (*lo, *hi) = (const_idx, const_idx + 1);
                    const_idx += 1;
                    sp += 1;
                }
                PostfixNode::Var(i) => {
                    let (buf, lo, hi) = &mut self.jac_stack[sp];
                    buf[..n].copy_from_slice(&columns[i][..n]);
                    (*lo, *hi) = (const_idx, const_idx);
                    sp += 1;
                }
                PostfixNode::Unary(op) => {
                    let (buf, lo, hi) = &mut self.jac_stack[sp - 1];
                    let (lo, hi) = (*lo, *hi);
                    let (a, rest) = buf.split_at_mut(n);
                    if hi > lo {
                        let v = &mut self.tmp_value;
                        v.copy_from_slice(a);
                        apply_unary(op, v);
                        unary_derivative(op, a, v, &mut self.tmp_fa);
                        let fa = &self.tmp_fa;
                        for d in rest[lo * n..hi * n].chunks_exact_mut(n) {
                            for (d, f) in d.iter_mut().zip(fa.iter()) {
                                *d *= *f;
                            }
                        }
                        a.copy_from_slice(&self.tmp_value);
                        if !all_finite(a) || !all_finite(&rest[lo * n..hi * n]) {
                            return false;
                        }
                    } else {
                        apply_unary(op, a);
                        if !all_finite(a) {
                            return false;
                        }
                    }
                }
                PostfixNode::Binary(op) => {
                    let (below, top) = self.jac_stack.split_at_mut(sp - 1);
                    let (abuf, alo, ahi) = &mut below[sp - 2];
                    let (bbuf, blo, bhi) = &top[0];
                    let (la, ha, lb, hb) = (*alo, *ahi, *blo, *bhi);
                    debug_assert!(ha == lb || la == ha || lb == hb);
                    if la == ha && lb == hb {
                        apply_binary(op, &mut abuf[..n], &bbuf[..n]);
                        if !all_finite(&abuf[..n]) {
                            return false;
                        }
                        (*alo, *ahi) = (lb, hb);
                        sp -= 1;
                        continue;
                    }
                    let (a, arest) = abuf.split_at_mut(n);
                    let (b, brest) = bbuf.split_at(n);
                    let v = &mut self.tmp_value;
                    v.copy_from_slice(a);
                    apply_binary(op, v, b);
                    binary_derivatives(op, a, b, v, &mut self.tmp_fa, &mut self.tmp_fb);
                    let (fa, fb) = (&self.tmp_fa, &self.tmp_fb);
                    for d in arest[la * n..ha * n].chunks_exact_mut(n) {
                        for (d, f) in d.iter_mut().zip(fa.iter()) {
                            *d *= *f;
                        }
                    }
                    let (dst, src) = (&mut arest[lb * n..hb * n], &brest[lb * n..hb * n]);
                    for (d, s) in dst.chunks_exact_mut(n).zip(src.chunks_exact(n)) {
                        for ((d, s), f) in d.iter_mut().zip(s).zip(fb.iter()) {
                            *d = f * s;
                        }
                    }
                    a.copy_from_slice(&self.tmp_value);
                    // The operands' ranges are adjacent (or one is empty).
                    let (lo, hi) = if la == ha {
                        (lb, hb)
                    } else if lb == hb {
                        (la, ha)
                    } else {
                        (la, hb)
                    };
                    (*alo, *ahi) = (lo, hi);
                    if !all_finite(a) || !all_finite(&arest[lo * n..hi * n]) {
                        return false;
                    }
                    sp -= 1;
                }
            }
        }
        debug_assert_eq!(sp, 1);
        let (buf, lo, hi) = &self.jac_stack[0];
        out.copy_from_slice(&buf[..n]);
        debug_assert!(*hi == *lo || (*lo, *hi) == (0, k));
        if *hi > *lo {
            jacobian.copy_from_slice(&buf[n..width]);
        } else {
            jacobian.fill(0.0);
        }
        all_finite(out)
    }
}

/// Evaluating an expression on whole columns, through the compiled [`Program`].
impl Expr {
    /// Evaluates on column-major data (`columns[i][row]` is variable `i`); `None` if any
    /// intermediate value is non-finite on any row.
    ///
    /// ```
    /// use sts_symreg::{Expr, BinaryOp};
    /// let e = Expr::binary(BinaryOp::Div, Expr::Var(0), Expr::Var(1));
    /// let x0 = [1.0, 2.0];
    /// let x1 = [2.0, 0.0];
    /// assert_eq!(e.eval_columns(&[&x0, &x1]), None); // 2/0 is not finite
    /// ```
    pub fn eval_columns(&self, columns: &[&[f64]]) -> Option<Vec<f64>> {
        let n_rows = columns.first().map_or(0, |c| c.len());
        let program = Program::compile(self);
        let mut evaluator = Evaluator::new(n_rows);
        let mut out = vec![0.0; n_rows];
        evaluator.eval(&program, columns, &mut out).then_some(out)
    }

    /// Evaluates on every row of a row-major [`crate::Matrix`]; `None` if any intermediate
    /// value is non-finite.
    pub fn eval_matrix(&self, x: &crate::Matrix) -> Option<Vec<f64>> {
        let columns = x.columns();
        let refs: Vec<&[f64]> = columns.iter().map(Vec::as_slice).collect();
        if refs.is_empty() {
            // No input columns: only constant expressions can be evaluated.
            let v = self.eval_row(&[]);
            return v.is_finite().then(|| vec![v; x.n_rows()]);
        }
        self.eval_columns(&refs)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::expr::{BinaryOp::*, UnaryOp::*};

    fn sample() -> Expr {
        // 1.3 - 0.7 * tanh(0.2*x0 + |x1/x0|^0.6) + sqrt(exp(0.1*x1)) * log(x0) - sin(x1*0.5)
        let inner = Expr::binary(
            Add,
            Expr::binary(Mul, Expr::Const(0.2), Expr::Var(0)),
            Expr::binary(Pow, Expr::binary(Div, Expr::Var(1), Expr::Var(0)), Expr::Const(0.6)),
        );
        let t = Expr::binary(Sub, Expr::Const(1.3), Expr::binary(Mul, Expr::Const(0.7), Expr::unary(Tanh, inner)));
        let s = Expr::binary(
            Mul,
            Expr::unary(Sqrt, Expr::unary(Exp, Expr::binary(Mul, Expr::Const(0.1), Expr::Var(1)))),
            Expr::unary(Log, Expr::Var(0)),
        );
        let w = Expr::unary(Sin, Expr::binary(Mul, Expr::Var(1), Expr::Const(0.5)));
        Expr::binary(Sub, Expr::binary(Add, t, s), Expr::unary(Abs, w))
    }

    fn data() -> Vec<Vec<f64>> {
        let x0: Vec<f64> = (0..37).map(|i| 0.5 + i as f64 * 0.13).collect();
        let x1: Vec<f64> = (0..37).map(|i| -2.0 + i as f64 * 0.21).collect();
        vec![x0, x1]
    }

    #[test]
    fn column_eval_matches_row_eval() {
        let e = sample();
        let cols = data();
        let refs: Vec<&[f64]> = cols.iter().map(Vec::as_slice).collect();
        let out = e.eval_columns(&refs).unwrap();
        for (r, v) in out.iter().enumerate() {
            let row = [cols[0][r], cols[1][r]];
            assert_eq!(*v, e.eval_row(&row));
        }
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let e = sample();
        let cols = data();
        let refs: Vec<&[f64]> = cols.iter().map(Vec::as_slice).collect();
        let p = Program::compile(&e);
        let n = cols[0].len();
        let k = p.n_constants();
        let mut ev = Evaluator::new(n);
        let mut out = vec![0.0; n];
        let mut jac = vec![0.0; k * n];
        assert!(ev.eval_with_jacobian(&p, &refs, &mut out, &mut jac));
        let base = e.eval_columns(&refs).unwrap();
        assert_eq!(out, base);
        let consts = e.constants();
        for j in 0..k {
            let h = 1e-6 * consts[j].abs().max(1.0);
            let mut plus = consts.clone();
            plus[j] += h;
            let mut minus = consts.clone();
            minus[j] -= h;
            let mut ep = e.clone();
            ep.set_constants(&plus);
            let mut em = e.clone();
            em.set_constants(&minus);
            let fp = ep.eval_columns(&refs).unwrap();
            let fm = em.eval_columns(&refs).unwrap();
            for r in 0..n {
                let fd = (fp[r] - fm[r]) / (2.0 * h);
                let an = jac[j * n + r];
                assert!((fd - an).abs() <= 1e-5 * (1.0 + an.abs()), "const {j} row {r}: fd {fd} vs {an}");
            }
        }
    }

    /// The AVX2 variants give the same bits as the generic (SSE2) code.
    #[test]
    fn avx2_and_generic_agree_bit_for_bit() {
        let e = sample();
        let cols = data();
        let refs: Vec<&[f64]> = cols.iter().map(Vec::as_slice).collect();
        let p = Program::compile(&e);
        let n = cols[0].len();
        let k = p.n_constants();
        let mut ev = Evaluator::new(n);
        let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
        assert!(ev.eval(&p, &refs, &mut a));
        assert!(ev.eval_generic(&p, &refs, &mut b));
        assert_eq!(
            a.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            b.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
        let (mut ja, mut jb) = (vec![0.0; k * n], vec![0.0; k * n]);
        assert!(ev.eval_with_jacobian(&p, &refs, &mut a, &mut ja));
        assert!(ev.eval_with_jacobian_generic(&p, &refs, &mut b, &mut jb));
        assert_eq!(
            a.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            b.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
        assert_eq!(
            ja.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            jb.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
    }

    /// The libm semantics the engine had before its own `exp`/`ln`/`tanh`/`pow`: the
    /// evaluator must classify every edge input the same way (valid or not) and, when valid,
    /// agree to rounding.
    fn std_unary(op: UnaryOp, a: f64) -> f64 {
        match op {
            Abs => a.abs(),
            Sqrt => a.abs().sqrt(),
            Exp => a.exp(),
            Log => a.abs().ln(),
            Tanh => a.tanh(),
            Sin => a.sin(),
        }
    }

    fn std_binary(op: BinaryOp, a: f64, b: f64) -> f64 {
        match op {
            Add => a + b,
            Sub => a - b,
            Mul => a * b,
            Div => a / b,
            Pow => a.abs().powf(b),
        }
    }

    const EDGES: [f64; 24] = [
        0.0,
        -0.0,
        1.0,
        -1.0,
        2.0,
        -2.0,
        0.78,
        -0.78,
        5e-324,
        -5e-324,
        1e-300,
        2.5e-308,
        30.0,
        -30.0,
        709.0,
        709.9,
        -745.0,
        -746.0,
        1e300,
        -1e300,
        f64::MAX,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NAN,
    ];

    fn check_one(e: &Expr, cols: &[&[f64]], want: f64) {
        let p = Program::compile(e);
        let mut ev = Evaluator::new(1);
        let mut out = [0.0];
        let ok = ev.eval(&p, cols, &mut out);
        // The evaluator checks what operators compute (data columns are checked when loaded);
        let want_ok = want.is_finite();
        let inputs_finite = cols.iter().all(|c| c[0].is_finite());
        assert_eq!(ok, want_ok, "{e} at {cols:?}: got {} valid={ok}, std {want}", out[0]);
        if ok {
            let tol = 2e-13 * want.abs();
            assert!((out[0] - want).abs() <= tol, "{e} at {cols:?}: {} vs std {want}", out[0]);
        }
        if inputs_finite {
            let row: Vec<f64> = cols.iter().map(|c| c[0]).collect();
            assert_eq!(e.eval_row(&row).is_finite(), want_ok, "{e} row at {row:?}");
        }
    }

    #[test]
    fn edge_inputs_are_classified_as_with_libm() {
        for op in UnaryOp::ALL {
            for &x in &EDGES {
                let e = Expr::unary(op, Expr::Var(0));
                check_one(&e, &[&[x]], std_unary(op, x));
            }
        }
        for op in BinaryOp::ALL {
            for &x in &EDGES {
                for &y in &EDGES {
                    // Column op column, and column op constant (the fused path).
                    let e = Expr::binary(op, Expr::Var(0), Expr::Var(1));
                    check_one(&e, &[&[x], &[y]], std_binary(op, x, y));
                    if y.is_finite() {
                        let e = Expr::binary(op, Expr::Var(0), Expr::Const(y));
                        check_one(&e, &[&[x]], std_binary(op, x, y));
                    }
                }
            }
        }
    }

    #[test]
    fn set_constants_equals_recompiling() {
        let mut e = sample();
        let mut p = Program::compile(&e);
        let c: Vec<f64> = e.constants().iter().map(|v| v * 1.7 - 0.1).collect();
        p.set_constants(&c);
        e.set_constants(&c);
        let q = Program::compile(&e);
        assert_eq!(format!("{:?}", p), format!("{:?}", q));
    }

    #[test]
    fn non_finite_intermediate_is_invalid() {
        // tanh(1/(x0 - x0)) would be finite at the output (tanh(inf) = 1) but is invalid.
        let e = Expr::unary(Tanh, Expr::binary(Div, Expr::Const(1.0), Expr::binary(Sub, Expr::Var(0), Expr::Var(0))));
        assert_eq!(e.eval_columns(&[&[1.0, 2.0]]), None);
    }
}
