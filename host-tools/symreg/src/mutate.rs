//! Random expressions, mutations and crossover, all driven by one seeded ChaCha stream.

use rand_chacha::rand_core::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::expr::{BinaryOp, Expr};
use crate::operators::OperatorSet;

/// A seeded random stream with the few draws the search needs (independent of `rand`'s
/// distribution code, so results cannot change with a dependency update).
#[derive(Clone, Debug)]
pub(crate) struct Rand(ChaCha8Rng);

impl Rand {
    pub fn new(seed: u64, stream: u64) -> Rand {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(stream);
        Rand(rng)
    }

    /// Uniform in [0, 1).
    pub fn f64(&mut self) -> f64 {
        (self.0.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform integer in `0..n` (`n > 0`).
    pub fn below(&mut self, n: usize) -> usize {
        debug_assert!(n > 0);
        // Multiply-shift: bias below 2^-32 for the small n used here.
        (((self.0.next_u64() >> 32) * n as u64) >> 32) as usize
    }

    pub fn chance(&mut self, p: f64) -> bool {
        self.f64() < p
    }

    /// Standard normal (Box-Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = 1.0 - self.f64();
        let u2 = self.f64();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    pub fn pick<T: Copy>(&mut self, items: &[T]) -> T {
        items[self.below(items.len())]
    }
}

/// Everything mutations need to know about the problem.
pub(crate) struct Grammar<'a> {
    pub ops: &'a OperatorSet,
    pub n_vars: usize,
    pub max_complexity: usize,
    pub max_depth: usize,
}

impl Grammar<'_> {
    fn random_const(&self, rng: &mut Rand) -> Expr {
        // Magnitudes from 0.1 to 10, either sign: constant optimisation refines them.
        let mag = 10f64.powf(rng.f64() * 2.0 - 1.0);
        Expr::Const(if rng.chance(0.5) { mag } else { -mag })
    }

    fn random_var(&self, rng: &mut Rand) -> Expr {
        if self.n_vars == 0 {
            return Expr::Const(1.0);
        }
        Expr::Var(rng.below(self.n_vars))
    }

    pub fn random_leaf(&self, rng: &mut Rand) -> Expr {
        if self.n_vars > 0 && rng.chance(0.7) {
            self.random_var(rng)
        } else {
            self.random_const(rng)
        }
    }

    /// A random tree of exactly `size` nodes where the operator set allows it (smaller
    /// otherwise).
    pub fn random_tree(&self, rng: &mut Rand, size: usize) -> Expr {
        let has_bin = !self.ops.binary.is_empty();
        let has_un = !self.ops.unary.is_empty();
        if size <= 1 || (!has_bin && !has_un) {
            return self.random_leaf(rng);
        }
        if size == 2 || !has_bin || (has_un && rng.chance(0.2)) {
            if has_un {
                let op = rng.pick(&self.ops.unary);
                return Expr::unary(op, self.random_tree(rng, size - 1));
            }
            return self.random_leaf(rng);
        }
        let op = rng.pick(&self.ops.binary);
        let rest = size - 1;
        let left = 1 + rng.below(rest - 1);
        let right = rest - left;
        Expr::binary(op, self.random_tree(rng, left), self.random_tree(rng, right))
    }

    /// `c * x_i` or `x_i`: scaled variables make linear combinations one step away.
    fn random_term(&self, rng: &mut Rand) -> Expr {
        let v = self.random_leaf(rng);
        if matches!(v, Expr::Var(_)) && rng.chance(0.4) && self.ops.binary.contains(&BinaryOp::Mul) {
            Expr::binary(BinaryOp::Mul, self.random_const(rng), v)
        } else {
            v
        }
    }

    pub fn fits(&self, e: &Expr) -> bool {
        e.complexity() <= self.max_complexity && e.depth() <= self.max_depth
    }

