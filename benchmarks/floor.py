"""Big static solves against the floor of the method (issue 25 §2), from the chain rows.

For a static FIM_S solve the floor is *iterations × the LU Newton performs*: the worker
(:func:`benchmarks.chain._newton_lu`) times :class:`poise.solvers.linalg.Factor` of the KKT
matrix at the solution exactly as Newton factorises it (its column order made once per
model, not timed). Ratios are of CPU seconds (``time.process_time``, one BLAS thread) of the
same worker process, so that the load of this shared machine, which stretches wall times
unevenly, cancels; wall-time ratios are shown next to them.
"""
from __future__ import annotations

import math

SIZES = (1000, 10000, 100000)
#: fresh worker runs per size for these targets (medians): the chain table runs these sizes at
#: least this many times (other sizes ``--repeat`` times), the scaling table the sizes it adds
#: (10^5) this many times. Five, because one 10^5 run varies by ±10 % on a 2-core machine and
#: the exponent target (a ratio of two medians) needs the median to sit still.
REPEAT = 5
FLOOR_RATIO = 2.0            # solve <= 2 x iterations x Newton's LU
EXPONENT = 1.03              # solve time 10^4 -> 10^5 links
PEAK_BYTES = 1.5e9           # peak RSS at 10^5 links (GB = 10^9 bytes)
#: what a certified static solve with a stability verdict cannot leave out on these chains:
#: Newton's five iterations (3 LUs, the last two chord steps), a Jacobian at each LU, a
#: residual at each chord step and at the written state, a solve per iteration, the inertia's
#: LDL^T at the written state and the lowest mode's solves with it (5 on these chains)
LEAST = dict(lu=3, jac=3, res=3, solve=5, ldl=1, ldl_solve=5)


def verdict_parts(model, state, settings, active, repeat: int = 3) -> dict:
    """Median CPU seconds of the operations :data:`LEAST` counts, each as poise performs it at
    the solution ``state`` (a chain worker calls this after its solve): ``jac`` an evaluation
    with the KKT Jacobian assembled, ``res`` a residual-only one (two states alternate, so that
    the solve's memo of its last evaluation never answers), ``solve`` a plain solve with
    Newton's factors (no refinement), ``ldl`` the classification's LDL^T of the equilibrated
    KKT matrix (SuperLU in symmetric mode, its matrix formed, its pivots read) and
    ``ldl_solve`` one of the lowest mode's solves with it."""
    import dataclasses
    import itertools
    import statistics
    import time

    import numpy as np

    from poise.core import memory
    from poise.model.workspace import Workspace
    from poise.solvers.frames import _kkt_columns
    from poise.solvers.linalg import Factor
    from poise.solvers.stability_modes import AUG_RHO
    from poise.solvers.stability_sparse import SparsePencil

    def cpu(fn):
        fn()                                         # a first call, not timed
        ts = []
        for _ in range(repeat):
            c = time.process_time()
            fn()
            ts.append(time.process_time() - c)
        return statistics.median(ts)

    eps = float(np.sqrt(settings.stability))
    ws = Workspace()
    other = dataclasses.replace(state, lam=state.lam * (1.0 + 1e-9))
    states = itertools.cycle((state, other))
    out = {}
    out["jac"] = cpu(lambda: model.evaluate(next(states), need_jac=True, eps_mass=eps,
                                            active=active, workspace=ws))
    out["res"] = cpu(lambda: model.evaluate(next(states), need_jac=False, eps_mass=eps,
                                            active=active, workspace=ws))
    def newton_solve():
        J = model.evaluate(state, need_jac=True, eps_mass=eps, active=active, workspace=ws).J
        F = Factor(J)
        b = J @ np.random.default_rng(0).standard_normal(J.shape[0])
        return cpu(lambda: F.unchecked.solve(b))

    out["solve"] = newton_solve()              # (its matrix and factors go with the call)
    ws.clear()
    J0 = memory.hand_over(model.evaluate(state, need_jac=True, eps_mass=0.0, active=active).J)
    P = SparsePencil(model, J0, active=active, lean=True, kkt_columns=_kkt_columns(model))
    out["ldl"] = cpu(lambda: P.ldl(0.0, AUG_RHO[0]))
    L = P.ldl(0.0, AUG_RHO[0])
    v = np.random.default_rng(1).standard_normal(model.nq)
    out["ldl_solve"] = cpu(lambda: L.solve_head(v, model.nq))
    out["ldl_ok"] = bool(L.ok)
    return out


def least(r):
    """The cost of :data:`LEAST` in Newton's LUs for a chain row (None if not measured)."""
    parts, lu = r.get("verdict_parts"), _med(r, "newton_lu_cpu_s")
    if not parts or not lu:
        return None
    return LEAST["lu"] + sum(LEAST[k] * _med(parts, k) / lu for k in LEAST if k != "lu")


