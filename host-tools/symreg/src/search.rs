//! The search: islands of regularised evolution with migration, a hall of fame per
//! complexity, constant optimisation on every offspring, and the Pareto front.
//!
//! Determinism: each island owns a ChaCha stream derived from the seed and its index, runs a
//! fixed number of offspring per epoch, and islands only interact at epoch boundaries, in
//! island order, through a separate seeded stream. Threads only decide which island runs
//! where, so the result is the same bit for bit for any thread count. The optional wall-time
//! budget is checked only at epoch boundaries; when it is what stops the search the result
//! depends on the machine's speed (see [`StopReason::TimeBudget`]).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::time::{Duration, Instant};

use crate::data::{Matrix, SymregError};
use crate::expr::Expr;
use crate::mutate::{Grammar, Rand};
use crate::operators::OperatorSet;
use crate::optimize::Workspace;
use crate::select::{explain, select_model, SelectionConfig};
use crate::simplify::simplify;

/// Everything that steers a search. [`SearchConfig::default`] is tuned for about 100 rows
/// and a dozen features.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SearchConfig {
    /// Seed of every random choice.
    pub seed: u64,
    /// Worker threads (the result does not depend on it).
    pub threads: usize,
    /// Stop after this many epochs (the deterministic budget).
    pub max_epochs: usize,
    /// Optional wall-time cap, checked at epoch boundaries only; a search stopped by it is
    /// reproducible only on a machine of the same speed.
    pub time_budget: Option<Duration>,
    /// Operators to build formulas from.
    pub operators: OperatorSet,
    /// Largest complexity (node count) searched.
    pub max_complexity: usize,
    /// Largest tree depth searched.
    pub max_depth: usize,
    /// Number of islands (independent populations).
    pub islands: usize,
    /// Members per island.
    pub population_size: usize,
    /// Offspring each island breeds per epoch.
    pub offspring_per_epoch: usize,
    /// Members drawn per tournament.
    pub tournament_size: usize,
    /// Strength of the penalty on crowded complexities in tournaments (PySR's adaptive
    /// parsimony): fitness is `nmse * exp(scaling * fraction_at_that_complexity)`.
    pub adaptive_parsimony: f64,
    /// Probability that an offspring comes from crossover rather than mutation.
    pub crossover_probability: f64,
    /// Levenberg-Marquardt iterations on each offspring.
    pub lm_iterations: usize,
    /// Probability of an extra constant-optimisation restart from perturbed constants.
    pub restart_probability: f64,
    /// Levenberg-Marquardt iterations when polishing hall-of-fame entries.
    pub polish_iterations: usize,
    /// Restarts from perturbed constants when polishing.
    pub polish_restarts: usize,
    /// Members each island receives at each epoch boundary (half from the global front,
    /// half from other islands).
    pub migrants: usize,
    /// Stop early once a front member reaches this NMSE (`None`: never) ...
    pub early_stop_nmse: Option<f64>,
    /// ... and the simplest such member has stayed the same for this many epochs.
    pub exact_patience: usize,
    /// The model-selection rule.
    pub selection: SelectionConfig,
    /// Set from another thread to stop the search at its next epoch boundary with
    /// [`SymregError::Stopped`] (a Ctrl-C); not part of the search's settings.
    #[serde(skip)]
    pub stop: Option<StopFlag>,
}

/// A flag another thread sets to stop searches at their next epoch boundary. Clones share
/// the flag; two flags are equal when they are the same flag.
#[derive(Clone, Debug, Default)]
pub struct StopFlag(std::sync::Arc<std::sync::atomic::AtomicBool>);

impl StopFlag {
    /// A flag not set.
    pub fn new() -> Self {
        Self::default()
    }

    /// Sets the flag: searches holding it stop at their next epoch boundary.
    pub fn stop(&self) {
        self.0.store(true, std::sync::atomic::Ordering::Relaxed);
    }

    /// Whether the flag is set.
    pub fn is_stopped(&self) -> bool {
        self.0.load(std::sync::atomic::Ordering::Relaxed)
    }
}

impl PartialEq for StopFlag {
    fn eq(&self, other: &Self) -> bool {
        std::sync::Arc::ptr_eq(&self.0, &other.0)
    }
}

