"""Markdown sections and matplotlib (Agg) plots for the issue-7 benchmarks."""
from __future__ import annotations

import math
from pathlib import Path

FLOOR = 1e-17     # errors of exactly 0 are drawn here


def _s(x, d=3):
    if x is None:
        return "—"
    if isinstance(x, float) and (math.isnan(x) or math.isinf(x)):
        return str(x)
    if abs(x) >= 100:
        return f"{x:.0f}"
    return f"{x:.{d}g}"


def _mmm(st):
    if not st:
        return "—"
    return f"{_s(st['median'])} ({_s(st['min'])}–{_s(st['max'])})"


def _e(x):
    return "—" if x is None else f"{x:.1e}"


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_wp(rows, path: Path):
    plt = _plt()
    decks = list(dict.fromkeys(r["deck"] for r in rows))
    nc = 4 if len(decks) > 4 else len(decks)
    nr = math.ceil(len(decks) / nc)
    fig, axes = plt.subplots(nr, nc, figsize=(4.2 * nc, 3.6 * nr), squeeze=False)
    marks = {"FIM_S": "o-", "MKEAM": "s-", "FIM_D": "^-"}
    for ax, deck in zip(axes.flat, decks):
        for m in dict.fromkeys(r["method"] for r in rows if r["deck"] == deck):
            pts = [r for r in rows if r["deck"] == deck and r["method"] == m]
            x = [r["solve_s"]["median"] for r in pts]
            y = [max(r.get("error") or FLOOR, FLOOR) for r in pts]
            ax.loglog(x, y, marks.get(m, "x-"), label=m)
            for r, xi, yi in zip(pts, x, y):
                if r["status"] != "converged":
                    ax.plot([xi], [yi], "rx", ms=10)
        ax.set_title(deck, fontsize=10)
        ax.set_xlabel("solve time [s]")
        ax.set_ylabel("error / L")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    for ax in list(axes.flat)[len(decks):]:
        ax.axis("off")
    fig.suptitle("Work-precision: achieved CG error vs solve time (red x = not converged)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_scaling(chains, grids, fits, path: Path):
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    for fam, rows, m in (("chain", chains, "o-"), ("grid", grids, "s-")):
        rows = sorted(rows, key=lambda r: r["n"])
        if not rows:
            continue
        n = [r["n"] for r in rows]
        p = fits.get(f"{fam}_solve_s_1000")
        axes[0].loglog(n, [r["solve_s"]["median"] for r in rows], m,
                       label=f"{fam} (slope {p:.2f} large N)" if p else fam)
        p = fits.get(f"{fam}_peak_rss_bytes_1000")
        axes[1].loglog(n, [r["peak_rss_bytes"]["max"] / 2**20 for r in rows], m,
                       label=f"{fam} (slope {p:.2f} large N)" if p else fam)
        axes[2].loglog(n, [r["iteration_s"]["median"] for r in rows], m, label=f"{fam}: Newton iteration")
        axes[2].loglog(n, [r["lu_s"]["median"] for r in rows], m.replace("-", "--"),
                       label=f"{fam}: one sparse LU", alpha=0.7)
    axes[0].set_ylabel("solve time [s]")
    axes[1].set_ylabel("peak RSS [MiB]")
    axes[2].set_ylabel("time [s]")
    for ax in axes:
        ax.set_xlabel("N (links / bodies)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def wp_section(rows, procs, qs, decade, deck_docs) -> list[str]:
    L = ["## Work-precision (issue 7)", "",
         "Every benchmark deck in `decks/bench/` for every method that applies, over a tolerance "
         "ladder. FIM_S rung *t*: `max_imbalance = max_error = t`; MKEAM: `max_ke_tol = "
         "max_dq_tol = t` and, because MKEAM ends with a Newton polish, `max_imbalance = "
         "max_error = t`; FIM_D: `dae_constr_tol = integr_tol = t` (IDA rtol) and `max_imbalance "
         "= max_error = t`. Fallback chain off (`fallback=False`), so each row is the method itself. "
         "Times are in-process (`poise.app.api.run_deck`, one warm-up, then the median of the runs "
         "with min–max; runs longer than 2 s are repeated 3 times instead of 5 — the *n* column); "
         "*solve* is `RunResult.timings['solve']`, *total* includes parse and compile. **Error** = "
         "max over frames and bodies of |CG − CG_ref| / L (L = the model's length scale), against "
         "an independent reference:", ""]
    for name, doc in deck_docs.items():
        L.append(f"- `{name}`: {doc}")
    L += ["", "MKEAM is not laddered on `chain_1000` (one run at 1e-3 takes minutes: the "
          "explicit RATTLE steps are limited by the stiffest link period). FIM_S converges "
          "quadratically, so a loose rung already lands far below its tolerance: the error axis "
          "shows what a rung *achieves*, not what it asks for.", "",
          "![work-precision](img/work_precision.png)", "",
          "| deck | method | rung | status | iterations | residuals / Jacobians / factorisations "
          "| solve [s] | total [s] | n | error / L | final imbalance |",
          "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        c = r["counts"]
        L.append(f"| {r['deck']} | {r['method']} | {r['tol']:.0e} | {r['status']} | "
                 f"{r['iterations']} | {c.get('residuals', '—')} / {c.get('jacobians', '—')} / "
                 f"{c.get('factorizations', '—')} | {_mmm(r['solve_s'])} | "
                 f"{_s(r['total_s']['median'])} | {r['solve_s']['n']} | {_e(r.get('error'))} | "
                 f"{_e(r.get('imbalance'))} |")
    if decade:
        L += ["", "FIM_S cost of accuracy per deck: *per rung decade* = (time at 1e-10 / time at "
              "1e-2)^(1/8) of the requested tolerance; *per error decade* = least-squares slope "
              "of log time vs −log error (achieved).", "",
              "| deck | time factor per requested decade | per achieved-error decade |",
              "|---|---|---|"]
        for d in decade:
            L.append(f"| {d['deck']} | {_s(d.get('per_rung'))} | {_s(d.get('factor_per_decade'))} |")
    if procs:
        L += ["", "### Whole process per deck", "",
              "`poise solve decks/bench/X.xml -o out.h5` at the deck's own settings, process start "
              "to HDF5 written, median (min–max).", "", "| deck | wall time [s] | runs | exit |",
              "|---|---|---|---|"]
        for p in procs:
            L.append(f"| {p['deck']} | {_mmm(p['wall_s'])} | {p['repeat']} | {p['returncode']} |")
    if qs:
        L += ["", "### FIM_D vs FIM_S on a long quasi-static run", "",
              f"`{qs[0]['file']}` ({qs[0]['frames']} frames, slider load ramp), one run per rung.",
              "FIM_D's output frames are corrected onto the equilibrium to the `Param_Static` "
              "tolerances (the last column: time spent there, included in the solve time; "
              "corrections / residual evaluations / full-Newton fallbacks).",
              "", "| method | rung | status | Newton iterations | IDA steps | residuals / Jacobians "
              "/ factorisations | solve [s] | error / L | output-frame correction |",
              "|---|---|---|---|---|---|---|---|---|"]
        for r in qs:
            c = r.get("counts", {})
            steps = r.get("ida_steps")
            k = r.get("correction")
            corr = (f"{_s(k['seconds'])} s ({k['corrections']} / {k['residuals']} / "
                    f"{k['newton']})" if k else "—")
            L.append(f"| {r['method']} | {r['tol']:.0e} | {r['status']} | {r['iterations']} | "
                     f"{'—' if steps is None else steps} | {c.get('residuals', '—')} / "
                     f"{c.get('jacobians', '—')} / {c.get('factorizations', '—')} | "
                     f"{_s(r['solve_s']['median'])} | {_e(r.get('error'))} | {corr} |")
    return L


def peer_section(rows) -> list[str]:
    from benchmarks import peer
    L = ["## Peer: Exudyn static solver, same problems, same run", ""]
    L += peer.caption()
    if not rows or not rows[0].get("peer_available"):
        L.append(f"**Peer skipped**: {rows[0]['peer'] if rows else 'no rows'}.")
        return L
    L += [f"Peer: {rows[0]['peer']}. Times: in-process solve median (warm-up first); whole process "
          "= `poise solve deck -o out.h5` vs `python peer_script.py spec.json` (import exudyn + "
          "build + solve, no output file).", "",
          "| problem | poise status / iterations | poise solve [s] | poise error / L | Exudyn "
          "status / Newton iterations | Exudyn solve [s] | Exudyn error / L | solve ratio "
          "poise/Exudyn | poise process [s] | Exudyn process [s] | process ratio |",
          "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        p, e = r["poise"], r.get("exudyn", {})
        est = "converged" if e.get("converged") else "FAILED (reason below)"
        err = e.get("error") if e.get("converged") else e.get("error_unconverged")
        L.append(f"| {r['problem']} | {p['status']} / {p['iterations']} | {_mmm(p['solve_s'])} | "
                 f"{_e(p['error'])} | {est} / {e.get('iterations')} | {_mmm(e.get('solve_s'))} | "
                 f"{_e(err)}{'' if e.get('converged') else ' (at stop)'} | "
                 f"{_s(r.get('solve_ratio'))} | {_mmm(p['process_s'])} | "
                 f"{_mmm(e.get('process_s'))} | {_s(r.get('process_ratio'))} |")
    L += ["", "Ratios are given only where Exudyn converged. Exudyn model per problem "
          "(coordinates = ODE2 unknowns; AE = algebraic (Lagrange multiplier) unknowns) and the "
          "result:", "",
          "| problem | Exudyn model | coordinates / AE | static solver settings | result |",
          "|---|---|---|---|---|"]
    for r in rows:
        e = r.get("exudyn", {})
        if not e:
            continue
        if e["converged"]:
            res = f"converged, {e['iterations']} Newton iterations"
        else:
            res = (f"FAILED ({e.get('message')}; last converged load factor "
                   f"{_s(e.get('load_factor'))}, {e['iterations']} Newton iterations): "
                   f"{e.get('reason') or 'see the caption'}")
        L.append(f"| {r['problem']} | {e['model']} | {e['n_coordinates']} / "
                 f"{e['n_constraints']} | {peer.settings_text(e['settings'])} | {res} |")
    return L + floor_section(rows)


def floor_section(rows) -> list[str]:
    """Whole process of the small decks next to the import floors (poise's mandated
    dependencies; numpy alone; the peer script's imports) and next to ``poise batch``, all
    measured the same way (``benchmarks.chain._wall``)."""
    rows = [r for r in rows if r.get("import_floor") and r.get("exudyn", {}).get("process_s")]
    if not rows:
        return []
    fl = rows[0]["import_floor"]
    L = ["", "### Whole process vs the import floor (small decks)", "",
         "All processes of this table (poise, Exudyn and the floors) are run round-robin, one "
         "warm-up each and then 11 or more rounds, so that machine drift hits them alike; "
         "median (min–max), same interpreter and environment. "
         f"*Import floor* = `{fl['command']}`. *Floor as poise* = the "
         f"same imports set up the way a poise process is: `python -c '{fl['command_as_poise']}'`"
         " (poise sets `OPENBLAS_NUM_THREADS=1` before importing numpy, and ends its process "
         "with `os._exit` after the exit handlers). *numpy alone* = "
         f"`python -c '{fl['command_numpy']}'`: numpy is imported by both sides (Exudyn imports "
         "it too), so no Python solver built on numpy can go below it. *Exudyn above its imports* = "
         f"Exudyn process − `python -c \"{fl['command_peer']}\"`: its build and solve. "
         "*Mandated minimum* = the floor as poise plus importing click (the CLI), reading the deck "
         "with lxml and writing a one-dataset HDF5 file with fsync: the least any `poise solve` "
         "process does with the mandated stack, before it compiles or solves anything. "
         "*poise above floor* = poise process − floor as poise: poise's own imports (click, "
         "poise), parse, compile, solve and the HDF5 write. If the mandated minimum alone is "
         "above 0.8 × Exudyn, the target cannot be met with the mandated dependencies.", "",
         "| problem | poise process [s] | Exudyn process [s] | poise / Exudyn | import floor [s] | "
         "floor / Exudyn | floor as poise [s] | floor as poise / Exudyn | numpy alone [s] | "
         "numpy alone / Exudyn | mandated minimum [s] | mandated minimum / Exudyn | "
         "poise above floor [s] | Exudyn above its imports [s] |",
         "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        f = r["import_floor"]
        L.append(f"| {r['problem']} | {_mmm(r['poise']['process_s'])} | "
                 f"{_mmm(r['exudyn']['process_s'])} | {_s(r.get('process_ratio'))} | "
                 f"{_mmm(f['normal'])} | {_s(r.get('floor_ratio'))} | {_mmm(f['as_poise'])} | "
                 f"{_s(r.get('floor_as_poise_ratio'))} | {_mmm(f.get('numpy'))} | "
                 f"{_s(r.get('numpy_ratio'))} | {_mmm(f.get('mandated'))} | "
                 f"{_s(r.get('mandated_ratio'))} | {_s(r.get('poise_above_floor_s'))} | "
                 f"{_s(r.get('peer_above_floor_s'))} |")
    b = [r for r in rows if r.get("batch")]
    if b:
        n = b[0]["batch"]["copies"]
        L += ["", "### Many decks, one process: `poise batch`", "",
              f"A CI job that solves many decks can hand them to one `poise batch` call, which "
              f"pays the imports once. Per deck = wall time of `poise batch` over {n} copies of "
              "the deck (process start to every results file and summary.csv/json written) / "
              f"{n}; `-j 1` is one worker (the CPU cost per deck), `-j 0` one worker per CPU. "
              "Ratios are to Exudyn's whole process per deck (one process per problem, as "
              "above).", "",
              "| problem | per deck, -j 1 [s] | / Exudyn process | per deck, -j 0 [s] | "
              "/ Exudyn process |", "|---|---|---|---|---|"]
        for r in b:
            bt, br = r["batch"], r.get("batch_ratio") or {}
            L.append(f"| {r['problem']} | {_mmm(bt['j1'])} | {_s(br.get('j1'))} | "
                     f"{_mmm(bt['j0'])} | {_s(br.get('j0'))} |")
    return L


def scaling_section(chains, grids, skips, fits) -> list[str]:
    L = ["## Scaling (issue 7)", "",
         "Chains: `poise.gen.chain` (revolute); sizes from the chain benchmark above plus the "
         "larger ones, one fresh process per run. Grid: n×n rigid blocks joined to neighbours and "
         "(edges) to ground by `Force_Bushing` (`benchmarks.decks.build_grid_deck`, 6 N "
         "unknowns, no constraints). Exponents: least squares on log–log data; *large N* uses "
         "N ≥ 1000 (chains) / N ≥ 256 (grids).", "",
         "![scaling](img/scaling.png)", "",
         "| family | N | unknowns | iterations | solve [s] | time/iteration [s] | one LU [s] | "
         "iter/LU | peak RSS [MiB] | status |", "|---|---|---|---|---|---|---|---|---|---|"]
    for fam, rows in (("chain", chains), ("grid", grids)):
        for r in sorted(rows, key=lambda r: r["n"]):
            L.append(f"| {fam} | {r['n']} | {r['nq']} | {r['iterations']} | {_mmm(r['solve_s'])} | "
                     f"{_s(r['iteration_s']['median'])} | {_s(r['lu_s']['median'])} | "
                     f"{_s(r['iteration_per_lu'])} | {r['peak_rss_bytes']['max'] / 2**20:.0f} | "
                     f"{r['status']} |")
    for s in skips:
        L.append(f"| {s['family']} | {s['n']} | — | — | skipped: {s['reason']} | | | | | |")
    L += ["", "| fit | exponent (all N) | exponent (large N) |", "|---|---|---|"]
    for fam in ("chain", "grid"):
        for k, lab in (("solve_s", "solve time"), ("peak_rss_bytes", "peak RSS")):
            L.append(f"| {fam} {lab} | {_s(fits.get(f'{fam}_{k}_all'))} | "
                     f"{_s(fits.get(f'{fam}_{k}_1000'))} |")
    return L