    /// One random mutation of `parent`. May return a copy of the parent when the drawn
    /// mutation does not apply.
    pub fn mutate(&self, rng: &mut Rand, parent: &Expr) -> Expr {
        let mut e = parent.clone();
        let n = e.complexity();
        // Weights: tuned on planted problems; constant optimisation does the fine work.
        const W: [(Mutation, f64); 11] = [
            (Mutation::PerturbConst, 0.6),
            (Mutation::ChangeOp, 1.0),
            (Mutation::ChangeVar, 1.0),
            (Mutation::Grow, 1.6),
            (Mutation::Insert, 1.2),
            (Mutation::Delete, 1.0),
            (Mutation::Replace, 0.8),
            (Mutation::Hoist, 0.2),
            (Mutation::Affine, 0.5),
            (Mutation::AddTerm, 0.8),
            (Mutation::Randomize, 0.05),
        ];
        let total: f64 = W.iter().map(|w| w.1).sum();
        let mut u = rng.f64() * total;
        let mut kind = Mutation::Randomize;
        for (m, w) in W {
            if u < w {
                kind = m;
                break;
            }
            u -= w;
        }
        match kind {
            Mutation::PerturbConst => {
                let idx = indices(&e, |n| matches!(n, Expr::Const(_)));
                if idx.is_empty() {
                    return self.mutate_fallback(rng, e);
                }
                let k = rng.pick(&idx);
                if let Expr::Const(c) = nth_mut(&mut e, k) {
                    if rng.chance(0.1) {
                        *c = -*c;
                    } else {
                        *c *= (rng.normal() * 0.5).exp();
                    }
                }
            }
            Mutation::ChangeOp => {
                let idx = indices(&e, |n| matches!(n, Expr::Unary(..) | Expr::Binary(..)));
                if idx.is_empty() {
                    return self.mutate_fallback(rng, e);
                }
                let k = rng.pick(&idx);
                match nth_mut(&mut e, k) {
                    Expr::Unary(op, _) => *op = rng.pick(&self.ops.unary),
                    Expr::Binary(op, _, _) => *op = rng.pick(&self.ops.binary),
                    _ => {}
                }
            }
            Mutation::ChangeVar => {
                let idx = indices(&e, |n| matches!(n, Expr::Var(_)));
                if idx.is_empty() || self.n_vars == 0 {
                    return self.mutate_fallback(rng, e);
                }
                let k = rng.pick(&idx);
                *nth_mut(&mut e, k) = self.random_var(rng);
            }
            Mutation::Grow => {
                // A leaf becomes op(leaf, new) / op(new, leaf) / u(leaf).
                let idx = indices(&e, |n| matches!(n, Expr::Const(_) | Expr::Var(_)));
                let k = rng.pick(&idx);
                let node = nth_mut(&mut e, k);
                let leaf = node.clone();
                *node = self.wrap(rng, leaf);
            }
            Mutation::Insert => {
                let k = rng.below(n);
                let node = nth_mut(&mut e, k);
                let sub = node.clone();
                *node = self.wrap(rng, sub);
            }
            Mutation::Delete => {
                let idx = indices(&e, |n| matches!(n, Expr::Unary(..) | Expr::Binary(..)));
                if idx.is_empty() {
                    return self.mutate_fallback(rng, e);
                }
                let k = rng.pick(&idx);
                let node = nth_mut(&mut e, k);
                let replacement = match node {
                    Expr::Unary(_, a) => (**a).clone(),
                    Expr::Binary(_, a, b) => {
                        if rng.chance(0.5) {
                            (**a).clone()
                        } else {
                            (**b).clone()
                        }
                    }
                    _ => node.clone(),
                };
                *node = replacement;
            }
            Mutation::Replace => {
                let k = rng.below(n);
                let size = 1 + rng.below(5);
                *nth_mut(&mut e, k) = self.random_tree(rng, size);
            }
            Mutation::Hoist => {
                let k = rng.below(n);
                e = nth_mut(&mut e, k).clone();
            }
            Mutation::Affine => {
                // sub -> c0 + c1*sub, or c0 + c1*u(sub).
                if !self.ops.binary.contains(&BinaryOp::Add) || !self.ops.binary.contains(&BinaryOp::Mul) {
                    return self.mutate_fallback(rng, e);
                }
                let k = if rng.chance(0.5) { 0 } else { rng.below(n) };
                let node = nth_mut(&mut e, k);
                let mut sub = node.clone();
                if !self.ops.unary.is_empty() && rng.chance(0.5) {
                    sub = Expr::unary(rng.pick(&self.ops.unary), sub);
                }
                *node =
                    Expr::binary(BinaryOp::Add, Expr::Const(0.0), Expr::binary(BinaryOp::Mul, Expr::Const(1.0), sub));
            }
            Mutation::AddTerm => {
                // sub -> sub + c*x_i (or - / * / a new leaf term).
                let k = if rng.chance(0.3) { 0 } else { rng.below(n) };
                let node = nth_mut(&mut e, k);
                let sub = node.clone();
                let op = if self.ops.binary.contains(&BinaryOp::Add) && rng.chance(0.7) {
                    BinaryOp::Add
                } else {
                    rng.pick(&self.ops.binary)
                };
                let term = self.random_term(rng);
                *node = Expr::binary(op, sub, term);
            }
            Mutation::Randomize => {
                let size = 1 + rng.below(self.max_complexity.min(12));
                e = self.random_tree(rng, size);
            }
        }
        e
    }