impl Default for SearchConfig {
    fn default() -> Self {
        SearchConfig {
            seed: 0,
            threads: 2,
            max_epochs: 200,
            time_budget: None,
            operators: OperatorSet::all(),
            max_complexity: 20,
            max_depth: 10,
            islands: 8,
            population_size: 64,
            offspring_per_epoch: 200,
            tournament_size: 6,
            adaptive_parsimony: 5.0,
            crossover_probability: 0.08,
            lm_iterations: 6,
            restart_probability: 0.05,
            polish_iterations: 60,
            polish_restarts: 3,
            migrants: 4,
            early_stop_nmse: Some(1e-12),
            exact_patience: 2,
            selection: SelectionConfig::default(),
            stop: None,
        }
    }
}

impl SearchConfig {
    fn validate(&self) -> Result<(), SymregError> {
        let bad = |m: &str| Err(SymregError::Config(m.to_string()));
        if self.threads == 0 {
            return bad("threads must be at least 1");
        }
        if self.islands == 0 || self.population_size < 2 {
            return bad("need at least one island of at least two members");
        }
        if self.tournament_size == 0 {
            return bad("tournament size must be at least 1");
        }
        if self.max_complexity == 0 || self.max_depth == 0 {
            return bad("max complexity and depth must be at least 1");
        }
        if self.operators.unary.is_empty() && self.operators.binary.is_empty() && self.max_complexity > 1 {
            // Leaves only: allowed, but say so clearly if the user also asked for size.
        }
        Ok(())
    }
}

/// One member of the Pareto front.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrontMember {
    /// The formula.
    pub expr: Expr,
    /// Mean squared error on the training data (in units of `y` squared).
    pub loss: f64,
    /// Complexity (node count).
    pub complexity: usize,
    /// Coefficient of determination on the training data.
    pub r2: f64,
    /// Selection score (see [`crate::select`]).
    pub score: f64,
}

/// Why the search stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum StopReason {
    /// Ran `max_epochs` epochs.
    MaxEpochs,
    /// A front member reached `early_stop_nmse`.
    ExactFit,
    /// The wall-time budget ran out (machine-speed dependent result).
    TimeBudget,
}

/// The outcome of a search.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SearchResult {
    /// The Pareto front, in increasing complexity (and decreasing loss).
    pub front: Vec<FrontMember>,
    /// Index into `front` of the selected model.
    pub selected: usize,
    /// Why that member: the rule and the score of every member (variables as `x0, x1, ...`).
    pub explanation: String,
    /// Why the search stopped.
    pub stop_reason: StopReason,
    /// Epochs run.
    pub epochs: usize,
    /// Expression evaluations (a derivative evaluation counts as one).
    pub evaluations: u64,
}

impl SearchResult {
    /// The selected front member.
    pub fn best(&self) -> &FrontMember {
        &self.front[self.selected]
    }
}

/// What the progress callback sees at each epoch boundary.
#[derive(Debug)]
pub struct Progress<'a> {
    /// Epochs completed.
    pub epoch: usize,
    /// The epoch limit.
    pub max_epochs: usize,
    /// Evaluations so far.
    pub evaluations: u64,
    /// Wall time so far.
    pub elapsed: Duration,
    /// The current front, scored.
    pub front: &'a [FrontMember],
    /// Index of the member the selection rule would pick now.
    pub selected: usize,
}

#[derive(Clone, Debug)]
struct Member {
    expr: Expr,
    mse: f64,
    complexity: usize,
    birth: u64,
}

struct Island {
    rng: Rand,
    pop: Vec<Member>,
    hof: Vec<Option<Member>>,
    births: u64,
    evaluations: u64,
    /// Members per complexity, for adaptive parsimony.
    counts: Vec<u32>,
}

struct Problem<'a> {
    columns: &'a [&'a [f64]],
    y: &'a [f64],
    var_y: f64,
    grammar: Grammar<'a>,
    cfg: &'a SearchConfig,
}

impl Island {
    fn new(seed: u64, index: usize, max_complexity: usize) -> Island {
        Island {
            rng: Rand::new(seed, 1 + index as u64),
            pop: Vec::new(),
            hof: vec![None; max_complexity + 1],
            births: 0,
            evaluations: 0,
            counts: vec![0; max_complexity + 1],
        }
    }

    fn record(&mut self, m: &Member) {
        let slot = &mut self.hof[m.complexity];
        if slot.as_ref().is_none_or(|h| m.mse < h.mse) {
            *slot = Some(m.clone());
        }
    }

