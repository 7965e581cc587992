"""Work-precision ladders: every applicable method of every benchmark deck over a tolerance ladder,
timed in-process (warm-up + median of ``repeat`` runs), with the achieved error against an
independent reference.

Error metric: ``max over frames and bodies |x_cg - x_cg,ref| / L`` (CG positions, ``L`` = the
model's length scale ``/model/length_scale``), i.e. relative to model size, the measure of
``tests/reference/test_decks_reference.py``. References (documented per deck in :data:`DECKS`):
closed forms from ``tests/support/reference.py`` (numpy/scipy only, never poise).
"""
from __future__ import annotations

import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.decks import BENCH_DIR, support_module
from poise.app import ladder as ladder_mod
from poise.app.ladder import method_settings, with_settings  # noqa: F401 (re-exported)

# --------------------------------------------------------------------------- ladders
FULL_RUNGS = [10.0 ** -k for k in range(2, 11)]             # 1e-2 ... 1e-10, every decade
SPARSE_RUNGS = [10.0 ** -k for k in (2, 4, 6, 8, 10)]        # every second decade
QUICK_RUNGS = [10.0 ** -k for k in (2, 6, 10)]




# --------------------------------------------------------------------------- references
def _reference_module():
    return support_module("reference")


def _ref_pendulum(ref, times):
    return {2: ref.pendulum_multiturn()["cg"][None, :]}


def _ref_fourbar(ref, times):
    r = ref.fourbar_equilibrium()
    cg = r["cg"]
    return {2: cg["crank"][None], 3: cg["coupler"][None], 4: cg["rocker"][None]}


def _ref_slider(ref, times):
    cg = ref.slider_crank()["cg"]
    return {2: cg["crank"][None], 3: cg["rod"][None], 4: cg["slider"][None]}


def _ref_slider_qs(ref, times):
    out = {2: [], 3: [], 4: []}
    for t in times:
        p = dict(ref.SLIDER_CRANK_PARAMS, fx=-60.0 * float(t))
        cg = ref.slider_crank(p)["cg"]
        for b, k in ((2, "crank"), (3, "rod"), (4, "slider")):
            out[b].append(cg[k])
    return {b: np.array(v) for b, v in out.items()}


def _ref_chain(n):
    def f(ref, times):
        cg = ref.catenary(n)["cg"]
        return {k + 2: cg[k][None] for k in range(n)}
    return f


def _ref_contact(ref, times):
    m, k, e, radius = 1.0, 1000.0, 1.5, 50.0
    pen = (ref.weight(m) / k) ** (1.0 / e)
    return {2: np.array([[0.0, radius - pen, 0.0]])}


# name -> (file, kind, methods, reference fn, reference description, ladder)
DECKS = {
    "pendulum_multiturn": ("pendulum_multiturn.xml", "static", ("FIM_S", "MKEAM"), _ref_pendulum,
                           "closed form: brentq root of −k(θ − θ₀) − m g l cos θ (3.14 turns)"),
    "fourbar_spring": ("fourbar_spring.xml", "static", ("FIM_S", "MKEAM"), _ref_fourbar,
                       "closed-form loop closure + brentq on dV/dφ (redundant: 3 equations)"),
    "slider_crank_static": ("slider_crank_static.xml", "static", ("FIM_S", "MKEAM"), _ref_slider,
                            "virtual work, brentq on analytic dV/dφ"),
    "slider_crank_qs": ("slider_crank_qs.xml", "quasistatic", ("FIM_S", "FIM_D"), _ref_slider_qs,
                        "virtual work per frame (fx = −60 t N), 101 frames"),
    "chain_20": ("chain_20.xml", "static", ("FIM_S", "MKEAM"), _ref_chain(20),
                 "closed-form discrete catenary (`reference.catenary`)"),
    "chain_1000": ("chain_1000.xml", "static", ("FIM_S",), _ref_chain(1000),
                   "closed-form discrete catenary; MKEAM not laddered (see note)"),
    "contact_sphere_plane": ("contact_sphere_plane.xml", "static", ("FIM_S", "MKEAM"),
                             _ref_contact, "closed form: penetration (m g / k)^(1/e)"),
}


def deck_error(res, ref_fn, ref_mod) -> float:
    """Max CG position error over frames and bodies / model length scale."""
    L = float(res.model_datasets.get("length_scale", 1.0))
    err = 0.0
    for a in res.analyses:
        d = a.datasets
        ids = list(np.asarray(d["bodies/id"]).astype(int))
        pos = np.asarray(d["bodies/position"])           # (F, B, 3)
        times = np.asarray(d.get("time", np.zeros(pos.shape[0])))
        want = ref_fn(ref_mod, times)
        for b, xr in want.items():
            x = pos[:, ids.index(b), :]
            if xr.shape[0] == 1 and x.shape[0] > 1:
                x = x[-1:]
            err = max(err, float(np.max(np.abs(x - xr))))
    return err / L




def run_point(xml_text: str, static: dict, transient: dict | None, repeat: int, tmpdir: Path,
              ref_fn=None, ref_mod=None, warmup: bool = True,
              allow_user_code: bool = False) -> dict:
    """:func:`poise.app.ladder.run_point` plus, with ``ref_fn``, the error against the reference."""
    out, res = ladder_mod.run_point(xml_text, static, transient, repeat, tmpdir, warmup=warmup,
                                    allow_user_code=allow_user_code)
    if ref_fn is not None:
        out["error"] = deck_error(res, ref_fn, ref_mod)
    return out


