"""Orchestration of the issue-7 suites: ladders, FIM_D target, whole-process, peer, scaling;
targets with PASS/MISS; markdown sections and plots. Called by ``python -m benchmarks``."""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path

from benchmarks import floor, report, scaling, wp

IMG = "docs/img"
SMOOTH = ("pendulum_multiturn", "fourbar_spring", "slider_crank_static", "chain_20", "chain_1000")


def _log(msg):
    print(msg, file=sys.stderr, flush=True)


def run(root: Path, tmp: Path, chain_rows: list[dict], peer_small: dict | None = None,
        quick: bool = False) -> tuple[list[dict], list[str], list[tuple]]:
    """Returns (JSON rows, markdown lines, target rows)."""
    t0 = time.perf_counter()
    rows: list[dict] = []
    decks = [d for d in wp.DECKS if not (quick and d == "chain_1000")]
    wprows = []
    for d in decks:
        wprows += wp.ladder(d, quick=quick, repeat=3 if quick else 5, log=_log)
    _log(f"[issue 7] ladders done in {time.perf_counter() - t0:.0f} s")
    qs = wp.fim_d_vs_fim_s(quick=quick, log=_log)
    procs = wp.whole_process(decks, repeat=3 if quick else 5, log=_log)
    _log(f"[issue 7] FIM_D target + whole process done in {time.perf_counter() - t0:.0f} s")
    from benchmarks import peer
    peers = peer.run(quick=quick, repeat=3 if quick else 5, log=_log)
    _log(f"[issue 7] peer done in {time.perf_counter() - t0:.0f} s")
    sc = scaling.run(chain_rows, tmp, quick=quick, log=_log, budget_s=120 if quick else 600)
    _log(f"[issue 7] scaling done in {time.perf_counter() - t0:.0f} s")
    chains = [r for r in chain_rows if r.get("bench") == "chain"] + \
             [r for r in sc if r["bench"] == "chain_scaling"]
    grids = [r for r in sc if r["bench"] == "grid"]
    skips = [r for r in sc if r["bench"] == "scaling_skip"]
    fits = scaling.fits(chains, grids)
    decade = wp.decade_cost(wprows)
    load = os.getloadavg()
    for r in wprows + qs + procs + peers + sc:
        r.setdefault("loadavg", load)
    rows = wprows + qs + procs + peers + sc + [dict(bench="scaling_fits", **fits),
                                                dict(bench="decade_cost", decks=decade)]
    img = root / IMG
    plots_ok = True
    try:
        report.plot_wp(wprows, img / "work_precision.png")
        report.plot_scaling(chains, grids, fits, img / "scaling.png")
    except ImportError as e:
        plots_ok = False
        _log(f"[issue 7] no plots: {e} (install the 'bench' extra)")
    tg = targets(wprows, qs, peers, chains, grids, fits, decade) + floor.targets(chains)
    md = ["## Issue 7 targets", "",
          f"Measured by `make bench`{' (quick mode: reduced ladder and sizes)' if quick else ''}; "
          f"load average at the end {load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f} (1/5/15 min; "
          "2 cores, shared machine: times are noisy, each JSON row records its own load). "
          "Targets are never asserted in tests.", "",
          "| target | limit | measured | result |", "|---|---|---|---|"]
    for name, lim, meas, ok in tg:
        md.append(f"| {name} | {lim} | {meas} | {'—' if ok is None else ('PASS' if ok else 'MISS')} |")
    md += ["", *EXPLAIN, ""]
    md += report.wp_section(wprows, procs, qs, decade,
                            {k: v[4] for k, v in wp.DECKS.items() if k in decks}) + [""]
    md += report.peer_section(peers) + [""]
    md += report.scaling_section(chains, grids, skips, fits) + [""]
    md += floor.section(chains) + [""]
    if not plots_ok:
        md += ["*Plots not generated: matplotlib missing (`pip install -e '.[bench]'`).*", ""]
    md += [f"Issue-7 suites took {time.perf_counter() - t0:.0f} s.", ""]
    return rows, md, tg