    fn initialize(&mut self, p: &Problem<'_>) {
        let mut ws = Workspace::new(p.columns, p.y);
        let max_size = p.cfg.max_complexity.min(10);
        let mut attempts = 0;
        while self.pop.len() < p.cfg.population_size && attempts < p.cfg.population_size * 50 {
            attempts += 1;
            let size = 1 + self.rng.below(max_size);
            let e = simplify(&p.grammar.random_tree(&mut self.rng, size));
            if let Some(m) = self.evaluate(&mut ws, p, e) {
                self.push(m);
            }
        }
        // Degenerate data or operators: fall back to constants so the island is never empty.
        while self.pop.len() < 2 {
            let e = Expr::Const(p.y.iter().sum::<f64>() / p.y.len() as f64);
            let m = self.evaluate(&mut ws, p, e).unwrap_or(Member {
                expr: Expr::Const(0.0),
                mse: f64::MAX,
                complexity: 1,
                birth: 0,
            });
            self.push(m);
        }
        self.evaluations += ws.evaluations;
    }

    fn push(&mut self, mut m: Member) {
        m.birth = self.births;
        self.births += 1;
        self.counts[m.complexity] += 1;
        self.record(&m);
        self.pop.push(m);
    }

    /// Optimises constants and scores a candidate.
    fn evaluate(&mut self, ws: &mut Workspace<'_>, p: &Problem<'_>, mut e: Expr) -> Option<Member> {
        if !p.grammar.fits(&e) {
            return None;
        }
        let mut mse = ws.optimize_constants(&mut e, p.cfg.lm_iterations);
        if e.n_constants() > 0 && self.rng.chance(p.cfg.restart_probability) {
            let mut alt = e.clone();
            let consts: Vec<f64> = alt
                .constants()
                .iter()
                .map(|c| if self.rng.chance(0.5) { c * (self.rng.normal()).exp() } else { self.rng.normal() })
                .collect();
            alt.set_constants(&consts);
            let alt_mse = ws.optimize_constants(&mut alt, p.cfg.lm_iterations * 2);
            if let Some(a) = alt_mse
                && mse.is_none_or(|m| a < m)
            {
                e = alt;
                mse = Some(a);
            }
        }
        let mse = mse?;
        let complexity = e.complexity();
        Some(Member { expr: e, mse, complexity, birth: 0 })
    }

    fn fitness(&self, m: &Member, var_y: f64, scaling: f64) -> f64 {
        let frac = self.counts[m.complexity] as f64 / self.pop.len().max(1) as f64;
        (m.mse / var_y).max(1e-30) * (scaling * frac).exp()
    }

    fn tournament(&mut self, p: &Problem<'_>) -> usize {
        let mut best = self.rng.below(self.pop.len());
        let mut best_fit = self.fitness(&self.pop[best], p.var_y, p.cfg.adaptive_parsimony);
        for _ in 1..p.cfg.tournament_size {
            let i = self.rng.below(self.pop.len());
            let f = self.fitness(&self.pop[i], p.var_y, p.cfg.adaptive_parsimony);
            if f < best_fit {
                best = i;
                best_fit = f;
            }
        }
        best
    }

    fn run_epoch(&mut self, p: &Problem<'_>) {
        let mut ws = Workspace::new(p.columns, p.y);
        for _ in 0..p.cfg.offspring_per_epoch {
            let a = self.tournament(p);
            let child = if self.rng.chance(p.cfg.crossover_probability) {
                let b = self.tournament(p);
                p.grammar.crossover(&mut self.rng, &self.pop[a].expr, &self.pop[b].expr)
            } else {
                p.grammar.mutate(&mut self.rng, &self.pop[a].expr)
            };
            let child = simplify(&child);
            let Some(m) = self.evaluate(&mut ws, p, child) else {
                continue;
            };
            // De-duplicate: same complexity and the same error means the same function
            // (up to an equivalent rewrite); keep the population diverse.
            let dup = self
                .pop
                .iter()
                .any(|o| o.complexity == m.complexity && (o.mse - m.mse).abs() <= 1e-9 * o.mse.max(m.mse) + 1e-300);
            if dup {
                self.record(&m);
                continue;
            }
            self.replace_oldest(m);
        }
        self.evaluations += ws.evaluations;
    }

    /// Regularised (aging) evolution: the newcomer replaces the oldest member.
    fn replace_oldest(&mut self, mut m: Member) {
        let oldest = self.pop.iter().enumerate().min_by_key(|(_, o)| o.birth).map(|(i, _)| i).unwrap_or(0);
        self.counts[self.pop[oldest].complexity] -= 1;
        m.birth = self.births;
        self.births += 1;
        self.counts[m.complexity] += 1;
        self.record(&m);
        self.pop[oldest] = m;
    }

