"""What accuracy costs on one deck: a deck's variants over a tolerance ladder, timed in-process.

``poise bench DECK`` (``poise_cli.bench``) and the work-precision benchmarks
(``benchmarks/wp.py``) share these: the ladder rung's solver attributes
(:func:`method_settings`), the deck with those attributes written in (:func:`with_settings`) and
one timed point, a warm-up then the median of ``repeat`` runs (:func:`run_point`).
"""
from __future__ import annotations

import statistics
import time
from functools import partial
from pathlib import Path

import numpy as np

from poise.app import runner


def method_settings(method: str, tol: float) -> tuple[dict, dict | None]:
    """(Param_Static, Param_Transient) attributes of one rung of the ladder.

    * FIM_S: ``max_imbalance = max_error = tol``.
    * MKEAM: ``max_ke_tol = max_dq_tol = tol`` and, since MKEAM ends with a Newton polish to the
      FIM tolerances, ``max_imbalance = max_error = tol`` too.
    * FIM_D: ``dae_constr_tol = integr_tol = tol`` (IDA rtol) and ``max_imbalance = max_error =
      tol`` for the initial static solution.
    """
    t = f"{tol:.1E}"
    if method == "FIM_S":
        return dict(method="FIM_S", max_imbalance=t, max_error=t), None
    if method == "MKEAM":
        return dict(method="MKEAM", max_ke_tol=t, max_dq_tol=t, max_imbalance=t, max_error=t,
                    max_num_iter="200"), None
    if method == "FIM_D":
        return (dict(method="FIM_D", max_imbalance=t, max_error=t),
                dict(dae_constr_tol=t, integr_tol=t))
    raise ValueError(method)


def with_settings(xml_text: str, static: dict, transient: dict | None = None) -> bytes:
    """The deck with every ``Param_Static`` (model and command) given ``static`` attributes and
    the model's ``Param_Transient`` given ``transient`` (inserted when missing)."""
    from lxml import etree
    root = etree.fromstring(xml_text.encode() if isinstance(xml_text, str) else xml_text)
    model = root.find("Model")
    ps = [e for e in root.iter() if isinstance(e.tag, str) and e.tag == "Param_Static"]
    if not ps:
        el = etree.SubElement(model, "Param_Static")
        model.remove(el)
        model.insert(0, el)
        ps = [el]
    for e in ps:
        for k, v in static.items():
            e.set(k, str(v))
    if transient:
        pt = [e for e in model if isinstance(e.tag, str) and e.tag == "Param_Transient"]
        if not pt:
            el = etree.Element("Param_Transient")
            model.insert(0, el)
            pt = [el]
        for e in pt:
            for k, v in transient.items():
                e.set(k, str(v))
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8")


def stats(xs):
    """Median, min, max and count of the values that are not None (None when there are none)."""
    xs = [x for x in xs if x is not None]
    if not xs:
        return None
    return dict(median=statistics.median(xs), min=min(xs), max=max(xs), n=len(xs))


def run_point(xml_text: str, static: dict, transient: dict | None, repeat: int, tmpdir: Path,
              warmup: bool = True, allow_user_code: bool = False) -> tuple[dict, object]:
    """Solve one deck variant ``repeat`` times in this process (after one warm-up run);
    ``allow_user_code``: run its Python user routines (scripts next to ``tmpdir/variant.xml``).
    Returns the row (status, counts, timings, imbalance, ...) and the last run's RunResult."""
    # quiet: no per-solve progress lines inside a timed ladder (the caller shows its rungs)
    run_deck = partial(runner.run_deck, allow_user_code=allow_user_code, quiet=True)
    p = tmpdir / "variant.xml"
    p.write_bytes(with_settings(xml_text, static, transient))
    ov = {"fallback": False}
    if warmup:
        tw = time.perf_counter()
        run_deck(str(p), overrides=ov)
        if time.perf_counter() - tw > 2.0:      # long runs: 3 repetitions instead of 5
            repeat = min(repeat, 3)
    walls, solves, res = [], [], None
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        res = run_deck(str(p), overrides=ov)
        walls.append(time.perf_counter() - t0)
        solves.append(res.timings.get("solve"))
    an = res.analyses
    iters = int(sum(int(np.sum(a.datasets.get("frames/iterations", [0]))) for a in an))
    imb = [float(np.max(a.datasets["frames/imbalance"])) for a in an
           if len(a.datasets.get("frames/imbalance", []))]
    out = dict(status="converged" if all(a.status == "converged" for a in an) else "failed",
               message="; ".join(str(a.message) for a in an if a.status != "converged"),
               iterations=iters, frames=int(sum(len(a.datasets.get("time", [0])) for a in an)),
               counts=dict(res.counts), solve_s=stats(solves), total_s=stats(walls),
               parse_s=res.timings.get("parse"), compile_s=res.timings.get("compile"),
               imbalance=max(imb) if imb else None)
    steps = [int(a.attrs["ida_steps"]) for a in an if "ida_steps" in a.attrs]
    if steps:
        out["ida_steps"] = sum(steps)
    # FIM_D: cost of bringing the output frames onto the equilibrium (fim_d.Corrector), from
    # the last repetition: frames, corrections, residual evaluations, factorisations, full
    # Newton fallbacks, seconds
    corr = {}
    for a in an:
        for k, v in a.attrs.items():
            if k.startswith("correction_"):
                corr[k[len("correction_"):]] = corr.get(k[len("correction_"):], 0) + v
    if corr:
        out["correction"] = corr
    return out, res
