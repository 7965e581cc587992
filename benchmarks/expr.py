"""Expression benchmark (issue 3): compile and evaluate 10 000 expression-based forces.

Part of ``make bench`` (called by :mod:`benchmarks.chain`). Each instance is the nonlinear spring law
``-1000*(DM(I,J)-50)+STEP(TIME,0,0,1,100)`` with its own marker pair and its own numbers, so the
batch compiler groups all of them into one vectorised program. Measured: compile time (parse
every text, group, build the program; median of ``repeat`` runs) and one evaluation of values
and exact derivatives (per Newton iteration; median of 20 after a warm-up).
Targets: evaluation <= 5 ms, compile <= 1 s for 10 000 expressions.
"""
from __future__ import annotations

import gc
import time

import numpy as np

N_EXPR = 10_000


class _Resolver:
    """Markers 1..2n map to indices 0..2n-1; nothing else is referenced."""

    def __init__(self, n_markers):
        self.n = n_markers
        self.angles = {}

    def marker_index(self, id):
        if id == 0:
            return -1
        if 1 <= id <= self.n:
            return id - 1
        raise KeyError(id)

    def angle_key(self, i_idx, j_idx, axis):
        return self.angles.setdefault((i_idx, j_idx, axis), len(self.angles))


def _texts(n, rng):
    k = np.round(rng.uniform(500.0, 1500.0, n), 3)
    L0 = np.round(rng.uniform(40.0, 60.0, n), 3)
    h = 100 + np.arange(n) % 7
    texts = [f"-{float(k[i])!r}*(DM({2 * i + 1},{2 * i + 2})-{float(L0[i])!r})+STEP(TIME,0,0,1,{h[i]})"
             for i in range(n)]
    return texts, k, L0, h


def bench_expressions(n: int = N_EXPR, repeat: int = 3) -> dict:
    from poise.deck.spec import Expr
    from poise.core.errors import SourceLoc
    from poise.expr import EvalContext, compile_batch
    rng = np.random.default_rng(0)
    texts, k, L0, h = _texts(n, rng)
    loc = SourceLoc("<bench>", 1, "Force_Scalar_TwoBody", 1)
    comp = []
    batch = None
    for _ in range(max(1, repeat)):
        exprs = [Expr(t, loc, "val_expression") for t in texts]   # fresh: no text cache reuse
        gc.collect()
        t0 = time.perf_counter()
        batch = compile_batch(exprs, _Resolver(2 * n))
        comp.append(time.perf_counter() - t0)
    P = rng.normal(scale=100.0, size=(2 * n, 3))
    A = np.broadcast_to(np.eye(3), (2 * n, 3, 3)).copy()
    ctx = EvalContext(t=0.4, P=P, A=A, angle=np.zeros(0), static=True)
    batch.evaluate(ctx)
    ev = []
    for _ in range(20):
        t0 = time.perf_counter()
        out = batch.evaluate(ctx)
        ev.append(time.perf_counter() - t0)
    dm = np.linalg.norm(P[0::2] - P[1::2], axis=1)
    expect = -k * (dm - L0) + h * 0.4 ** 2 * (3 - 2 * 0.4)     # STEP is cubic on [0, 1]
    ok = bool(np.allclose(out.value, expect, rtol=1e-12, atol=1e-9))
    return dict(bench="expressions", n=n, groups=int(getattr(batch, "n_groups", 1) or 1),
                compile_s=_stats(comp), eval_s=_stats(ev), value_check=bool(ok))


def _stats(xs):
    xs = sorted(xs)
    return dict(median=float(np.median(xs)), min=float(xs[0]), max=float(xs[-1]), runs=len(xs))


def markdown(r: dict) -> str:
    ev_ms = 1e3 * r["eval_s"]["median"]
    c = r["compile_s"]["median"]
    lines = [
        "## Expressions (issue 3)",
        "",
        f"{r['n']} expression-based forces `-k*(DM(I,J)-L0)+STEP(TIME,0,0,1,h)` (own markers and "
        "numbers each), one vectorised group.",
        "",
        "| measure | median | min | max | target | |",
        "|---|---|---|---|---|---|",
        f"| evaluate values + exact derivatives | {ev_ms:.2f} ms | {1e3 * r['eval_s']['min']:.2f} ms "
        f"| {1e3 * r['eval_s']['max']:.2f} ms | ≤ 5 ms | {'PASS' if ev_ms <= 5 else 'MISS'} |",
        f"| compile (parse, group, build) | {c:.3f} s | {r['compile_s']['min']:.3f} s | "
        f"{r['compile_s']['max']:.3f} s | ≤ 1 s | {'PASS' if c <= 1 else 'MISS'} |",
        "",
        f"Value check against the closed form: {'ok' if r['value_check'] else 'FAILED'}.",
        "",
    ]
    return "\n".join(lines)


def targets(r: dict):
    ev_ms = 1e3 * r["eval_s"]["median"]
    c = r["compile_s"]["median"]
    return [("10 000 expressions evaluated with derivatives", "5 ms", f"{ev_ms:.2f} ms", ev_ms <= 5),
            ("10 000 expressions compiled", "1 s", f"{c:.3f} s", c <= 1)]