    /// Replaces a random member (never the best one) with a migrant.
    fn receive(&mut self, migrant: &Member, rng: &mut Rand) {
        let best = self.pop.iter().enumerate().min_by(|a, b| a.1.mse.total_cmp(&b.1.mse)).map(|(i, _)| i).unwrap_or(0);
        let mut i = rng.below(self.pop.len());
        if i == best {
            i = (i + 1) % self.pop.len();
        }
        self.counts[self.pop[i].complexity] -= 1;
        let mut m = migrant.clone();
        m.birth = self.births;
        self.births += 1;
        self.counts[m.complexity] += 1;
        self.pop[i] = m;
    }
}

/// Checks the data and returns `var(y)`.
fn validate(x: &Matrix, y: &[f64]) -> Result<f64, SymregError> {
    if x.n_rows() != y.len() {
        return Err(SymregError::RowCount { x_rows: x.n_rows(), y_len: y.len() });
    }
    if y.len() < 3 {
        return Err(SymregError::TooFewRows { min: 3, got: y.len() });
    }
    for r in 0..x.n_rows() {
        for (c, &v) in x.row(r).iter().enumerate() {
            if !v.is_finite() {
                return Err(SymregError::NonFiniteX { row: r, col: c, value: v });
            }
        }
    }
    for (r, &v) in y.iter().enumerate() {
        if !v.is_finite() {
            return Err(SymregError::NonFiniteY { row: r, value: v });
        }
    }
    let mean = y.iter().sum::<f64>() / y.len() as f64;
    let var = y.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / y.len() as f64;
    if var.is_nan() || var <= 0.0 {
        return Err(SymregError::ConstantTarget { value: y[0] });
    }
    Ok(var)
}

/// The Pareto front of a hall of fame: members whose loss beats every simpler member.
fn pareto(hof: &[Option<Member>]) -> Vec<Member> {
    let mut front: Vec<Member> = Vec::new();
    for m in hof.iter().flatten() {
        if front.last().is_none_or(|l| m.mse < l.mse) {
            front.push(m.clone());
        }
    }
    front
}

fn scored_front(front: &[Member], var_y: f64, cfg: &SelectionConfig) -> (Vec<FrontMember>, usize) {
    let pairs: Vec<(usize, f64)> = front.iter().map(|m| (m.complexity, m.mse / var_y)).collect();
    let sel = select_model(&pairs, cfg);
    let members = front
        .iter()
        .enumerate()
        .map(|(i, m)| FrontMember {
            expr: m.expr.clone(),
            loss: m.mse,
            complexity: m.complexity,
            r2: 1.0 - m.mse / var_y,
            score: sel.as_ref().map_or(0.0, |s| s.scores[i]),
        })
        .collect();
    (members, sel.map_or(0, |s| s.selected))
}

