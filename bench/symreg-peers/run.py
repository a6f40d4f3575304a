#!/usr/bin/env python3
"""Side-by-side benchmark of sts-symreg against pyoperon and the `symbolic_regression` crate
on the planted problems P1 and P2 (99 rows x 12 features), several seeds each.

Every engine sees the same CSV files (written by the sts-symreg `planted` example), runs on
the same number of threads with the same wall-time budget per problem, and its SELECTED model
(each engine's own choice) is judged by the same exact-form check, done here with SymPy:

  * the formula uses no distractor feature, and
  * on 4000 points drawn from the feature box widened by half its width on each side (lower
    bounds kept positive) it is finite everywhere and within 1% of the truth at every point.

This mirrors `sts_symreg::planted::is_exact_recovery`.

Usage (from the repository root, after `pip install pyoperon sympy numpy`):

    python3 bench/symreg-peers/run.py [--seeds 10] [--threads 2] [--engines ours,rust-sr,pyoperon]

It builds what it needs with cargo, prints one line per run, then a Markdown table.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np
import sympy

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
PEER_DIR = os.path.join(ROOT, "bench", "symreg-peers", "rust-sr")

# Feature ranges, exactly as sts_symreg::planted::ranges.
DISTRACTORS = [(0.5, 2.0), (1.0, 20.0), (0.5, 10.0), (2.0, 8.0), (0.5, 5.0), (1.0, 15.0),
               (0.5, 3.0), (3.0, 20.0), (0.5, 10.0), (1.0, 4.0)]


def ranges(problem):
    r = [(0.5, 10.0)] * 12
    if problem == "P1":
        r[0] = (1.0, 5.0)
        used = 3
    else:
        r[0] = (5.0, 40.0)
        r[1] = (1.0, 10.0)
        used = 2
    for j, d in zip(range(used, 12), DISTRACTORS):
        r[j] = d
    return r


def truth(problem, x):
    if problem == "P1":
        return 2.5 * x[0] * np.abs(x[1] / x[2]) ** 0.78
    return 1.95 - 1.23 * np.tanh(-0.0441 * x[0] + 0.122 * x[1] + 1.08)


USED = {"P1": {0, 1, 2}, "P2": {0, 1}}
BUDGET_S = {"P1": 10.0, "P2": 30.0}
SYMS = sympy.symbols("x0:12")


def parse_formula(text):
    """Parses a formula from any engine into SymPy with the engines' function names."""
    local = {f"x{i}": SYMS[i] for i in range(12)}
    local.update({
        "abs": sympy.Abs, "sqrt": sympy.sqrt, "exp": sympy.exp, "log": sympy.log,
        "tanh": sympy.tanh, "sin": sympy.sin, "cos": sympy.cos,
        "pow": lambda a, b: a ** b, "square": lambda a: a ** 2, "cube": lambda a: a ** 3,
        "neg": lambda a: -a, "add": lambda a, b: a + b, "sub": lambda a, b: a - b,
        "mul": lambda a, b: a * b, "div": lambda a, b: a / b, "abs2": lambda a: a ** 2,
    })
    text = text.replace("^", "**")
    return sympy.parse_expr(text, local_dict=local, evaluate=True)


def is_exact(problem, formula):
    try:
        expr = parse_formula(formula)
    except Exception as e:  # noqa: BLE001 - any unparsable formula is simply not recovered
        return False, f"unparsable: {e}"
    used = {int(str(s)[1:]) for s in expr.free_symbols}
    if not used <= USED[problem]:
        return False, f"uses distractors {sorted(used - USED[problem])}"
    f = sympy.lambdify(SYMS, expr, modules="numpy")
    rng = np.random.default_rng(12345)
    cols = []
    for lo, hi in ranges(problem):
        w = hi - lo
        a, b = max(lo - 0.5 * w, 0.5 * lo), hi + 0.5 * w
        cols.append(rng.uniform(a, b, 4000))
    with np.errstate(all="ignore"):
        pred = np.asarray(f(*cols), dtype=complex) * np.ones(4000)
        t = truth(problem, cols)
    if np.any(~np.isfinite(pred)) or np.any(np.abs(pred.imag) > 1e-9 * np.abs(t)):
        return False, "not finite/real on the widened box"
    rel = np.max(np.abs(pred.real - t) / np.abs(t))
    return bool(rel <= 0.01), f"max rel err {rel:.2e}"


def run_ours(cmd, csv, seed, threads, budget):
    args = cmd + ["regress", csv, "--target", "y", "--seed", str(seed), "--threads", str(threads),
                  "--time-budget", str(budget), "--json"]
    t0 = time.perf_counter()
    out = subprocess.run(args, check=True, capture_output=True, text=True).stdout
    wall = time.perf_counter() - t0
    j = json.loads(out)
    return j["formula"], j["complexity"], wall, [m["formula"] for m in j["front"]]