def ladder(name: str, quick: bool = False, repeat: int = 5, log=print) -> list[dict]:
    """All methods × rungs of one benchmark deck."""
    file, kind, methods, ref_fn, ref_doc = DECKS[name]
    xml = (BENCH_DIR / file).read_text()
    ref_mod = _reference_module()
    rows = []
    with tempfile.TemporaryDirectory(prefix="poise-wp-") as td:
        for method in methods:
            if quick:
                rungs = QUICK_RUNGS if method != "MKEAM" else QUICK_RUNGS[:2]
            elif method == "FIM_S" and kind == "static":
                rungs = FULL_RUNGS
            else:
                rungs = SPARSE_RUNGS
            for tol in rungs:
                st, tr = method_settings(method, tol)
                t0 = time.perf_counter()
                r = run_point(xml, st, tr, repeat, Path(td), ref_fn, ref_mod)
                r.update(bench="wp", deck=name, file=f"decks/bench/{file}", kind=kind,
                         method=method, tol=tol, settings=dict(static=st, transient=tr),
                         repeat=repeat, reference=ref_doc, loadavg=os.getloadavg())
                log(f"wp {name} {method} tol={tol:.0e}: {r['status']}, "
                    f"solve {r['solve_s']['median']:.3g} s, {r['iterations']} it, "
                    f"err {r.get('error', float('nan')):.2e} ({time.perf_counter() - t0:.1f} s)")
                rows.append(r)
    return rows


def fim_d_vs_fim_s(quick: bool = False, log=print) -> list[dict]:
    """The FIM_D target: ≥ 1000-frame quasi-static run, FIM_D vs FIM_S at error ≤ 1e-6.
    Each rung runs once (a run is seconds long; no warm-up needed beyond the first import)."""
    file = "slider_crank_qs.xml" if quick else "slider_crank_qs_1000.xml"
    xml = (BENCH_DIR / file).read_text()
    ref_mod = _reference_module()
    rows = []
    rungs = {"FIM_S": [1e-4, 1e-6, 1e-8], "FIM_D": [1e-4, 1e-6, 1e-8]}
    with tempfile.TemporaryDirectory(prefix="poise-wp-") as td:
        for method, tols in rungs.items():
            for tol in tols:
                st, tr = method_settings(method, tol)
                r = run_point(xml, st, tr, 1, Path(td), _ref_slider_qs, ref_mod, warmup=False)
                r.update(bench="qs_target", deck=Path(file).stem, file=f"decks/bench/{file}",
                         method=method, tol=tol, settings=dict(static=st, transient=tr))
                c = r.get("correction")
                log(f"qs target {method} tol={tol:.0e}: {r['status']}, {r['frames']} frames, "
                    f"solve {r['solve_s']['median']:.3g} s, err {r['error']:.2e}"
                    + (f", output-frame correction {c['seconds']:.3g} s ({c['corrections']} "
                       f"corrections, {c['newton']} full Newton)" if c else ""))
                rows.append(r)
    return rows


def whole_process(names, repeat: int = 5, log=print) -> list[dict]:
    """``poise solve decks/bench/X.xml -o tmp.h5`` wall time (process start → HDF5 written)."""
    from benchmarks.chain import _poise_cmd, _wall
    rows = []
    with tempfile.TemporaryDirectory(prefix="poise-wp-") as td:
        for name in names:
            file = DECKS[name][0] if name in DECKS else f"{name}.xml"
            rep = repeat if name != "chain_1000" and "qs" not in name else max(3, repeat // 2)
            st, rc = _wall(_poise_cmd() + ["solve", str(BENCH_DIR / file), "-o",
                                           str(Path(td) / "o.h5")], rep)
            rows.append(dict(bench="process", deck=name, file=f"decks/bench/{file}",
                             command=f"poise solve decks/bench/{file} -o out.h5", wall_s=st,
                             returncode=rc, repeat=rep))
            log(f"process {name}: {st['median']:.3g} s (rc {rc})")
    return rows


def decade_cost(rows: list[dict]) -> list[dict]:
    """FIM_S cost per extra decade of achieved accuracy, per deck: least-squares slope of
    log10(solve time) vs −log10(error) over converged rungs -> time factor per decade."""
    out = []
    for deck in dict.fromkeys(r["deck"] for r in rows):
        pts = [(r["error"], r["solve_s"]["median"]) for r in rows
               if r["deck"] == deck and r["method"] == "FIM_S" and r["status"] == "converged"
               and r.get("error") and r["error"] > 0]
        errs = sorted({e for e, _ in pts})
        if len(errs) < 2 or math.log10(max(errs) / min(errs)) < 0.5:
            continue
        x = np.array([-math.log10(e) for e, _ in pts])
        y = np.array([math.log10(t) for _, t in pts])
        slope = float(np.polyfit(x, y, 1)[0])
        d = dict(deck=deck, factor_per_decade=10.0 ** slope, decades=float(x.max() - x.min()))
        by_tol = {r["tol"]: r["solve_s"]["median"] for r in rows
                  if r["deck"] == deck and r["method"] == "FIM_S" and r["status"] == "converged"}
        lo, hi = max(by_tol), min(by_tol)
        if lo > hi:
            d["per_rung"] = (by_tol[hi] / by_tol[lo]) ** (1.0 / math.log10(lo / hi))
        out.append(d)
    return out