/// Runs a symbolic-regression search for `y ~ f(x)`.
///
/// `progress` is called after every epoch with the current front (it cannot change the
/// result). The same data, configuration and seed give the same result bit for bit, for any
/// thread count, unless the search is stopped by `time_budget`.
///
/// ```
/// use sts_symreg::{fit, Matrix, SearchConfig};
/// // y = 3*x0 + 1 on 20 rows.
/// let rows: Vec<Vec<f64>> = (0..20).map(|i| vec![i as f64 * 0.5, (i * 7 % 5) as f64]).collect();
/// let y: Vec<f64> = rows.iter().map(|r| 3.0 * r[0] + 1.0).collect();
/// let x = Matrix::from_rows(&rows).unwrap();
/// let cfg = SearchConfig { max_epochs: 20, islands: 2, ..SearchConfig::default() };
/// let result = fit(&x, &y, &cfg, |_| {}).unwrap();
/// assert!(result.best().r2 > 0.999999);
/// ```
pub fn fit<F>(x: &Matrix, y: &[f64], cfg: &SearchConfig, mut progress: F) -> Result<SearchResult, SymregError>
where
    F: FnMut(&Progress<'_>),
{
    cfg.validate()?;
    let var_y = validate(x, y)?;
    let start = Instant::now();
    let columns_owned = x.columns();
    let columns: Vec<&[f64]> = columns_owned.iter().map(Vec::as_slice).collect();
    let problem = Problem {
        columns: &columns,
        y,
        var_y,
        grammar: Grammar {
            ops: &cfg.operators,
            n_vars: x.n_cols(),
            max_complexity: cfg.max_complexity,
            max_depth: cfg.max_depth,
        },
        cfg,
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(cfg.threads)
        .build()
        .map_err(|e| SymregError::Config(format!("cannot start {} threads: {e}", cfg.threads)))?;

    let mut islands: Vec<Island> = (0..cfg.islands).map(|i| Island::new(cfg.seed, i, cfg.max_complexity)).collect();
    let mut master = Rand::new(cfg.seed, 0);
    pool.install(|| islands.par_iter_mut().for_each(|isl| isl.initialize(&problem)));

    let mut global: Vec<Option<Member>> = vec![None; cfg.max_complexity + 1];
    let mut polish_evaluations = 0u64;
    let mut epochs = 0;
    let mut stop_reason = StopReason::MaxEpochs;
    let mut last_exact: Option<usize> = None;
    let mut exact_stable = 0usize;
    let mut front_members: Vec<FrontMember>;
    let mut selected;
    let stopped = || cfg.stop.as_ref().is_some_and(StopFlag::is_stopped);
    loop {
        if stopped() {
            return Err(SymregError::Stopped);
        }
        if epochs < cfg.max_epochs {
            pool.install(|| islands.par_iter_mut().for_each(|isl| isl.run_epoch(&problem)));
            epochs += 1;
        }
        // Merge the islands' halls of fame in island order; polish newcomers.
        let mut changed: Vec<usize> = Vec::new();
        for isl in &islands {
            for m in isl.hof.iter().flatten() {
                let slot = &mut global[m.complexity];
                if slot.as_ref().is_none_or(|g| m.mse < g.mse) {
                    *slot = Some(m.clone());
                    if !changed.contains(&m.complexity) {
                        changed.push(m.complexity);
                    }
                }
            }
        }
        changed.sort_unstable();
        // Polish and prune the new entries in parallel; each gets its own random stream
        // (seed, epoch, complexity) and results are merged in complexity order.
        let jobs: Vec<(usize, Member)> = changed.iter().filter_map(|&c| global[c].clone().map(|m| (c, m))).collect();
        let polished: Vec<(Vec<Member>, u64)> = pool.install(|| {
            jobs.par_iter()
                .map(|(c, m)| {
                    let mut ws = Workspace::new(&columns, y);
                    let mut rng = Rand::new(cfg.seed, (1u64 << 40) + (epochs as u64) * 4096 + *c as u64);
                    let mut out = Vec::new();
                    if let Some(p) = polish(&mut ws, &mut rng, &problem, m) {
                        let pruned = prune(&mut ws, &problem, &p);
                        out.push(p);
                        out.extend(pruned);
                    }
                    (out, ws.evaluations)
                })
                .collect()
        });
        for (members, evals) in polished {
            polish_evaluations += evals;
            for q in members {
                let slot = &mut global[q.complexity];
                if slot.as_ref().is_none_or(|g| q.mse < g.mse) {
                    *slot = Some(q);
                }
            }
        }
        let front = pareto(&global);
        (front_members, selected) = scored_front(&front, var_y, &cfg.selection);
        let evaluations = islands.iter().map(|i| i.evaluations).sum::<u64>() + polish_evaluations;
        progress(&Progress {
            epoch: epochs,
            max_epochs: cfg.max_epochs,
            evaluations,
            elapsed: start.elapsed(),
            front: &front_members,
            selected,
        });
        if epochs >= cfg.max_epochs {
            break;
        }
        if let Some(tol) = cfg.early_stop_nmse {
            // Stop once the simplest exact member has not become simpler for `patience`
            // epochs (simpler exact forms often appear shortly after the first).
            let simplest_exact = front.iter().find(|m| m.mse / var_y <= tol).map(|m| m.complexity);
            if simplest_exact.is_some() && simplest_exact == last_exact {
                exact_stable += 1;
            } else {
                exact_stable = 0;
            }
            last_exact = simplest_exact;
            if simplest_exact.is_some() && exact_stable >= cfg.exact_patience {
                stop_reason = StopReason::ExactFit;
                break;
            }
        }
        if cfg.time_budget.is_some_and(|b| start.elapsed() >= b) {
            stop_reason = StopReason::TimeBudget;
            break;
        }
        migrate(&mut islands, &front, &mut master, cfg);
    }
    let evaluations = islands.iter().map(|i| i.evaluations).sum::<u64>() + polish_evaluations;
    let pairs: Vec<(usize, f64)> = front_members.iter().map(|m| (m.complexity, m.loss / var_y)).collect();
    let explanation = match select_model(&pairs, &cfg.selection) {
        Some(sel) => {
            let rows: Vec<(usize, f64, f64, String)> = front_members
                .iter()
                .map(|m| (m.complexity, m.loss / var_y, m.r2, m.expr.to_infix_rounded::<&str>(&[], 6)))
                .collect();
            explain(&rows, &sel, &cfg.selection)
        }
        None => String::from("The front is empty: no valid formula was found."),
    };
    if front_members.is_empty() {
        return Err(SymregError::Config(
            "no valid formula was found (every candidate was non-finite on the data)".into(),
        ));
    }
    Ok(SearchResult { front: front_members, selected, explanation, stop_reason, epochs, evaluations })
}

/// Thorough constant optimisation of a hall-of-fame member (with restarts), then
/// simplification; returns the improved member if it is valid.
fn polish(ws: &mut Workspace<'_>, rng: &mut Rand, p: &Problem<'_>, m: &Member) -> Option<Member> {
    let mut best = m.expr.clone();
    let mut best_mse = ws.optimize_constants(&mut best, p.cfg.polish_iterations)?;
    if best.n_constants() > 0 {
        for _ in 0..p.cfg.polish_restarts {
            let mut alt = best.clone();
            let consts: Vec<f64> = alt.constants().iter().map(|c| c * (1.0 + 0.3 * rng.normal())).collect();
            alt.set_constants(&consts);
            if let Some(a) = ws.optimize_constants(&mut alt, p.cfg.polish_iterations)
                && a < best_mse
            {
                best = alt;
                best_mse = a;
            }
        }
    }
    let simplified = simplify(&best);
    if simplified != best
        && let Some(s) = ws.mse(&simplified)
        && s <= best_mse * (1.0 + 1e-9) + 1e-300
    {
        best = simplified;
        best_mse = s;
    }
    let complexity = best.complexity();
    if complexity > p.cfg.max_complexity || best_mse > m.mse {
        return None;
    }
    Some(Member { expr: best, mse: best_mse, complexity, birth: 0 })
}

/// Removes nodes that do not pay for themselves: repeatedly replaces an operator node by one
/// of its operands, re-optimises the constants, and keeps the smaller formula if the error
/// does not grow (or stays below the exact-fit floor). Returns every smaller formula kept.
fn prune(ws: &mut Workspace<'_>, p: &Problem<'_>, m: &Member) -> Vec<Member> {
    let floor = p.cfg.selection.exact_nmse * p.var_y;
    let mut current = m.clone();
    let mut kept = Vec::new();
    'outer: loop {
        let n = current.expr.complexity();
        for k in 0..n {
            for side in 0..2 {
                let Some(candidate) = crate::mutate::remove_node(&current.expr, k, side) else {
                    continue;
                };
                let mut candidate = simplify(&candidate);
                if candidate.complexity() >= current.complexity {
                    continue;
                }
                let Some(mse) = ws.optimize_constants(&mut candidate, p.cfg.polish_iterations) else {
                    continue;
                };
                if mse <= current.mse * (1.0 + 1e-6) || mse <= floor {
                    let simplified = simplify(&candidate);
                    let (expr, mse) = match ws.mse(&simplified) {
                        Some(s)
                            if simplified.complexity() < candidate.complexity()
                                && (s <= mse * (1.0 + 1e-9) || s <= floor) =>
                        {
                            (simplified, s)
                        }
                        _ => (candidate, mse),
                    };
                    current = Member { complexity: expr.complexity(), expr, mse, birth: 0 };
                    kept.push(current.clone());
                    continue 'outer;
                }
            }
        }
        break;
    }
    kept
}

/// Epoch-boundary migration: each island, in order, receives members of the global front
/// and the best members of other islands (as they were before this migration).
fn migrate(islands: &mut [Island], front: &[Member], rng: &mut Rand, cfg: &SearchConfig) {
    if islands.len() < 2 && front.is_empty() {
        return;
    }
    let bests: Vec<Member> = islands
        .iter()
        .map(|isl| isl.pop.iter().min_by(|a, b| a.mse.total_cmp(&b.mse)).cloned().expect("islands are never empty"))
        .collect();
    let n = islands.len();
    for (i, isl) in islands.iter_mut().enumerate() {
        for k in 0..cfg.migrants {
            let migrant = if k % 2 == 0 && !front.is_empty() {
                &front[rng.below(front.len())]
            } else if n > 1 {
                let mut j = rng.below(n - 1);
                if j >= i {
                    j += 1;
                }
                &bests[j]
            } else {
                continue;
            };
            isl.receive(migrant, rng);
        }
    }
}