def targets(wprows, qs, peers, chains, grids, fits, decade) -> list[tuple]:
    s = report._s
    out = []
    its = {r["deck"]: r["iterations"] for r in wprows
           if r["method"] == "FIM_S" and abs(r["tol"] - 1e-8) < 1e-20 and r["deck"] in SMOOTH}
    if not its:
        its = {r["deck"]: r["iterations"] for r in wprows
               if r["method"] == "FIM_S" and r["deck"] in SMOOTH and r["kind"] == "static"}
    if its:
        m = max(its.values())
        out.append(("FIM_S Newton iterations on smooth decks (rung 1e-8)", "≤ 6",
                    f"max {m} ({', '.join(f'{k} {v}' for k, v in its.items())})", m <= 6))
    ch = {r["n"]: r for r in chains}
    if 1000 in ch:
        v = ch[1000]["solve_s"]["median"]
        out.append(("1000-link chain solve", "≤ 0.3 s", f"{s(v)} s", v <= 0.3))
    if 10000 in ch:
        v = ch[10000]["solve_s"]["median"]
        m = ch[10000]["peak_rss_bytes"]["max"]
        out.append(("10 000-link chain solve", "≤ 3 s", f"{s(v)} s", v <= 3.0))
        out.append(("10 000-link chain peak memory", "≤ 1 GiB", f"{m / 2**20:.0f} MiB",
                    m <= 2**30))
    e = fits.get("chain_solve_s_1000")
    if e is not None:
        out.append(("fitted exponent, chain solve time (N ≥ 1000)", "≤ 1.15", f"{e:.2f}",
                    e <= 1.15))
    g = fits.get("grid_solve_s_1000")
    if g is not None:
        out.append(("fitted exponent, grid solve time (N ≥ 256, informative)", "≤ 1.15",
                    f"{g:.2f}", g <= 1.15))
    big = [(r["n"], r["iteration_per_lu"], f) for f, rows in (("chain", chains), ("grid", grids))
           for r in rows if r["n"] >= 1000 and r.get("iteration_per_lu")]
    if big:
        worst = max(big, key=lambda x: x[1])
        out.append(("time per Newton iteration / one sparse LU, N ≥ 1000", "≤ 2",
                    f"max {worst[1]:.2f} ({worst[2]} N={worst[0]}); "
                    + ", ".join(f"{f} {n}: {v:.2f}" for n, v, f in big), worst[1] <= 2.0))
    pend = next((p for p in peers if p["problem"] == "pendulum_multiturn"), None)
    if pend and pend.get("process_ratio") is not None:
        v = pend["process_ratio"]
        floor = ""
        if pend.get("floor_ratio") is not None:
            fl = pend["import_floor"]
            floor = (f"; import floor (numpy, h5py, lxml) {s(fl['normal']['median'])} s = "
                     f"{pend['floor_ratio']:.2f} × Exudyn (set up as poise "
                     f"{s(fl['as_poise']['median'])} s = {pend['floor_as_poise_ratio']:.2f} ×); "
                     f"poise above that floor {s(pend['poise_above_floor_s'])} s")
            if pend.get("numpy_ratio") is not None:
                floor += (f"; numpy alone {s(fl['numpy']['median'])} s = "
                          f"{pend['numpy_ratio']:.2f} × Exudyn")
            if pend.get("mandated_ratio") is not None:
                floor += (f"; mandated minimum (those imports + click, lxml read of the deck, "
                          f"an fsync'ed one-dataset HDF5 write) {s(fl['mandated']['median'])} s "
                          f"= {pend['mandated_ratio']:.2f} × Exudyn")
            if pend.get("batch_ratio"):
                floor += (f"; `poise batch` per deck {s(pend['batch']['j1']['median'])} s = "
                          f"{pend['batch_ratio']['j1']:.2f} × Exudyn's process (one worker)")
        out.append(("whole process, small deck (pendulum_multiturn): poise / Exudyn", "≤ 0.8",
                    f"{v:.2f} ({s(pend['poise']['process_s']['median'])} s vs "
                    f"{s(pend['exudyn']['process_s']['median'])} s){floor}", v <= 0.8))
    elif pend:
        out.append(("whole process, small deck: poise / Exudyn", "≤ 0.8", "peer unavailable", None))
    if qs:
        best = {}
        for r in qs:
            if r["status"] == "converged" and r.get("error") is not None and r["error"] <= 1e-6:
                t = r["solve_s"]["median"]
                if r["method"] not in best or t < best[r["method"]][0]:
                    best[r["method"]] = (t, r["tol"], r["error"], r.get("ida_steps"),
                                         (r.get("correction") or {}).get("seconds"))
        if "FIM_S" in best and "FIM_D" in best:
            v = best["FIM_S"][0] / best["FIM_D"][0]
            fs, fd = best["FIM_S"], best["FIM_D"]
            out.append((f"FIM_D speed-up over FIM_S, {qs[0]['frames']}-frame quasi-static run at "
                        "error ≤ 1e-6", "≥ 5×",
                        f"{v:.2f}× (FIM_S {s(fs[0])} s at rung {fs[1]:.0e}, error {fs[2]:.1e}; "
                        f"FIM_D {s(fd[0])} s at rung {fd[1]:.0e}, error {fd[2]:.1e}, "
                        f"{fd[3]} IDA steps"
                        + (f", of which {s(fd[4])} s correcting the output frames onto the "
                           "equilibrium" if fd[4] is not None else "") + ")", v >= 5))
        else:
            out.append(("FIM_D speed-up over FIM_S at error ≤ 1e-6", "≥ 5×",
                        f"a method never reached 1e-6: {sorted(best)}", False))
    if decade:
        f = [d for d in decade if d.get("per_rung")]
        if f:
            worst = max(f, key=lambda d: d["per_rung"])
            out.append(("FIM_S time factor per extra decade of accuracy (requested rung)", "≤ 1.3×",
                        f"max {worst['per_rung']:.2f}× ({worst['deck']}); "
                        + ", ".join(f"{d['deck']} {d['per_rung']:.2f}" for d in f),
                        worst["per_rung"] <= 1.3))
    return out


EXPLAIN = """\
Notes on the misses (profile in *Where the time goes* above): the chain solve and the
per-iteration/LU ratio are set by the Newton iteration = one residual + KKT Jacobian evaluation
(family kernels, assembly by `np.bincount`) plus one SuperLU factorisation with a fresh COLAMD
ordering; the kernels are being optimised separately (families/base.py, model/assembly.py,
solvers/newton.py, linalg.py) and these tables are re-measured by every `make bench`. Whole-process
time of a small deck is dominated by the interpreter and the imports of the mandated dependencies
(numpy, h5py, lxml: the *import floor* in the peer section, measured the same way), not by the
solve (≈ 0.02–0.05 s); the small-deck path imports no scipy, matplotlib or dask, the CLI imports
only the command it runs, and the process ends without interpreter finalisation. Exudyn's whole
process is Python + numpy + one C++ extension import plus a solve in microseconds: when the
*mandated minimum* (the three imports, click, reading the deck with lxml and an fsync'ed HDF5
write, measured interleaved with both processes) is above 0.8 × Exudyn, the target cannot be met
with these dependencies. Many decks in one `poise batch` pay the imports once per worker (see
*Many decks, one process*).""".splitlines()