def _med(r, key):
    st = r.get(key)
    return st["median"] if st else None


def floor_ratio(r, cpu: bool = True):
    """``solve / (iterations x Newton's LU)`` of a chain row (None if not measured)."""
    sk, lk = ("solve_cpu_s", "newton_lu_cpu_s") if cpu else ("solve_s", "newton_lu_s")
    t, lu, it = _med(r, sk), _med(r, lk), r.get("iterations")
    if not (t and lu and it):
        return None
    return t / (it * lu)


def exponent(chains, key="solve_cpu_s"):
    """Solve-time exponent from 10^4 to 10^5 links (None unless both were measured)."""
    by = {r["n"]: r for r in chains}
    a, b = by.get(10000), by.get(100000)
    if not (a and b and _med(a, key) and _med(b, key)):
        return None
    return math.log(_med(b, key) / _med(a, key)) / math.log(10.0)


def targets(chains) -> list[tuple]:
    from benchmarks.report import _s
    by = {r["n"]: r for r in chains}
    out = []
    for n in SIZES:
        r = by.get(n)
        v = floor_ratio(r) if r else None
        if v is None:
            out.append((f"{n}-link chain: solve / (iterations × Newton's LU), CPU",
                        f"≤ {FLOOR_RATIO:g}", "not measured", None))
            continue
        out.append((f"{n}-link chain: solve / (iterations × Newton's LU), CPU",
                    f"≤ {FLOOR_RATIO:g}",
                    f"{v:.2f} ({_s(_med(r, 'solve_cpu_s'))} s / {r['iterations']} × "
                    f"{_s(_med(r, 'newton_lu_cpu_s') * 1e3)} ms; wall {_s(floor_ratio(r, False))})",
                    v <= FLOOR_RATIO and r["status"] == "converged"))
    e = exponent(chains)
    ew = exponent(chains, "solve_s")
    runs = "/".join(str(by[n].get("repeat", 1)) for n in (10000, 100000) if n in by)
    out.append(("chain solve-time exponent 10^4 → 10^5 links, CPU", f"≤ {EXPONENT:g}",
                "not measured" if e is None else
                f"{e:.3f} (wall {_s(ew)}; medians of {runs} fresh runs)",
                None if e is None else e <= EXPONENT))
    r = by.get(100000)
    # the bench worker's peak up to the end of the solve (parse, compile, solve; not its own
    # reference LU and evaluations after it) and a whole `poise solve` process's: the larger
    w = ((r.get("peak_solve_bytes") or r["peak_rss_bytes"])["max"]) if r else None
    c = r.get("cli_peak_rss_bytes") if r else None
    m = None if w is None and c is None else max(x for x in (w, c) if x is not None)
    out.append(("100 000-link chain peak memory (RSS), the larger of the bench worker through "
                "its solve and a whole `poise solve` process", "≤ 1.5 GB",
                "not measured" if m is None else
                f"{m / 1e9:.2f} GB (worker {'—' if w is None else f'{w / 1e9:.2f}'} GB, "
                f"`poise solve` {'not measured' if c is None else f'{c / 1e9:.2f} GB'})",
                None if m is None else m <= PEAK_BYTES))
    return out


