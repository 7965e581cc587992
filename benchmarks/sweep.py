"""Sweeps of a small model and the in-process solve (issue 25 §1), measured as ratios in one run.

* ``poise sweep decks/pendulum_multiturn.xml`` of 1000 stiffness values on 2 workers (the
  command, a fresh process: cluster start, solving, the sweep file and the index) against
  whole-process ``poise solve`` runs of the same deck: target ≤ 10 solve runs.
* The same sweep with 100,000 cases: target ≤ 60 s on 2 cores, with the peak memory of the
  largest process (``ru_maxrss`` of the command's process tree) reported to show it bounded.
* One worker's chunk of 1000 cases in process, solved together (one batched evaluation and
  factorisation per Newton iteration, :mod:`poise.app.chunk_batch`) against case by case.
* ``poise.solve`` of a 3-body deck (``decks/fourbar_spring.xml``: three moving links) in one
  process (median after a warm-up): target ≤ 3 ms; the sweep's deck alongside.

The cases' own wall times (``wall_time`` of the sweep file: parse, compile and solve in the
worker) give the per-case cost inside a sweep; the rest is cluster start, transport and writing.
``python -m benchmarks.sweep [--cases 1000,100000]`` runs this table alone.
"""
from __future__ import annotations

import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

from benchmarks.chain import _poise_cmd, _user_env, _wall

DECK = "decks/pendulum_multiturn.xml"
THREE_BODIES = "decks/fourbar_spring.xml"
K = "Force_SpringDamper[1].stiffness"
WORKERS = 2
RATIO_TARGET = 10.0
BIG_TARGET_S = 60.0
INPROCESS_TARGET_MS = 3.0


def _values(n: int) -> str:
    """``n`` stiffness values 10000, 10000 + step, ... (a range string of exactly n values)."""
    step = 20000.0 / n
    return f"10000:{10000 + step * (n - 0.5):.10g}:{step:.10g}"     # (n - 1/2: no rounding loss)