    fn mutate_fallback(&self, rng: &mut Rand, e: Expr) -> Expr {
        let n = e.complexity();
        let mut e = e;
        let k = rng.below(n);
        let node = nth_mut(&mut e, k);
        let sub = node.clone();
        *node = self.wrap(rng, sub);
        e
    }

    /// `u(sub)`, `sub op new` or `new op sub`.
    fn wrap(&self, rng: &mut Rand, sub: Expr) -> Expr {
        let has_un = !self.ops.unary.is_empty();
        let has_bin = !self.ops.binary.is_empty();
        if has_un && (!has_bin || rng.chance(0.3)) {
            return Expr::unary(rng.pick(&self.ops.unary), sub);
        }
        if !has_bin {
            return sub;
        }
        let op = rng.pick(&self.ops.binary);
        let new = if op == BinaryOp::Pow {
            // Exponents are almost always constants.
            if rng.chance(0.8) {
                Expr::Const(rng.pick(&[0.5, 2.0, -1.0, 1.5, 0.8]))
            } else {
                self.random_leaf(rng)
            }
        } else {
            self.random_term(rng)
        };
        if op == BinaryOp::Pow || rng.chance(0.5) {
            Expr::binary(op, sub, new)
        } else {
            Expr::binary(op, new, sub)
        }
    }

    /// Replaces a random subtree of `a` with a random subtree of `b`.
    pub fn crossover(&self, rng: &mut Rand, a: &Expr, b: &Expr) -> Expr {
        let mut child = a.clone();
        let ka = rng.below(child.complexity());
        let kb = rng.below(b.complexity());
        let donor = nth(b, kb).clone();
        *nth_mut(&mut child, ka) = donor;
        child
    }
}

#[derive(Clone, Copy, Debug)]
enum Mutation {
    PerturbConst,
    ChangeOp,
    ChangeVar,
    Grow,
    Insert,
    Delete,
    Replace,
    Hoist,
    Affine,
    AddTerm,
    Randomize,
}

/// `e` with the operator node at preorder index `k` replaced by its operand `side` (0 left /
/// only, 1 right); `None` if that node is a leaf or has no such operand.
pub(crate) fn remove_node(e: &Expr, k: usize, side: usize) -> Option<Expr> {
    let mut out = e.clone();
    let node = nth_mut(&mut out, k);
    let replacement = match (&*node, side) {
        (Expr::Unary(_, a), 0) => (**a).clone(),
        (Expr::Binary(_, a, _), 0) => (**a).clone(),
        (Expr::Binary(_, _, b), 1) => (**b).clone(),
        _ => return None,
    };
    *node = replacement;
    Some(out)
}

