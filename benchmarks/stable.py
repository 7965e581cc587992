"""The "stable equilibria" table of ``make bench``: MKEAM and ``--require-stable`` against plain
FIM_S on hanging chains (``poise.gen.chain``), each answer checked against the discrete
catenary (closed form up to one scalar root, :func:`catenary_cgs`), every time a ratio to FIM_S
in the same run. ``python -m benchmarks --only stable`` runs this table alone.

Decks: ``arc`` = the generator's default start (a circular arc near the catenary, span
0.8 N a); ``V`` = two straight legs (``start="v"``), span 0.6 N a (at 0.8 N a plain FIM_S from
the 1000-link V does not converge at all, which would leave nothing to compare).
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

A = 100.0
V_SPAN = 0.6
SCALING = (100, 300, 1000, 3000)


def catenary_cgs(n, a=A, span=None):
    """Link CG positions (n, 2) of the discrete catenary: ``tan th_i = (w (i - 1/2) - V0) / H``
    with ``V0 = N w / 2``; H the root of ``a sum cos th_i = span``."""
    from scipy.optimize import brentq
    span = 0.8 * n * a if span is None else span
    i = np.arange(1, n + 1)

    def tan_th(H):
        return (i - 0.5 - n / 2) / H

    H = brentq(lambda H: a * np.sum(1.0 / np.sqrt(1.0 + tan_th(H) ** 2)) - span,
               1e-9, 1e9, xtol=1e-14, rtol=1e-15)
    th = np.arctan(tan_th(H))
    nodes = np.vstack([[0.0, 0.0], np.cumsum(a * np.c_[np.cos(th), np.sin(th)], axis=0)])
    return 0.5 * (nodes[:-1] + nodes[1:])


def fourbar_deck(root: Path, phi: float) -> str:
    """decks/fourbar_spring.xml with the linkage placed at crank angle ``phi`` (exact loop
    closure: crank A-B 150, coupler B-C 350, rocker D-C 250, A=(0,0), D=(400,0), elbow up)."""
    import re
    A, D = np.array([0.0, 0.0]), np.array([400.0, 0.0])
    a, b, c = 150.0, 350.0, 250.0
    B = A + a * np.array([math.cos(phi), math.sin(phi)])
    bd = D - B
    d = float(np.linalg.norm(bd))
    u = bd / d
    h = (d * d + b * b - c * c) / (2 * d)
    C = B + h * u + math.sqrt(b * b - h * h) * np.array([-u[1], u[0]])

    def rz(v):
        t = math.atan2(v[1], v[0])
        return np.array([[math.cos(t), -math.sin(t), 0.0], [math.sin(t), math.cos(t), 0.0],
                         [0.0, 0.0, 1.0]])

    Rc, Ro, Rr = rz(B - A), rz(C - B), rz(C - D)
    place = {200: ((A + B) / 2, Rc), 201: (A, Rc), 202: (B, Rc), 300: ((B + C) / 2, Ro),
             301: (B, Ro), 302: (C, Ro), 400: ((C + D) / 2, Rr), 401: (C, Rr), 402: (D, Rr)}

    def sub(m):
        mid = int(m.group(1))
        if mid not in place:
            return m.group(0)
        x, R3 = place[mid]
        attrs = {"pos_x": x[0], "pos_y": x[1], "pos_z": 0.0}
        attrs.update({f"a{i}{j}": R3[i, j] for i in range(3) for j in range(3)})
        out = m.group(0)
        for k, v in attrs.items():
            out = re.sub(rf'\b{k}="[^"]*"', f'{k}="{float(v)!r}"', out)
        return out

    text = (root / "decks" / "fourbar_spring.xml").read_text()
    return re.sub(r'<Reference_Marker id="(\d+)"[^>]*/>', sub, text, flags=re.S)


FOURBAR_MIN = -2.141631367731787    # rad: the only minimum (1-DOF scan, tests/support/reference.py)


def _best_of(repeat, run):
    """``run()`` ``repeat`` times; the result with the smallest solve time (each case and the
    FIM_S baseline it is compared with get the same number of repeats)."""
    best = None
    for _ in range(repeat):
        res = run()
        if best is None or res.timings.get("solve", np.inf) < best.timings.get("solve", np.inf):
            best = res
    return best


def _repeats(n):
    return 3 if n <= 200 else 2 if n <= 1000 else 1


def _fourbar_case(tmp: Path, root: Path, method, log, **over):
    import poise
    p = tmp / "stable_fourbar_60.xml"
    if not p.exists():
        p.write_text(fourbar_deck(root, math.radians(60.0)))
    res = _best_of(_repeats(3), lambda: poise.solve(str(p), method=method, **over))
    a = res.analyses[0]
    ids = list(np.asarray(a.datasets["bodies/id"]))
    Rc = np.asarray(a.datasets["bodies/orientation"])[0][ids.index(2)]
    ang = math.atan2(Rc[1, 0], Rc[0, 0])
    dev = abs((ang - FOURBAR_MIN + math.pi) % (2 * math.pi) - math.pi)
    row = dict(bench="stable", n=3, start="fourbar 60 deg", method=method,
               require_stable=bool(over.get("require_stable", False)), status=a.status,
               stability=str(a.datasets["frames/stability"][0]),
               n_negative=int(a.datasets["frames/n_negative"][0]),
               solve_s=float(res.timings.get("solve", np.nan)), deviation=dev)
    log(f"[stable] four-bar {method}{' --require-stable' if row['require_stable'] else ''}: "
        f"{row['status']} {row['stability']} in {row['solve_s']:.3f} s, crank {ang:.6f} rad")
    return row


def _case(tmp: Path, n, start, method, log, **over):
    import poise
    from poise.gen.chain import build_chain_deck
    span = (V_SPAN if start == "v" else 0.8) * n * A
    p = tmp / f"stable_chain_{n}_{start}.xml"
    if not p.exists():
        p.write_text(build_chain_deck(n, start=start, span=span))
    t = time.perf_counter()
    res = _best_of(_repeats(n), lambda: poise.solve(str(p), method=method, **over))
    wall = (time.perf_counter() - t) / _repeats(n)
    a = res.analyses[0]
    ids = np.asarray(a.datasets["bodies/id"])
    pos = np.asarray(a.datasets["bodies/position"])[0][np.argsort(ids)][:, :2]
    dev = float(np.max(np.abs(pos - catenary_cgs(n, span=span)))) / (n * A)
    row = dict(bench="stable", n=n, start=start, method=method,
               require_stable=bool(over.get("require_stable", False)), status=a.status,
               stability=str(a.datasets["frames/stability"][0]),
               n_negative=int(a.datasets["frames/n_negative"][0]),
               solve_s=float(res.timings.get("solve", wall)), wall_s=wall, deviation=dev)
    log(f"[stable] N={n} {start} {method}{' --require-stable' if row['require_stable'] else ''}"
        f": {row['status']} {row['stability']} in {row['solve_s']:.2f} s, deviation {dev:.1e}")
    return row


def run(tmp: Path, log=print, quick=False):
    """Returns (rows, markdown lines, targets)."""
    root = Path(__file__).resolve().parents[1]
    rows = []
    fb = [_fourbar_case(tmp, root, "FIM_S", log), _fourbar_case(tmp, root, "FIM_S", log,
                                                                  require_stable=True),
          _fourbar_case(tmp, root, "MKEAM", log)]
    rows += fb
    c = lambda *a, **k: rows.append(_case(tmp, *a, log=log, **k)) or rows[-1]   # noqa: E731
    big = 200 if quick else 1000
    fs_arc_100 = c(100, "arc", "FIM_S")
    mk_arc_100 = c(100, "arc", "MKEAM")
    fs_v200 = c(200, "v", "FIM_S")
    rs_v200 = c(200, "v", "FIM_S", require_stable=True)
    c(200, "v", "MKEAM")
    fs_arc_big = c(big, "arc", "FIM_S")
    fs_v_big = c(big, "v", "FIM_S")
    rs_v_big = c(big, "v", "FIM_S", require_stable=True)
    mk_v_big = c(big, "v", "MKEAM")
    scal = [mk_arc_100] + [c(n, "arc", "MKEAM") for n in SCALING[1:]
                           if not quick or n <= 1000]
    ns = np.array([r["n"] for r in scal], float)
    ts = np.array([r["solve_s"] for r in scal], float)
    slope = float(np.polyfit(np.log(ns), np.log(ts), 1)[0]) if len(ns) >= 2 else math.nan

    def good(r):
        return r["status"] == "converged" and r["stability"] == "stable"

    mk_rows = [r for r in rows if r["method"] == "MKEAM"]
    rs_rows = [r for r in rows if r["require_stable"]]
    tg = [
        (f"MKEAM, {big}-link V chain / FIM_S, {big}-link arc chain", "<= 20x",
         f"{mk_v_big['solve_s'] / fs_arc_big['solve_s']:.1f}x",
         mk_v_big["solve_s"] <= 20 * fs_arc_big["solve_s"]),
        ("MKEAM / FIM_S, 100-link arc chain", "<= 10x",
         f"{mk_arc_100['solve_s'] / fs_arc_100['solve_s']:.1f}x",
         mk_arc_100["solve_s"] <= 10 * fs_arc_100["solve_s"]),
        (f"MKEAM solve time exponent, N = {int(ns[0])} ... {int(ns[-1])}", "<= 1.3",
         f"{slope:.2f}", slope <= 1.3),
        ("every MKEAM answer stable and within 1e-8 x N a of the catenary", "all",
         f"{sum(good(r) and r['deviation'] <= 1e-8 for r in mk_rows)}/{len(mk_rows)}",
         all(good(r) and r["deviation"] <= 1e-8 for r in mk_rows)),
        ("--require-stable answers stable, within 1e-6 x N a of the catenary", "all",
         f"{sum(good(r) and r['deviation'] <= 1e-6 for r in rs_rows)}/{len(rs_rows)}",
         all(good(r) and r["deviation"] <= 1e-6 for r in rs_rows)),
    ]
    for fs, rs in ((fs_v200, rs_v200), (fs_v_big, rs_v_big)):
        tg.append((f"--require-stable / plain FIM_S, {fs['n']}-link V chain", "<= 5x",
                   f"{rs['solve_s'] / fs['solve_s']:.1f}x", rs["solve_s"] <= 5 * fs["solve_s"]))
    fb_ok = all(r["status"] == "converged" and r["stability"] == "stable"
                and r["deviation"] <= 1e-6 for r in fb[1:])
    tg.append(("four-bar started at 60 deg: --require-stable and MKEAM at the minimum "
               "(1e-6 rad)", "both", f"{'both' if fb_ok else 'not both'}", fb_ok))
    tg.append(("--require-stable / plain FIM_S, four-bar", "<= 5x",
               f"{fb[1]['solve_s'] / fb[0]['solve_s']:.1f}x",
               fb[1]["solve_s"] <= 5 * fb[0]["solve_s"]))
    md = ["## Stable equilibria", "",
          "Hanging chains of rigid links (`poise.gen.chain`; `V` = two straight legs, span "
          f"{V_SPAN} N a; `arc` = the default start near the catenary, span 0.8 N a). Solve "
          "times in one process (parse and compile excluded; the best of 3 runs for N <= 200 "
          "and the four-bar, of 2 for N = 1000, one run above: a case and the FIM_S run it is "
          "compared with get the same number); the deviation is the largest CG "
          "distance from the discrete catenary (closed form, one scalar root) over N a.", "",
          "| N | start | method | status | stability (negative modes) | solve [s] | "
          "x FIM_S | deviation |", "|---|---|---|---|---|---|---|---|"]
    md[2] = (md[2] + " The four-bar (`decks/fourbar_spring.xml` started at crank "
                 "angle 60 deg; the issue's 90-deg start reaches the minimum with plain Newton on "
                 "this linkage) reports in the deviation column the crank-angle error [rad] "
                 f"from its only minimum {FOURBAR_MIN:.6f} rad.")
    base = {(r["n"], r["start"]): r for r in rows if r["method"] == "FIM_S"
            and not r["require_stable"]}
    for r in rows:
        b = base.get((r["n"], r["start"]))
        ratio = f"{r['solve_s'] / b['solve_s']:.1f}" if b else "—"
        name = r["method"] + (" --require-stable" if r["require_stable"] else "")
        md.append(f"| {r['n']} | {r['start']} | {name} | {r['status']} | {r['stability']} "
                  f"({r['n_negative']}) | {r['solve_s']:.2f} | {ratio} | {r['deviation']:.1e} |")
    md += ["", "| target | limit | measured | result |", "|---|---|---|---|"]
    for name, lim, meas, ok in tg:
        md.append(f"| {name} | {lim} | {meas} | "
                  f"{'—' if ok is None else ('PASS' if ok else 'MISS')} |")
    md.append("")
    rows.append(dict(bench="stable_fit", mkeam_exponent=slope))
    return rows, md, tg
