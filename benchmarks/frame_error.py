"""The "frame error" table of ``make bench`` (issue 22 §7): does ``frames/error`` bound the true
error of every quasi-static frame?

Every quasi-static deck of ``decks/bench`` and ``decks/`` (``qs_*``, ``*_qs``) and a soft block
whose load reverses (an SHF turning point, ``tests/support/linkages.py``) is solved with FIM_S and
FIM_D at its own tolerances and at the defaults (``max_imbalance`` = ``max_error`` = 1e-4); each
frame's true error is measured against a tight FIM_S solve of the same deck (``max_imbalance`` =
``max_error`` = 1e-12): the largest CG displacement / L and the largest rotation [rad] between
the two states, the measure ``max_error`` and ``frames/error`` use. A row passes when no frame's
true error exceeds its reported error (plus 1e-12 of round-off).
``python -m benchmarks --only path`` runs this table and the singular-configuration table
alone.
"""
from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.decks import BENCH_DIR, ROOT, support_module

ROUNDOFF = 1e-12
DEFAULTS = {"max_imbalance": 1e-4, "max_error": 1e-4}
TIGHT = {"method": "FIM_S", "max_imbalance": 1e-12, "max_error": 1e-12, "max_num_iter": 200}


def _linkages():
    return support_module("linkages")


def table(columns, cells, rows) -> list[str]:
    """Markdown table of ``cells`` (one tuple per row) and a last column, PASS or MISS, from
    each row's ``ok``."""
    return (["| " + " | ".join(columns) + " | result |", "|---" * (len(columns) + 1) + "|"]
            + ["| " + " | ".join(map(str, c)) + f" | {'PASS' if r['ok'] else 'MISS'} |"
               for c, r in zip(cells, rows)])


def close_table(md: list, what: str, t0: float, rows, target: str, limit: str, detail: str):
    """End a table's markdown (``md``, in place) with its duration; its target row passes when
    every row passed (``ok``)."""
    md += ["", f"{what} table took {time.perf_counter() - t0:.0f} s.", ""]
    n_bad = sum(not r["ok"] for r in rows)
    return [(target, limit, f"{n_bad} of {len(rows)} rows missed, {detail}", n_bad == 0)]


def decks(tmp: Path, quick: bool = False) -> list[Path]:
    """The quasi-static decks of the table."""
    out = [BENCH_DIR / "slider_crank_qs.xml"]
    if not quick:
        out.append(BENCH_DIR / "slider_crank_qs_1000.xml")
    out += sorted((ROOT / "decks").glob("qs_*.xml")) + sorted((ROOT / "decks").glob("*_qs.xml"))
    shf = Path(_linkages().shf_reversal(interval=0.02).write(tmp / "shf_reversal_qs.xml"))
    return out + [shf]


def true_errors(a, ref, L) -> np.ndarray:
    """Per frame: the largest CG displacement / L and rotation angle [rad] between the frames
    of analysis ``a`` and the reference analysis ``ref`` (frames paired by index)."""
    n = min(len(a.datasets["time"]), len(ref.datasets["time"]))
    P, P0 = (np.asarray(x.datasets["bodies/position"])[:n] for x in (a, ref))
    R, R0 = (np.asarray(x.datasets["bodies/orientation"])[:n] for x in (a, ref))
    dp = np.linalg.norm(P - P0, axis=2).max(axis=1, initial=0.0) / L
    # rotation angle of R R0^T from the Frobenius distance: |R - R0|_F = 2 sqrt(2) sin(angle / 2)
    f = np.linalg.norm((R - R0).reshape(n, R.shape[1], 9), axis=2)
    ang = 2.0 * np.arcsin(np.minimum(f / math.sqrt(8.0), 1.0)).max(axis=1, initial=0.0)
    return np.maximum(dp, ang)


def run(tmp: Path, log=print, quick: bool = False):
    """Returns (JSON rows, markdown lines, target rows)."""
    from poise.app.api import run_deck
    t0 = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory(prefix="poise-ferr-", dir=tmp) as td:
        for path in decks(Path(td), quick):
            ref = run_deck(str(path), overrides=TIGHT)
            L = float(ref.model_datasets.get("length_scale", 1.0))
            r0 = ref.analyses[0]
            for method in ("FIM_S", "FIM_D"):
                for label, over in (("deck", {}), ("defaults", DEFAULTS)):
                    res = run_deck(str(path), overrides=dict(over, method=method))
                    a = res.analyses[0]
                    true = true_errors(a, r0, L)
                    rep = np.asarray(a.datasets["frames/error"])[:len(true)]
                    ok = np.asarray(a.datasets["frames/converged"])[:len(true)].astype(bool)
                    bad = ok & ~(true <= rep + ROUNDOFF)
                    with np.errstate(divide="ignore", invalid="ignore"):
                        ratio = np.where(ok & (true > ROUNDOFF), true / rep, 0.0)
                    k = int(np.argmax(ratio)) if len(ratio) else 0
                    row = dict(bench="frame_error", deck=path.stem, method=method,
                               tolerances=label, status=a.status, reference=r0.status,
                               frames=int(len(true)),
                               max_reported=float(np.max(rep, initial=0.0)),
                               max_true=float(np.max(true, initial=0.0)),
                               worst_ratio=float(ratio[k]) if len(ratio) else 0.0,
                               worst_time=float(np.asarray(a.datasets["time"])[k])
                               if len(ratio) else 0.0,
                               violations=int(bad.sum()), ok=bool(not bad.any()))
                    rows.append(row)
                    log(f"frame error {path.stem} {method} {label}: {a.status}, "
                        f"{row['frames']} frames, reported <= {row['max_reported']:.2e}, true "
                        f"<= {row['max_true']:.2e}, worst true/reported {row['worst_ratio']:.3g}"
                        f", {row['violations']} violations")
    md = ["## Frame error bounds (issue 22 §7)", "",
          "Every quasi-static deck, FIM_S and FIM_D, at the deck's tolerances and at the "
          "defaults (1e-4): `frames/error` against the true error of each frame, measured against "
          "a tight FIM_S solve (1e-12) as the largest CG displacement / L and rotation [rad]. "
          "*worst true/reported* is the largest ratio over the frames (frames whose true error is "
          "round-off, below 1e-12, are not counted); a row passes when no frame's true error "
          "exceeds its reported error.", ""]
    md += table(["deck", "method", "tolerances", "status", "frames", "max reported", "max true",
                 "worst true/reported (t)"],
                [(r["deck"], r["method"], r["tolerances"], r["status"], r["frames"],
                  f"{r['max_reported']:.2e}", f"{r['max_true']:.2e}",
                  f"{r['worst_ratio']:.3g} ({r['worst_time']:.3g})") for r in rows], rows)
    worst = max((r["worst_ratio"] for r in rows), default=0.0)
    return rows, md, close_table(md, "Frame-error", t0, rows,
                                 "frame error: reported bounds true on every quasi-static frame",
                                 "0 rows missed", f"worst true/reported {worst:.3g}")
