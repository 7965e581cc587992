"""The "time to a singular configuration" table of ``make bench`` (issue 22 §2): a quasi-static
run that reaches a singular configuration must say so within a few seconds, exit 1, with the
located time of the closed form.

The mechanisms of ``tests/support/linkages.py`` (closed forms there): a slider-crank whose
slider is driven through its toggle and one driven beyond its reach, the dead point of a
crank-rocker four-bar, the workspace boundary of a delta-like 3-RUU robot, the limit point of a
von Mises truss and the bifurcation of a loaded column, each with FIM_S and FIM_D. Each is
paired with its healthy counterpart, the same deck ended at 90 % of the singular time (the same
path up to there, without the singular point). Whole ``poise solve`` processes (start-up,
solve, results file written), round-robin after one warm-up run each
(``benchmarks.chain._walls``). A row passes when the run ends ``singular_configuration`` of
the expected kind, exit 1, at the closed-form time (within ``TIME_TOL``), in at most
``LIMIT_S`` seconds. ``python -m benchmarks --only path`` runs this table and the frame-error
table alone.
"""
from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path

from benchmarks.chain import _poise_cmd, _walls
from benchmarks.frame_error import _linkages, close_table, table

LIMIT_S = 3.0            # "within a few seconds", whole process
TIME_TOL = 1e-6          # located time against the closed form
HEALTHY_FRACTION = 0.9   # the healthy counterpart ends at this fraction of the singular time
METHODS = ("FIM_S", "FIM_D")


def cases(L) -> list[tuple]:
    """``(name, deck builder(method), closed-form singular time, kind)``."""
    return [
        ("slider-crank driven through its toggle",
         lambda m: L.slider_crank("300+150*TIME", m), 2.0 / 3.0, "dead_point"),
        ("slider-crank driven beyond its reach",
         lambda m: L.slider_crank("300+200*TIME", m), 0.5, "dead_point"),
        ("four-bar at its dead point", lambda m: L.fourbar(60.0, m),
         L.fourbar_dead_time(60.0), "dead_point"),
        ("delta robot (3-RUU) at its boundary", lambda m: L.delta("-60D*TIME", m),
         (90.0 - L.delta_boundary_angle()) / 60.0, "dead_point"),
        ("von Mises truss at its limit point", lambda m: L.vonmises(m),
         L.vonmises_limit_time(), "limit_point"),
        ("loaded column at its bifurcation", lambda m: L.column(m),
         L.column_critical_time(), "bifurcation"),
    ]


def _ended(deck, end: float):
    """``deck`` with its ``Simulate`` ending at ``end`` (the print interval kept)."""
    deck.commands = [c.replace('end_time="1.0"', f'end_time="{end!r}"') for c in deck.commands]
    if not any(f'end_time="{end!r}"' in c for c in deck.commands):
        raise ValueError("the deck's Simulate does not end at 1.0")
    return deck


def _verdict(h5: Path) -> dict:
    import h5py  # lazy: only when the table runs
    with h5py.File(h5, "r") as f:
        a = f["analysis_000"]
        status = a["frames/status"][-1]
        els = json.loads(a.attrs.get("singular_elements", "[]") or "[]")
        return dict(status=status.decode() if isinstance(status, bytes) else str(status),
                    singular_time=float(a.attrs.get("singular_time", math.nan)),
                    kind=str(a.attrs.get("singular_kind", "")),
                    first_element=(f"{els[0]['tag']} {els[0]['id']} ({els[0]['label']})"
                                   if els else ""))


def run(tmp: Path, log=print, quick: bool = False):
    """Returns (JSON rows, markdown lines, target rows)."""
    L = _linkages()
    t0 = time.perf_counter()
    cmds, meta = {}, {}
    for name, build, t_star, kind in cases(L):
        for m in METHODS:
            stem = f"{len(meta):02d}"
            sing = build(m).write(tmp / f"singular_{stem}.xml")
            ok = _ended(build(m), HEALTHY_FRACTION * t_star).write(tmp / f"healthy_{stem}.xml")
            cmds[("singular", stem)] = _poise_cmd() + ["solve", str(sing), "-o",
                                                       str(tmp / f"singular_{stem}.h5")]
            cmds[("healthy", stem)] = _poise_cmd() + ["solve", str(ok), "-o",
                                                      str(tmp / f"healthy_{stem}.h5")]
            meta[stem] = (name, m, t_star, kind)
    load = [os.getloadavg()[0]]
    walls = _walls(cmds, 1 if quick else 3)
    load.append(os.getloadavg()[0])
    rows = []
    for stem, (name, m, t_star, kind) in meta.items():
        (ws, rc), (wh, rch) = walls[("singular", stem)], walls[("healthy", stem)]
        v = _verdict(tmp / f"singular_{stem}.h5")
        dt = abs(v["singular_time"] - t_star)
        row = dict(bench="singular", case=name, method=m, exit_code=rc, healthy_exit_code=rch,
                   wall_s=ws["median"], healthy_wall_s=wh["median"],
                   ratio=ws["median"] / wh["median"], expected_time=t_star,
                   located_time=v["singular_time"], time_error=dt, expected_kind=kind,
                   kind=v["kind"], status=v["status"], named=v["first_element"])
        row["ok"] = bool(rc == 1 and rch == 0 and v["status"] == "singular_configuration"
                         and v["kind"] == kind and dt <= TIME_TOL and ws["median"] <= LIMIT_S)
        rows.append(row)
        log(f"singular {name} {m}: {v['status']} ({v['kind']}) at t = {v['singular_time']:.7g} "
            f"(closed form {t_star:.7g}), exit {rc}, {ws['median']:.2f} s (healthy "
            f"{wh['median']:.2f} s)")
    md = ["## Time to a singular configuration (issue 22 §2)", "",
          "Quasi-static runs that reach a singular configuration (`tests/support/linkages.py`, "
          "closed forms there), whole `poise solve` processes, median of "
          f"{1 if quick else 3} runs; *healthy*: the same deck ended at "
          f"{HEALTHY_FRACTION:.0%} of the singular time. A row passes when the run ends "
          "`singular_configuration` of the expected kind, exit 1, at the closed-form time "
          f"(within {TIME_TOL:g}), in at most {LIMIT_S:g} s. Load average (1 min) before and "
          f"after: {load[0]:.1f}, {load[1]:.1f} (wall times grow with it on a shared machine).",
          ""]
    md += table(["case", "method", "verdict", "located t (error vs closed form)",
                 "joint named first", "wall [s]", "healthy [s]", "ratio"],
                [(r["case"], r["method"], f"{r['status']}, {r['kind']}, exit {r['exit_code']}",
                  f"{r['located_time']:.9g} ({r['time_error']:.1e})", r["named"] or "–",
                  f"{r['wall_s']:.2f}", f"{r['healthy_wall_s']:.2f}", f"{r['ratio']:.2f}")
                 for r in rows], rows)
    worst = max((r["wall_s"] for r in rows), default=0.0)
    return rows, md, close_table(
        md, "Singular-configuration", t0, rows,
        "singular configurations: located, named and exit 1 within a few seconds",
        f"every row <= {LIMIT_S:g} s at the closed-form time", f"slowest {worst:.2f} s")