def run_rust_sr(binary, csv, seed, threads, budget):
    args = [binary, csv, "--seed", str(seed), "--threads", str(threads), "--timeout", str(budget)]
    t0 = time.perf_counter()
    out = subprocess.run(args, check=True, capture_output=True, text=True).stdout
    wall = time.perf_counter() - t0
    j = json.loads(out)
    return j["formula"], j["complexity"], wall, [m["formula"] for m in j["front"]]


def run_pyoperon(csv, seed, threads, budget):
    from pyoperon.sklearn import SymbolicRegressor
    data = np.loadtxt(csv, delimiter=",", skiprows=1)
    x, y = data[:, :-1], data[:, -1]
    reg = SymbolicRegressor(
        allowed_symbols="add,sub,mul,div,constant,variable,pow,abs,sqrt,exp,log,tanh,sin",
        objectives=["r2", "length"],   # multi-objective (NSGA-II): a complexity-accuracy front
        optimizer_iterations=10,      # Levenberg-Marquardt local search on every offspring
        max_length=20,                # the same size limit as the other engines
        max_evaluations=100_000_000,  # let the time budget decide
        generations=100_000,
        n_threads=threads,
        max_time=int(budget),
        random_state=seed,
    )
    t0 = time.perf_counter()
    reg.fit(x, y)
    wall = time.perf_counter() - t0
    names = [f"x{i}" for i in range(x.shape[1])]
    formula = reg.get_model_string(reg.model_, 12, names)
    front = [reg.get_model_string(m["tree"], 12, names) for m in getattr(reg, "pareto_front_", [])]
    return formula, reg.model_.Length if hasattr(reg.model_, "Length") else -1, wall, front


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--problems", default="P1,P2")
    ap.add_argument("--engines", default="ours,rust-sr,pyoperon")
    ap.add_argument("--ours-cmd", default=None,
                    help="command for sts-twin (default: build and use target/release/sts-twin)")
    ap.add_argument("--json-out", default=None, help="also write every run as JSON here")
    a = ap.parse_args()
    engines = a.engines.split(",")
    problems = a.problems.split(",")

    subprocess.run(["cargo", "build", "--release", "-p", "sts-symreg", "--example", "planted"], cwd=ROOT, check=True)
    target = os.environ.get("CARGO_TARGET_DIR", os.path.join(ROOT, "target"))
    planted = os.path.join(target, "release", "examples", "planted")
    ours_cmd = a.ours_cmd.split() if a.ours_cmd else None
    if "ours" in engines and ours_cmd is None:
        subprocess.run(["cargo", "build", "--release", "-p", "sts-twin"], cwd=ROOT, check=True)
        ours_cmd = [os.path.join(target, "release", "sts-twin")]
    peer_bin = None
    if "rust-sr" in engines:
        peer_target = os.path.join(target, "symreg-peers")
        subprocess.run(["cargo", "build", "--release"], cwd=PEER_DIR, check=True,
                       env={**os.environ, "CARGO_TARGET_DIR": peer_target})
        peer_bin = os.path.join(peer_target, "release", "symreg-peer-rust-sr")

    data_dir = tempfile.mkdtemp(prefix="symreg-planted-")
    subprocess.run([planted, "--write-csv", data_dir, "--seeds", str(a.seeds)], check=True)

    runs = []
    for problem in problems:
        budget = BUDGET_S[problem]
        for seed in range(a.seeds):
            csv = os.path.join(data_dir, f"{problem}_seed{seed}.csv")
            for engine in engines:
                if engine == "ours":
                    formula, cx, wall, front = run_ours(ours_cmd, csv, seed, a.threads, budget)
                elif engine == "rust-sr":
                    formula, cx, wall, front = run_rust_sr(peer_bin, csv, seed, a.threads, budget)
                else:
                    formula, cx, wall, front = run_pyoperon(csv, seed, a.threads, budget)
                ok, why = is_exact(problem, formula)
                on_front = any(is_exact(problem, f)[0] for f in front)
                runs.append(dict(problem=problem, seed=seed, engine=engine, formula=formula,
                                 complexity=cx, wall_s=wall, recovered=ok, exact_on_front=on_front, check=why))
                print(f"{problem} seed {seed:2d} {engine:9s} {wall:7.2f} s  recovered={ok!s:5s} "
                      f"on_front={on_front!s:5s} {why:28s} {formula}", flush=True)

    if a.json_out:
        with open(a.json_out, "w") as fh:
            json.dump(runs, fh, indent=1)
    print()
    print(f"| problem (budget) | engine | recovered (selected model) | exact form on front | median wall time |")
    print(f"|---|---|---|---|---|")
    for problem in problems:
        for engine in engines:
            rs = [r for r in runs if r["problem"] == problem and r["engine"] == engine]
            rec = sum(r["recovered"] for r in rs)
            front = sum(r["exact_on_front"] for r in rs)
            med = statistics.median(r["wall_s"] for r in rs)
            print(f"| {problem} ({BUDGET_S[problem]:.0f} s) | {engine} | {rec}/{len(rs)} ({100 * rec / len(rs):.0f}%) "
                  f"| {front}/{len(rs)} | {med:.2f} s |")


if __name__ == "__main__":
    sys.exit(main())