/// Preorder indices of the nodes matching `pred`.
fn indices(e: &Expr, pred: impl Fn(&Expr) -> bool + Copy) -> Vec<usize> {
    fn go(e: &Expr, k: &mut usize, out: &mut Vec<usize>, pred: impl Fn(&Expr) -> bool + Copy) {
        if pred(e) {
            out.push(*k);
        }
        *k += 1;
        match e {
            Expr::Const(_) | Expr::Var(_) => {}
            Expr::Unary(_, a) => go(a, k, out, pred),
            Expr::Binary(_, a, b) => {
                go(a, k, out, pred);
                go(b, k, out, pred);
            }
        }
    }
    let mut out = Vec::new();
    let mut k = 0;
    go(e, &mut k, &mut out, pred);
    out
}

/// The node at preorder index `k`.
fn nth(e: &Expr, k: usize) -> &Expr {
    if k == 0 {
        return e;
    }
    match e {
        Expr::Const(_) | Expr::Var(_) => e,
        Expr::Unary(_, a) => nth(a, k - 1),
        Expr::Binary(_, a, b) => {
            let na = a.complexity();
            if k - 1 < na {
                nth(a, k - 1)
            } else {
                nth(b, k - 1 - na)
            }
        }
    }
}

/// The node at preorder index `k`, mutably.
fn nth_mut(e: &mut Expr, k: usize) -> &mut Expr {
    if k == 0 {
        return e;
    }
    match e {
        Expr::Const(_) | Expr::Var(_) => e,
        Expr::Unary(_, a) => nth_mut(a, k - 1),
        Expr::Binary(_, a, b) => {
            let na = a.complexity();
            if k - 1 < na {
                nth_mut(a, k - 1)
            } else {
                nth_mut(b, k - 1 - na)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn random_trees_have_the_requested_size() {
        let ops = OperatorSet::all();
        let g = Grammar { ops: &ops, n_vars: 3, max_complexity: 30, max_depth: 30 };
        let mut rng = Rand::new(7, 0);
        for size in 1..20 {
            let t = g.random_tree(&mut rng, size);
            assert_eq!(t.complexity(), size, "{t}");
        }
    }

    #[test]
    fn mutations_and_simplification_keep_values_valid() {
        let ops = OperatorSet::all();
        let g = Grammar { ops: &ops, n_vars: 3, max_complexity: 30, max_depth: 30 };
        let mut rng = Rand::new(11, 0);
        let mut e = g.random_tree(&mut rng, 7);
        for _ in 0..3000 {
            let child = if rng.chance(0.1) {
                let other = g.random_tree(&mut rng, 5);
                g.crossover(&mut rng, &e, &other)
            } else {
                g.mutate(&mut rng, &e)
            };
            let s = crate::simplify::simplify(&child);
            assert!(s.complexity() <= child.complexity(), "{child} -> {s}");
            for r in 0..5 {
                let row = [0.3 + r as f64, 1.7 - 0.4 * r as f64, 2.2 + 0.1 * r as f64];
                let (a, b) = (child.eval_row(&row), s.eval_row(&row));
                if a.is_finite() && b.is_finite() {
                    assert!((a - b).abs() <= 1e-6 * (1.0 + a.abs()), "{child} = {a}, {s} = {b}");
                }
            }
            e = if s.complexity() <= 25 { s } else { g.random_tree(&mut rng, 5) };
        }
    }

    #[test]
    fn same_seed_same_stream() {
        let mut a = Rand::new(5, 3);
        let mut b = Rand::new(5, 3);
        let mut c = Rand::new(5, 4);
        let va: Vec<u64> = (0..8).map(|_| a.0.next_u64()).collect();
        let vb: Vec<u64> = (0..8).map(|_| b.0.next_u64()).collect();
        let vc: Vec<u64> = (0..8).map(|_| c.0.next_u64()).collect();
        assert_eq!(va, vb);
        assert_ne!(va, vc);
    }
}