def _run_measured(cmd: list[str]) -> tuple[float, int, float]:
    """Wall time [s], return code and peak RSS [MB] of the largest process in ``cmd``'s tree
    (a wrapper process, so that only this command's children count)."""
    code = ("import json, resource, subprocess, sys, time\n"
            "t0 = time.perf_counter()\n"
            "r = subprocess.run(sys.argv[1:], capture_output=True)\n"
            "w = time.perf_counter() - t0\n"
            "m = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss\n"
            "print(json.dumps([w, r.returncode, m / 1024]))\n"
            "sys.stderr.write(r.stderr.decode()[-2000:])\n")
    p = subprocess.run([sys.executable, "-c", code, *cmd], capture_output=True, text=True,
                       env=_user_env())
    try:
        wall, rc, mb = json.loads(p.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        return float("nan"), 99, float("nan")
    return float(wall), int(rc), float(mb)


def bench_sweep(n: int, tmp: Path, root: Path) -> dict:
    """One ``poise sweep`` of ``n`` cases (fresh process) and what its sweep file says."""
    out = tmp / f"sweep_{n}"
    cmd = _poise_cmd() + ["sweep", str(root / DECK), "--set", f"{K}={_values(n)}",
                          "--workers", str(WORKERS), "--out-dir", str(out), "--quiet",
                          "--force", "--output", "bodies[2].position", "--max-cases", str(n)]
    wall, rc, mb = _run_measured(cmd)
    row = dict(bench="sweep", cases=n, workers=WORKERS, wall_s=wall, returncode=rc,
               peak_rss_mb=mb, command=" ".join(cmd[1:3]) + f" --set {K}=<{n} values>")
    try:
        import h5py
        import numpy as np
        with h5py.File(out / "sweep.h5", "r") as f:
            wt = f["wall_time"][()]
            st = f["status"].asstr()[()]
            row.update(case_ms_median=float(np.nanmedian(wt)) * 1e3,
                       case_ms_sum_per_worker=float(np.nansum(wt)) * 1e3 / WORKERS / n,
                       converged=int((st == "converged").sum()),
                       file_mb=(out / "sweep.h5").stat().st_size / 2 ** 20)
    except (OSError, KeyError):
        pass
    return row


def bench_inprocess(root: Path, name: str, repeat: int = 50) -> dict:
    """``poise.solve`` of deck ``name`` in this process: median/min over ``repeat`` runs after
    three warm-ups (the deck's parse and model kept between them, poise.app.deck_cache), the
    median CPU time of this thread per solve (``cpu_ms``: what other processes' load does not
    add), the solver's own share (``timings['solve']``), the median with the deck parsed and compiled
    every time (``fresh_ms``) and the Python function calls of one solve (``calls``, cProfile:
    independent of the machine's load)."""
    import cProfile
    import pstats

    import poise
    from poise.app import deck_cache
    deck = str(root / name)
    for _ in range(3):
        r = poise.solve(deck, quiet=True)
    times, solve, fresh, cpu = [], [], [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.thread_time()
        r = poise.solve(deck, quiet=True)
        times.append(time.perf_counter() - t0)
        cpu.append(time.thread_time() - c0)
        solve.append(r.timings.get("solve", float("nan")))
    for _ in range(repeat):
        deck_cache.clear()
        t0 = time.perf_counter()
        poise.solve(deck, quiet=True)
        fresh.append(time.perf_counter() - t0)
    prof = cProfile.Profile()
    prof.enable()
    poise.solve(deck, quiet=True)
    prof.disable()
    it = int(sum(int(x) for a in r.analyses for x in a.datasets["frames/iterations"]))
    return dict(bench="inprocess_solve", deck=name, repeat=repeat, status=r.status,
                bodies=len(r.model_datasets.get("bodies/id", ())), iterations=it,
                ms=dict(median=statistics.median(times) * 1e3, min=min(times) * 1e3),
                cpu_ms=statistics.median(cpu) * 1e3,
                solve_ms=statistics.median(solve) * 1e3,
                fresh_ms=statistics.median(fresh) * 1e3,
                calls=int(pstats.Stats(prof).total_calls))


def bench_chunk(root: Path, n: int = 1000, alone: int = 100) -> dict:
    """One worker's chunk of ``n`` cases of the sweep in this process: solved together
    (:mod:`poise.app.chunk_batch`) against the first ``alone`` of them solved case by case,
    per case; and the largest difference of a body position between the two."""
    from dataclasses import replace

    import numpy as np

    import poise
    from poise.app.cases import make_cases, resolve_param
    from poise.app.chunk_batch import plan_batch
    from poise.app.chunks import FrameLayout, Output, SweepJob, make_template, solve_chunk
    deck = root / DECK
    spec = poise.load_deck(str(deck))
    p = resolve_param(spec, K, _values(n))
    cases = list(enumerate(make_cases([p])))
    out = Output("bodies[2].position", "bodies", 2, "position", (3,))
    job = SweepJob(deck.read_bytes(), str(deck), (replace(p, values=[]),), {}, (out,),
                   FrameLayout((0.0,), (0,)), key="bench")
    template = make_template(job, {})
    batched = plan_batch(template, cases[0][1]) is not None
    solve_chunk(template, cases[:20])                  # warm-up (imports, the batch plan)
    t0 = time.perf_counter()
    together = solve_chunk(template, cases)
    t1 = time.perf_counter()
    single = solve_chunk(template, cases[:alone], batched=False)
    t2 = time.perf_counter()
    diff = max(float(np.max(np.abs(a.outputs[out.text] - b.outputs[out.text])))
               for a, b in zip(together, single))
    same = all((a.status, a.iterations, a.stability) == (b.status, b.iterations, b.stability)
               for a, b in zip(together, single))
    return dict(bench="sweep_chunk", deck=DECK, cases=n, batched=batched,
                together_ms=(t1 - t0) / n * 1e3, alone_ms=(t2 - t1) / alone * 1e3,
                max_position_difference=diff, same_verdicts=same,
                converged=sum(r.status == "converged" for r in together))


def run(tmp: Path, root: Path, cases=(1000, 100_000), repeat: int = 5, log=None,
        inprocess_repeat: int = 50, chunk: int = 1000) -> list[dict]:
    say = log or (lambda m: None)
    rows = []
    st, rc = _wall(_poise_cmd() + ["solve", str(root / DECK), "-o", str(tmp / "one.h5"),
                                   "-q"], repeat)
    rows.append(dict(bench="solve_process", deck=DECK, repeat=repeat, wall_s=st, returncode=rc))
    say(f"poise solve {DECK}: {st['median']:.3f} s")
    for name in (DECK, THREE_BODIES):
        rows.append(bench_inprocess(root, name, inprocess_repeat))
        say(f"poise.solve({name}) in process: {rows[-1]['ms']['median']:.2f} ms")
    rows.append(bench_chunk(root, chunk, min(100, chunk)))
    say(f"a chunk of {chunk} cases in process: {rows[-1]['together_ms']:.2f} ms per case "
        f"together, {rows[-1]['alone_ms']:.2f} ms alone")
    for n in cases:
        rows.append(bench_sweep(n, tmp, root))
        say(f"poise sweep {n} cases: {rows[-1]['wall_s']:.1f} s, "
            f"{rows[-1].get('case_ms_median', float('nan')):.1f} ms per case in its worker, "
            f"peak {rows[-1]['peak_rss_mb']:.0f} MB")
    return rows


def _get(rows, bench, **kw):
    return next((r for r in rows if r["bench"] == bench
                 and all(r.get(k) == v for k, v in kw.items())), None)


def targets(rows: list[dict]) -> list[tuple[str, str, str, bool | None]]:
    out = []
    one = _get(rows, "solve_process")
    s1k = _get(rows, "sweep", cases=1000)
    if one and s1k:
        ratio = s1k["wall_s"] / one["wall_s"]["median"]
        out.append((f"1000-case sweep of {DECK} on {WORKERS} workers, in whole-process "
                    "`poise solve` runs", f"≤ {RATIO_TARGET:g}", f"{ratio:.1f}",
                    ratio <= RATIO_TARGET and s1k["returncode"] == 0))
    big = _get(rows, "sweep", cases=100_000)
    if big:
        out.append((f"100,000-case sweep on {WORKERS} cores", f"≤ {BIG_TARGET_S:g} s",
                    f"{big['wall_s']:.0f} s (peak {big['peak_rss_mb']:.0f} MB)",
                    big["wall_s"] <= BIG_TARGET_S and big["returncode"] == 0))
    ip = _get(rows, "inprocess_solve", deck=THREE_BODIES)
    if ip:
        v = ip["ms"]["median"]
        out.append((f"in-process `poise.solve` of a {ip['bodies']}-body deck ({THREE_BODIES})",
                    f"≤ {INPROCESS_TARGET_MS:g} ms", f"{v:.1f} ms", v <= INPROCESS_TARGET_MS))
    return out


def markdown(rows: list[dict]) -> list[str]:
    one = _get(rows, "solve_process")
    md = ["## Sweeps of a small model", "",
          f"`{DECK}` (one moving body). *poise solve*: the command, a fresh "
          "process (median of its runs); *in process*: `poise.solve(path)` after warm-up "
          "(median), *solver* its `timings['solve']`; a sweep is the command `poise sweep "
          f"--workers {WORKERS} --output bodies[2].position` (cluster start, solving, the sweep "
          "file and the index); *per case* is a case's own wall time in its worker (parse, "
          "compile, solve; median; cases solved together share their chunk's solve time), "
          "*peak* the largest process's resident memory.", "",
          "| | wall | per case | peak memory | in `poise solve` runs |", "|---|---|---|---|---|"]
    base = one["wall_s"]["median"] if one else None
    if one:
        md.append(f"| `poise solve` | {base:.3f} s | | | 1 |")
    for ip in (r for r in rows if r["bench"] == "inprocess_solve"):
        md.append(f"| `poise.solve` in process, `{ip['deck']}` ({ip['bodies']} moving "
                  f"bodies) | {ip['ms']['median']:.2f} ms (CPU {ip.get('cpu_ms', float('nan')):.2f} ms, "
                  f"solver {ip['solve_ms']:.2f} ms, "
                  f"{ip['iterations']} iterations; parsed and compiled each time "
                  f"{ip.get('fresh_ms', float('nan')):.2f} ms; {ip.get('calls', 0):,} Python "
                  "calls) | | | "
                  + (f"{ip['ms']['median'] / 1e3 / base:.3f}" if base else "—") + " |")
    ch = _get(rows, "sweep_chunk")
    if ch:
        md.append(f"| a worker's chunk of {ch['cases']:,} cases in process, solved "
                  f"{'together' if ch['batched'] else 'case by case (not batchable)'} | "
                  f"{ch['together_ms'] * ch['cases'] / 1e3:.2f} s | {ch['together_ms']:.2f} ms "
                  f"(alone: {ch['alone_ms']:.1f} ms; positions within "
                  f"{ch['max_position_difference']:.1e} mm, same verdicts: "
                  f"{'yes' if ch['same_verdicts'] else 'NO'}) | | |")
    for r in rows:
        if r["bench"] != "sweep":
            continue
        md.append(f"| sweep, {r['cases']:,} cases | {r['wall_s']:.1f} s | "
                  f"{r.get('case_ms_median', float('nan')):.1f} ms | "
                  f"{r['peak_rss_mb']:.0f} MB | "
                  + (f"{r['wall_s'] / base:.1f}" if base else "—") + " |")
    return md + [""]


if __name__ == "__main__":      # python -m benchmarks.sweep: this table alone
    import argparse
    import tempfile
    ap = argparse.ArgumentParser(prog="python -m benchmarks.sweep")
    ap.add_argument("--cases", default="1000,100000", help="sweep sizes, comma-separated")
    args = ap.parse_args()
    root = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory(prefix="poise-bench-") as d:
        res = run(Path(d), root, [int(x) for x in args.cases.split(",") if x.strip()],
                  log=lambda m: print(m, file=sys.stderr, flush=True))
    print("\n".join(markdown(res)))
    for name, lim, meas, ok in targets(res):
        print(f"{'PASS' if ok else 'MISS'} {name}: {meas} (target {lim})")
    print(json.dumps(res, default=float))
