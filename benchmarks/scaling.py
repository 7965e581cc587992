"""Scaling: hanging chains (``poise.gen.chain``) and n x n grids of bushed rigid blocks
(:func:`benchmarks.decks.build_grid_deck`) vs N, each case in a fresh process through the
chain benchmark's worker (``python -m benchmarks --worker``: parse, compile, the static analysis
as ``poise solve`` runs it, one sparse LU (COLAMD) of the same KKT matrix at the solution, peak
RSS). The chain sizes already measured by the chain benchmark are reused."""
from __future__ import annotations

import math
import os
import time
from pathlib import Path

import numpy as np

CHAIN_FULL = (3000, 30000, 100000)
CHAIN_QUICK = (3000,)
GRID_FULL = (4, 8, 16, 32, 64)
GRID_QUICK = (4, 8, 16)


def fit_exponent(ns, ts, n_min: int = 0) -> float | None:
    """Least-squares slope of log t vs log N over N >= n_min."""
    pts = [(n, t) for n, t in zip(ns, ts) if n >= n_min and t and t > 0]
    if len(pts) < 2:
        return None
    x = np.log([p[0] for p in pts])
    y = np.log([p[1] for p in pts])
    return float(np.polyfit(x, y, 1)[0])


def run(chain_rows: list[dict], tmp: Path, quick: bool = False, log=print,
        budget_s: float = 420.0) -> list[dict]:
    """Extra chain sizes and the grid family. Stops adding sizes when the next one would not fit
    ``budget_s`` (the time is extrapolated from the previous size with exponent 1.3). Sizes
    that enter the floor targets (:data:`benchmarks.floor.SIZES`: the 10^5-link chain) run
    :data:`benchmarks.floor.REPEAT` times (medians), the others once."""
    from benchmarks import floor
    from benchmarks.chain import _run_worker, bench_chain
    from benchmarks.decks import build_grid_deck
    rows = []
    t_start = time.perf_counter()
    chain_rows = [r for r in chain_rows if r.get("bench") == "chain"]
    have = {r["n"] for r in chain_rows}
    last = None
    for n in (CHAIN_QUICK if quick else CHAIN_FULL):
        if n in have:
            continue
        reps = floor.REPEAT if n in floor.SIZES else 1
        if last is not None:
            n0, t0 = last
            est = reps * t0 * (n / n0) ** 1.3
            spent = time.perf_counter() - t_start
            if spent + est > budget_s:
                rows.append(dict(bench="scaling_skip", family="chain", n=n,
                                 reason=f"estimated {est:.0f} s for {reps} run(s) exceeds the "
                                        "remaining "
                                        f"budget ({budget_s - spent:.0f} s of {budget_s:.0f} s)"))
                log(f"scaling chain N={n}: skipped (estimated {est:.0f} s)")
                continue
        t0 = time.perf_counter()
        try:
            r = bench_chain(n, reps, tmp)
        except Exception as e:           # out of memory etc.: record it, keep going
            rows.append(dict(bench="scaling_skip", family="chain", n=n, reason=str(e)[-300:]))
            log(f"scaling chain N={n}: failed {e!s:.200}")
            continue
        wall = time.perf_counter() - t0
        last = (n, wall / reps)
        r["bench"] = "chain_scaling"
        r["loadavg"] = os.getloadavg()
        rows.append(r)
        log(f"scaling chain N={n}: solve {r['solve_s']['median']:.3g} s, "
            f"{r['peak_rss_bytes']['max'] / 2**20:.0f} MiB ({wall:.0f} s)")
    for g in (GRID_QUICK if quick else GRID_FULL):
        deck = tmp / f"grid_{g}.xml"
        deck.write_text(build_grid_deck(g))
        t0 = time.perf_counter()
        reps = 3 if g <= 16 else 1
        runs = [_run_worker(deck, g * g) for _ in range(reps)]
        from benchmarks.chain import _stats
        out = dict(bench="grid", n=g * g, grid=g, repeat=reps, nq=runs[0]["nq"], nc=runs[0]["nc"],
                   nnz=runs[0]["nnz"], iterations=runs[0]["iterations"],
                   status=runs[0]["status"], counters=runs[0]["counters"],
                   loadavg=os.getloadavg())
        for k in ("parse_s", "compile_s", "solve_s", "newton_s", "iteration_s", "lu_s",
                  "peak_rss_bytes"):
            out[k] = _stats([r[k] for r in runs])
        it, lu = out["iteration_s"], out["lu_s"]
        out["iteration_per_lu"] = it["median"] / lu["median"] if it and lu["median"] > 0 else None
        rows.append(out)
        log(f"scaling grid {g}x{g}: solve {out['solve_s']['median']:.3g} s, {out['iterations']} it "
            f"({time.perf_counter() - t0:.0f} s)")
    return rows


def fits(chains: list[dict], grids: list[dict]) -> dict:
    out = {}
    for fam, rows in (("chain", chains), ("grid", grids)):
        rows = sorted(rows, key=lambda r: r["n"])
        ns = [r["n"] for r in rows]
        for key in ("solve_s", "peak_rss_bytes"):
            ts = [r[key]["median"] for r in rows]
            out[f"{fam}_{key}_all"] = fit_exponent(ns, ts)
            out[f"{fam}_{key}_1000"] = fit_exponent(ns, ts, 1000 if fam == "chain" else 256)
    return out


def _log10(x):
    return math.log10(x) if x and x > 0 else None