def section(chains) -> list[str]:
    """Markdown: per chain size the solve, Newton's LU, the floor and the ratios."""
    from benchmarks.report import _s
    rows = sorted([r for r in chains if r.get("newton_lu_s")], key=lambda r: r["n"])
    if not rows:
        return []
    L = ["### Static solve vs its floor (issue 25 §2)", "",
         "*Floor* = iterations × one factorisation of the KKT matrix exactly as Newton performs "
         "it (`linalg.Factor`, the assembler's column order). Ratios of CPU seconds of one "
         "worker process (wall-time ratio in brackets). *Outside Newton*: redundancy detection, "
         "least-squares multipliers, output measures and stability classification. *Of it "
         "system*: the kernel's share of the solve CPU (mapping and zeroing fresh memory), "
         "with the solve's minor page faults.", "",
         "| N | iterations | solve CPU [s] | of it system [s] (page faults) | Newton's LU CPU [s] "
         "| floor CPU [s] | solve / floor | Newton wall [s] | outside Newton wall [s] | "
         "peak RSS [MiB] |",
         "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lu = _med(r, "newton_lu_cpu_s")
        nw = _med(r, "newton_s")
        flt = _med(r, "solve_faults")
        sys_s = f"{_s(_med(r, 'solve_sys_s'))} ({'—' if flt is None else f'{flt:.0f}'})"
        L.append(f"| {r['n']} | {r['iterations']} | {_s(_med(r, 'solve_cpu_s'))} | {sys_s} | "
                 f"{_s(lu)} | "
                 f"{_s(lu * r['iterations'])} | {_s(floor_ratio(r))} "
                 f"({_s(floor_ratio(r, False))}) | {_s(nw)} | "
                 f"{_s(_med(r, 'solve_s') - nw if nw is not None else None)} | "
                 f"{r['peak_rss_bytes']['max'] / 2**20:.0f} |")
    L += _phases(rows)
    L += _least(rows)
    return L


def _least(rows) -> list[str]:
    """Markdown: what a certified solve with a stability verdict cannot leave out
    (:data:`LEAST`), each part in Newton's LUs, against the target's budget."""
    from benchmarks.report import _s
    rows = [r for r in rows if least(r) is not None]
    if not rows:
        return []
    c = LEAST
    L = ["", f"What a solve with a certified verdict cannot leave out on these chains, each "
         f"part timed alone at the solution in the same worker (CPU, median) and given in "
         f"Newton's LUs: Newton's {c['lu']} LUs, {c['jac']} Jacobians (evaluation and "
         f"assembly) and {c['res']} residual-only evaluations (the chord steps' and the "
         f"written state's), {c['solve']} solves with Newton's factors (no refinement), the "
         "inertia's LDLᵀ at the written state (an LU with partial pivoting has no inertia; "
         "SuperLU in symmetric mode, its matrix formed and its pivots read) and the lowest "
         f"mode's {c['ldl_solve']} solves with it. *Left* is what the target (≤ "
         f"{FLOOR_RATIO:g} × iterations) leaves for everything else a verdict needs: "
         "redundancy detection (these closed chains have redundant rows), initial "
         "multipliers, the line search, refinement, reactions, outputs and the kernel's "
         "fresh pages.", "",
         "| N | Newton's LU [ms] | Jacobian | residual | solve | LDLᵀ | LDLᵀ solve | least | "
         "target | left | measured solve |", "|---" * 11 + "|"]
    for r in rows:
        lu, p = _med(r, "newton_lu_cpu_s"), r["verdict_parts"]
        budget = FLOOR_RATIO * r["iterations"]
        cells = [f"{_med(p, k) / lu:.2f}" for k in ("jac", "res", "solve", "ldl", "ldl_solve")]
        L.append(f"| {r['n']} | {_s(lu * 1e3)} | " + " | ".join(cells)
                 + f" | **{least(r):.1f}** | {budget:g} | {budget - least(r):.1f} | "
                 f"{_med(r, 'solve_cpu_s') / lu:.1f} |")
    return L


PHASES = ("redundancy", "multipliers", "newton", "stability")


def _phases(rows) -> list[str]:
    """Markdown: CPU seconds of the solve's phases in Newton's LUs, and where the peak RSS is
    reached (after parse, compile, each phase; MiB)."""
    from benchmarks.report import _s
    rows = [r for r in rows if r.get("phases_cpu") and r.get("peak_parse_bytes")]
    if not rows:
        return []
    L = ["", "Phases of the same solves: CPU seconds, and in brackets in Newton's LUs (the "
         "floor's unit); *peak after* is the worker's peak RSS once parse, compile and each "
         "phase have run, then the solve, then the whole worker with the bench's own LU and "
         "evaluation timings (MiB).", "",
         "| N | " + " | ".join(PHASES) + " | other | peak after parse | after compile | "
         + " | ".join(f"after {p}" for p in PHASES) + " | after solve | whole worker |",
         "|---" * (2 * len(PHASES) + 6) + "|"]
    for r in rows:
        lu = _med(r, "newton_lu_cpu_s")
        cpu = {p: (r["phases_cpu"].get(p) or {}).get("median") for p in PHASES}
        other = _med(r, "solve_cpu_s") - sum(v for v in cpu.values() if v)
        cells = [f"{_s(v)} ({v / lu:.1f})" if v is not None else "—" for v in cpu.values()]
        peaks = [(r["phases_peak"].get(p) or {}).get("max") for p in PHASES]
        L.append(f"| {r['n']} | " + " | ".join(cells) + f" | {_s(other)} ({other / lu:.1f}) | "
                 f"{r['peak_parse_bytes']['max'] / 2**20:.0f} | "
                 f"{r['peak_compile_bytes']['max'] / 2**20:.0f} | "
                 + " | ".join("—" if v is None else f"{v / 2**20:.0f}" for v in peaks) + " | "
                 + " | ".join("—" if v is None else f"{v / 2**20:.0f}" for v in (
                     (r.get("peak_solve_bytes") or {}).get("max"), r["peak_rss_bytes"]["max"]))
                 + " |")
    return L
