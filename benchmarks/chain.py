"""Benchmarks behind ``make bench``: hanging chains, CLI start-up and a small deck end to end.

* **Hanging chains** (``poise.gen.chain``, revolute joints, N = 10 ... 10 000), generated into a
  temporary directory. Every repetition runs in a fresh subprocess (``python -m benchmarks.chain DECK N``) that imports
  poise first (import time is reported separately, not inside parse/compile), then times
  parse (read + XML + validation), compile, and the static analysis exactly as ``poise solve``
  runs it (redundancy detection, assembly, initial multipliers, Newton, outputs). The worker also
  times one sparse LU (``scipy.sparse.linalg.splu``, COLAMD, as the solver uses) of the KKT matrix
  ``model.evaluate(state).J`` at the solution, and one Jacobian evaluation. Peak memory is the
  worker's peak resident set size (``getrusage(RUSAGE_SELF).ru_maxrss``: whole process,
  interpreter and libraries included); per solve phase, the peak after it (``phases_peak``)
  and on Linux its own peak (``phases_own_peak``: the high-water mark reset at its start).
* **``poise --help``** and **``poise solve decks/pendulum_multiturn.xml``** (process start to HDF5
  written): wall time of the console script, median of ``--cli-repeat`` runs with min/max.

Output: one JSON object per benchmark (``--out``, JSON lines, machine info in every object) and a
markdown report (``--markdown``) with the targets of issue 2 §9 marked PASS/MISS. The report has
no dates, so regenerating it changes only the numbers. Nothing here is asserted by the tests
(``tests/cli/test_bench.py`` only runs a 10-link smoke case).
"""
from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path

SIZES = (10, 100, 1000, 10000)
GIB = 1024.0 ** 3
TARGETS = {
    "chain1000_iterations": 10,
    "chain1000_solve_s": 0.3,
    "chain10000_solve_s": 3.0,
    "chain10000_peak_bytes": 1.0 * GIB,
    "iteration_per_lu": 2.0,
    "help_s": 0.3,
    "small_deck_s": 0.4,
}
SMALL_DECK = "decks/pendulum_multiturn.xml"
ROOT = Path(__file__).resolve().parents[1]


# --------------------------------------------------------------------------- machine
def machine_info() -> dict:
    def ver(p):
        try:
            return metadata.version(p)
        except metadata.PackageNotFoundError:
            return None
    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    return dict(cpu=cpu, cores=os.cpu_count(), usable_cores=usable,
                python=platform.python_version(), implementation=platform.python_implementation(),
                system=f"{platform.system()} {platform.machine()}",
                numpy=ver("numpy"), scipy=ver("scipy"), lxml=ver("lxml"), h5py=ver("h5py"),
                poise=ver("poise"))


def _stats(xs):
    xs = [x for x in xs if x is not None]
    if not xs:
        return None
    return dict(median=statistics.median(xs), min=min(xs), max=max(xs), n=len(xs))


# --------------------------------------------------------------------------- worker (one case)
def _worker(deck: str, n: int) -> dict:
    """Run one chain case in this process; return the measurements (called via ``--worker``)."""

    t = time.perf_counter()
    import poise  # noqa: F401  (first, as in `poise solve`: it configures BLAS threads)
    import poise.solvers.context as context_mod
    import poise.solvers.frames as frames_mod
    import poise.solvers.quasistatic as qs_mod
    import numpy as np
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from poise.deck.parser import load_deck
    from poise.model.compile import compile_model
    from poise.app.model_outputs import model_datasets
    from poise.app.runner import plan
    from poise.results.data import AnalysisResult
    from poise.solvers.driver import Driver
    from poise.solvers.superlu import lean
    import poise.app.runner as runner_mod
    from poise.core import memory
    t_import = time.perf_counter() - t

    phases: dict[str, float] = {}
    phases_cpu: dict[str, float] = {}
    phases_peak: dict[str, int] = {}
    phases_own_peak: dict[str, int] = {}
    hwm = _HighWater()

    def rss_now():
        return hwm.peak()

    def timed(name, fn):
        def wrapper(*a, **kw):
            t0, c0 = time.perf_counter(), time.process_time()
            hwm.enter(name)
            try:
                return fn(*a, **kw)
            finally:
                phases[name] = phases.get(name, 0.0) + time.perf_counter() - t0
                phases_cpu[name] = phases_cpu.get(name, 0.0) + time.process_time() - c0
                own = hwm.leave(name)
                if own is not None:                # the phase's own peak (Linux)
                    phases_own_peak[name] = max(phases_own_peak.get(name, 0), own)
                phases_peak[name] = rss_now()      # the process's peak RSS after the phase
        return wrapper

    # phase timers around the static driver's steps (module globals, no source change)
    context_mod.detect_redundancy = timed("redundancy", context_mod.detect_redundancy)
    context_mod.assemble = timed("assembly", context_mod.assemble)
    context_mod.initial_multipliers = timed("multipliers", context_mod.initial_multipliers)
    qs_mod.solve_frame = timed("newton", qs_mod.solve_frame)   # Newton (+ recovery)
    frames_mod.min_norm_multipliers = timed("min_norm_reactions", frames_mod.min_norm_multipliers)
    # the stability classification of the frame
    frames_mod.classify = timed("stability", frames_mod.classify)

    t0 = time.perf_counter()
    spec = load_deck(deck)
    t1 = time.perf_counter()
    peak_parse = rss_now()
    model = compile_model(spec)
    t2 = time.perf_counter()
    peak_compile = rss_now()
    # the solve exactly as runner.run sequences it (one static analysis)
    reqs = plan(spec, None)
    dropped = len(spec.model) * runner_mod._ELEMENT_BYTES
    del spec                             # as runner.run: the parsed deck is not held by the solve
    memory.release(dropped)              # ... and its pages go back to the OS
    model_datasets(model)
    state = model.initial_state()
    drv = Driver(model, reqs[0], redundancy=None)
    c2, u2, f2 = time.process_time(), os.times(), _minor_faults()
    state, rec = drv.run(state, index=0)
    ar = AnalysisResult.of(rec)          # laid out, as runner.run does
    t3 = time.perf_counter()
    solve_cpu = time.process_time() - c2
    u3, f3 = os.times(), _minor_faults()
    peak_solve = rss_now()               # the process's peak up to the end of the solve
    iters = int(np.sum(ar.datasets["frames/iterations"]))
    status, counters, redundant = ar.status, drv.data.as_dict(), int(len(drv.redundancy))
    active = drv.data.active
    del rec, ar, drv                     # the measurements below hold only the model and state
    newton_lu, newton_lu_cpu = _newton_lu(model, state, reqs[0].settings, active)

    # one Jacobian evaluation and one sparse LU of the same KKT matrix at the solution
    eps = float(np.sqrt(reqs[0].settings.stability))
    ev_times = []
    for _ in range(3):
        te = time.perf_counter()
        J = model.evaluate(state, need_jac=True, eps_mass=eps, active=active).J
        ev_times.append(time.perf_counter() - te)
    Jc = sp.csc_matrix(J) if not sp.issparse(J) else J.tocsc()
    del J
    nnz, kkt_size = int(Jc.nnz), int(Jc.shape[0])
    lu_times = []
    for _ in range(5):
        tl = time.perf_counter()
        spla.splu(Jc, permc_spec="COLAMD", **lean(Jc.shape[0]))   # the solver's options
        lu_times.append(time.perf_counter() - tl)
    peak = rss_now()
    del Jc
    from benchmarks import floor
    parts = (floor.verdict_parts(model, state, reqs[0].settings, active)
             if n in floor.SIZES else None)      # (after the peak: not part of the solve's)
    newton_s = phases.get("newton", 0.0)
    return dict(n=n, nq=model.nq, nc=model.nc, nnz=nnz, kkt_size=kkt_size, verdict_parts=parts,
                import_s=t_import, parse_s=t1 - t0, compile_s=t2 - t1, solve_s=t3 - t2,
                iterations=iters, newton_s=newton_s,
                iteration_s=newton_s / iters if iters else None,
                lu_s=statistics.median(lu_times), evaluate_s=statistics.median(ev_times),
                solve_cpu_s=solve_cpu, solve_user_s=u3.user - u2.user,
                solve_sys_s=u3.system - u2.system, solve_faults=None if f2 is None else f3 - f2,
                newton_lu_s=newton_lu, newton_lu_cpu_s=newton_lu_cpu,
                phases=phases, phases_cpu=phases_cpu,
                phases_peak=phases_peak, phases_own_peak=phases_own_peak, counters=counters,
                redundant=redundant, status=status,
                peak_rss_bytes=int(peak), peak_parse_bytes=int(peak_parse),
                peak_compile_bytes=int(peak_compile), peak_solve_bytes=int(peak_solve))


def _minor_faults() -> int | None:
    """The process's minor page faults so far (None where ``resource`` is missing): with the
    solve's system time, how much fresh memory the kernel mapped and zeroed for it."""
    try:
        import resource
    except ImportError:
        return None
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt


class _HighWater:
    """The worker's peak resident set size, and each timed phase's own peak (Linux: the
    kernel's high-water mark is reset when a phase starts, ``/proc/self/clear_refs``; the
    process's peak is the largest mark seen, so it stays what ``ru_maxrss`` would say).
    Elsewhere only the process's peak (``ru_maxrss``), and no own peaks."""

    def __init__(self):
        import resource
        self._resource = resource
        self._seen = 0
        self._open: dict[str, int] = {}        # phase -> its peak so far (nested phases)
        self._reset = sys.platform.startswith("linux") and self._clear()

    def _mark(self) -> int:
        r = self._resource.getrusage(self._resource.RUSAGE_SELF).ru_maxrss
        return r if sys.platform == "darwin" else r * 1024

    def _clear(self) -> bool:
        try:
            with open("/proc/self/clear_refs", "w") as f:
                f.write("5")
            return True
        except OSError:
            return False

    def peak(self) -> int:
        return max(self._seen, self._mark())

    def enter(self, name: str) -> None:
        if not self._reset:
            return
        m = self._mark()                     # folded into the process's and open phases' peaks
        self._seen = max(self._seen, m)
        for k in self._open:
            self._open[k] = max(self._open[k], m)
        self._clear()
        self._open[name] = 0

    def leave(self, name: str) -> int | None:
        if not self._reset or name not in self._open:
            return None
        m = self._mark()
        self._seen = max(self._seen, m)
        for k in self._open:
            self._open[k] = max(self._open[k], m)
        return self._open.pop(name)


def _newton_lu(model, state, settings, active, repeat: int = 5):
    """Median wall and CPU seconds of the factorisation Newton performs at ``state``:
    :class:`poise.solvers.linalg.Factor` of the KKT Jacobian as Newton assembles it (mass
    shift, active rows), in the model's column order (made once per model: the solve made it)
    and through the column-ordered CSC layout, as Newton's factorisations (the layout is built
    at the first factorisation, the untimed one below)."""
    import numpy as np
    from poise.model.workspace import Workspace
    from poise.solvers.linalg import Factor
    ws = Workspace()
    eps = float(np.sqrt(settings.stability))
    J = model.evaluate(state, need_jac=True, eps_mass=eps, active=active, workspace=ws).J
    Factor(J)                              # a first factorisation, as Newton's (not timed)
    wall, cpu = [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        Factor(J)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu)


# --------------------------------------------------------------------------- parent
def _run_worker(deck: Path, n: int) -> dict:
    cmd = [sys.executable, "-m", "benchmarks.chain", str(deck), str(n)]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if r.returncode != 0:
        raise RuntimeError(f"benchmark worker failed for N={n}:\n{r.stderr}")
    return json.loads(r.stdout.strip().splitlines()[-1])


#: chain sizes from which the peak RSS of a whole ``poise solve`` process is measured too (the
#: worker's peak includes the bench's own reference LU, but not the runner's results and labels)
CLI_PEAK_FROM = 100000


def cli_peak(deck: Path, tmp: Path) -> int | None:
    """Peak RSS in bytes of one ``poise solve DECK`` process (HDF5 written), or None if it
    failed: read by an intermediate Python process whose only child it is
    (``RUSAGE_CHILDREN``), so no earlier benchmark process enters the maximum."""
    code = ("import resource, subprocess, sys\n"
            "rc = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL,"
            " stderr=subprocess.DEVNULL).returncode\n"
            "r = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss\n"
            "print(rc, r if sys.platform == 'darwin' else r * 1024)\n")
    cmd = [sys.executable, "-c", code, sys.executable, "-m", "poise", "solve", str(deck),
           "-o", str(tmp / "cli_peak.h5")]
    out = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    try:
        rc, peak = (int(x) for x in out.stdout.split())
    except ValueError:
        return None
    return peak if rc in (0, 1) else None


def bench_chain(n: int, repeat: int, tmp: Path) -> dict:
    from poise.gen.chain import build_chain_deck
    deck = tmp / f"chain_{n}.xml"
    deck.write_text(build_chain_deck(n, "revolute"))
    runs = [_run_worker(deck, n) for _ in range(repeat)]
    keys = ("import_s", "parse_s", "compile_s", "solve_s", "newton_s", "iteration_s", "lu_s",
            "evaluate_s", "peak_rss_bytes", "solve_cpu_s", "solve_user_s", "solve_sys_s",
            "solve_faults", "newton_lu_s", "newton_lu_cpu_s",
            "peak_parse_bytes", "peak_compile_bytes", "peak_solve_bytes")
    out = dict(bench="chain", n=n, joint="revolute", repeat=repeat)
    for k in ("nq", "nc", "nnz", "kkt_size", "iterations", "redundant", "status", "counters"):
        out[k] = runs[0][k]
    out["statuses"] = sorted({r["status"] for r in runs})
    for k in keys:
        out[k] = _stats([r[k] for r in runs])
    phase_names = sorted({p for r in runs for p in r["phases"]})
    out["phases"] = {p: _stats([r["phases"].get(p, 0.0) for r in runs]) for p in phase_names}
    out["phases_cpu"] = {p: _stats([r.get("phases_cpu", {}).get(p) for r in runs])
                         for p in phase_names}
    out["phases_peak"] = {p: _stats([r.get("phases_peak", {}).get(p) for r in runs])
                          for p in phase_names}
    out["phases_own_peak"] = {p: _stats([r.get("phases_own_peak", {}).get(p) for r in runs])
                              for p in phase_names}
    parts = [r["verdict_parts"] for r in runs if r.get("verdict_parts")]
    if parts:
        out["verdict_parts"] = {k: _stats([p[k] for p in parts]) for k in parts[0]
                                if k != "ldl_ok"}
        out["verdict_parts"]["ldl_ok"] = all(p["ldl_ok"] for p in parts)
    if n >= CLI_PEAK_FROM:
        out["cli_peak_rss_bytes"] = cli_peak(deck, tmp)
    it = out["iteration_s"]
    out["iteration_per_lu"] = (it["median"] / out["lu_s"]["median"]
                               if it and out["lu_s"]["median"] > 0 else None)
    return out


def _poise_cmd() -> list[str]:
    exe = Path(sys.executable).parent / "poise"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "poise_cli"]


def _user_env() -> dict:
    """The environment a user's process has: bytecode caching on (a development shell may set
    PYTHONDONTWRITEBYTECODE, which would make every run recompile poise's modules)."""
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def _walls(cmds: dict, repeat: int, cwd=None) -> dict:
    """Median/min/max wall time of each command over ``repeat`` runs after one warm-up run each
    (which writes the bytecode caches, as any second run of an installed program finds them).
    Several commands run round-robin, so that machine drift hits them alike. Returns
    ``{key: (stats, worst return code)}``."""
    env = _user_env()
    for c in cmds.values():
        subprocess.run(c, capture_output=True, cwd=cwd, env=env)
    times = {k: [] for k in cmds}
    rc = dict.fromkeys(cmds, 0)
    for _ in range(repeat):
        for k, c in cmds.items():
            t0 = time.perf_counter()
            r = subprocess.run(c, capture_output=True, cwd=cwd, env=env)
            times[k].append(time.perf_counter() - t0)
            rc[k] = max(rc[k], r.returncode)
    return {k: (_stats(v), rc[k]) for k, v in times.items()}


def _wall(cmd, repeat, cwd=None) -> tuple[dict, int]:
    """:func:`_walls` of one command."""
    return _walls({0: cmd}, repeat, cwd)[0]


def bench_cli(repeat: int, tmp: Path, root: Path) -> list[dict]:
    out = []
    st, rc = _wall(_poise_cmd() + ["--help"], repeat)
    out.append(dict(bench="help", command="poise --help", repeat=repeat, wall_s=st, returncode=rc))
    deck = root / SMALL_DECK
    h5 = tmp / "small.h5"
    st, rc = _wall(_poise_cmd() + ["solve", str(deck), "-o", str(h5)], repeat)
    out.append(dict(bench="small_deck", command=f"poise solve {SMALL_DECK} -o small.h5",
                    repeat=repeat, wall_s=st, returncode=rc, written=h5.exists()))
    return out


# --------------------------------------------------------------------------- report
def _pf(ok) -> str:
    return "—" if ok is None else ("PASS" if ok else "MISS")


def _s(x, digits=3) -> str:
    if x is None:
        return "—"
    if x >= 100:
        return f"{x:.0f}"
    return f"{x:.{digits}g}"


def _mmm(st, unit="s") -> str:
    if not st:
        return "—"
    return f"{_s(st['median'])} ({_s(st['min'])}–{_s(st['max'])})"


def targets(results: list[dict]) -> list[tuple[str, str, str, bool | None]]:
    """(target, limit, measured, ok) rows for the report."""
    chains = {r["n"]: r for r in results if r["bench"] == "chain"}
    cli = {r["bench"]: r for r in results if r["bench"] in ("help", "small_deck")}
    rows = []
    c1 = chains.get(1000)
    if c1:
        ok = c1["status"] == "converged" and c1["iterations"] <= TARGETS["chain1000_iterations"]
        rows.append(("N = 1000 chain converges, Newton iterations", "≤ 10",
                     f"{c1['iterations']} ({c1['status']})", ok))
        v = c1["solve_s"]["median"]
        rows.append(("N = 1000 chain solve time", "≤ 0.3 s", f"{_s(v)} s",
                     v <= TARGETS["chain1000_solve_s"]))
    c4 = chains.get(10000)
    if c4:
        v = c4["solve_s"]["median"]
        rows.append(("N = 10 000 chain solve time", "≤ 3 s", f"{_s(v)} s",
                     v <= TARGETS["chain10000_solve_s"] and c4["status"] == "converged"))
        tot = c4["parse_s"]["median"] + c4["compile_s"]["median"] + v
        rows.append(("N = 10 000 chain parse + compile + solve (informative)", "—",
                     f"{_s(tot)} s", None))
        m = c4["peak_rss_bytes"]["max"]
        rows.append(("N = 10 000 chain peak memory (RSS)", "≤ 1 GiB", f"{m / 2**20:.0f} MiB",
                     m <= TARGETS["chain10000_peak_bytes"]))
    for n, c in sorted(chains.items()):
        if n < 1000 or c["iteration_per_lu"] is None:
            continue
        v = c["iteration_per_lu"]
        rows.append((f"N = {n}: time per Newton iteration / one sparse LU", "≤ 2",
                     f"{v:.2f} ({_s(c['iteration_s']['median'] * 1e3)} ms / "
                     f"{_s(c['lu_s']['median'] * 1e3)} ms)", v <= TARGETS["iteration_per_lu"]))
    if "help" in cli:
        v = cli["help"]["wall_s"]["median"]
        rows.append(("`poise --help` wall time", "≤ 0.3 s", f"{_s(v)} s",
                     v <= TARGETS["help_s"] and cli["help"]["returncode"] == 0))
    if "small_deck" in cli:
        c = cli["small_deck"]
        v = c["wall_s"]["median"]
        rows.append(("small deck end to end (process start → HDF5 written)", "≤ 0.4 s",
                     f"{_s(v)} s", v <= TARGETS["small_deck_s"] and c["returncode"] == 0
                     and c["written"]))
    return rows


PROFILE_NOTES = """\
## Where the time goes

Profiled with cProfile on the 1000- to 100 000-link chains (numbers below from this 2-core
machine while other jobs were running; the tables above are re-measured by every `make bench`).

**Parse** (`deck/parser.py`, `deck/validate.py`; 10 000 links: 3.3–4.1 s → ≈ 1.0 s, 100 000
links: 59 s → ≈ 13 s). Python work per attribute was the cost (a schema lookup, a number parse
and a dictionary store for each of the 600 000 attributes, then a second pass per attribute in
validation). Now lxml runs with a parser *target* (same secure options; no tree is built) and
element lines come from one vectorised byte scan (the `<` opening each start tag, outside
comments, CDATA, processing instructions and the DOCTYPE), which the tree walk uses too.
Decks in UTF-16/32 or another encoding the scan cannot read are re-encoded as UTF-8 first.
Anything unusual (malformed XML, a count mismatch) takes the tree walk, which reports the same messages. Elements are typed in batches grouped by
*shape* (tag and attribute names as written): each shape is analysed once (schema, canonical
names, unknown/duplicate-attribute warnings, defaults) and values are typed column by column
(`float`/`int` mapped over a column after a one-pass character check). Validation screens each
shape column-wise (types, finiteness, bounds, enums, references, required attributes; direction
cosines and inertia eigenvalues in batches) and runs the element-by-element checks only on
elements that may have a problem, in document order, so messages, their order and FILE:LINE are
unchanged (`tests/kernels/test_deck_fast_path.py` compares both paths). Cyclic garbage collection is
paused while parsing.
What remains at 10 000 links: lxml itself ≈ 0.35 s and `float()` of 600 000 17-digit numbers
≈ 0.2 s.

**Compile** (`model/compile*.py`; 10 000 links: 1.7–2.5 s → 0.4–0.65 s, 100 000 links: 31 s →
≈ 8 s). `DeckSpec.elements()` scanned the whole deck once per call (28 calls); the compiler now
reads a tag index built once (`DeckSpec.indexed()`). Marker poses (`rm_id` chains composed level
by level), bodies (inertia transforms) and marker arrays are batched numpy; joints are compiled
from per-type row templates; couplers, gears and user elements found joints and markers by
scanning the deck per element (quadratic) and now use dictionaries; the assembler's pattern uses
a stable (run-merging) sort instead of `np.unique`. `tests/methods/test_scaling.py` guards linear
scaling with call counts (200 vs 2000 links; 287 Python-level calls per link, was 1750).

**Solve.** One static analysis factorises 8 times: the Gram matrix for redundancy detection,
the least-squares initial multipliers, one per Newton iteration (5) and the minimum-norm
reactions; it assembles the KKT Jacobian 8 times. The family tangents were dense
`(n, 6K, 6K)` arrays (`B^T G B` by batched 3×3 products) gathered down to their structural
entries. `families/base.py: tangent_compact` now builds only the non-zero 3×3 blocks,
component-major (each operation over all instances, the skew products as cross products, slots
without a reaction skipped), and the model registers the entries in that order (no gather, no
transpose); the assembler reuses its value buffer. One Jacobian at 10 000 links: 75–80 ms →
22 ms (one SuperLU factorisation 120 ms: 0.6 → 0.18 of an LU); at 100 000 links ≈ 0.3 s
alone and 0.3–0.6 s inside a run (LU ≈ 1.5–1.8 s; fresh large arrays page-fault, about a third
of that run is system time). Newton reuses the step-limit retraction as the first line-search
trial. What is left of “other” at 30 000–100 000 links is mostly outside Newton: the stability
classification of the converged state and the Gram factorisations of redundancy detection
(neither goes through `Factor`, so neither counts as *factorise*), then the linear solves with
iterative refinement.

**Floor (issue 25 §2).** The phase table of *Static solve vs its floor* gives each phase in
Newton's LUs (the floor's unit, one per iteration). Newton's five iterations on these chains
cost ≈ 5–7 of them: three LUs (the last two iterations are chord steps by the third, Newton's
quadratic phase: `steps.chord_step`), three Jacobian evaluations and assemblies (≈ 0.5 each), a
residual evaluation per iteration, the steps' solves with refinement and the neutral-direction
filter's extra solve (a second one only next to neutral directions). Newton's factorisations
leave out the KKT matrix's stored exact zeros (`linalg.stored_nonzeros`, S18): the assembled
pattern holds every entry a family's block may fill, and on these chains 45 % of them are zero at
every iteration (the out-of-plane multipliers and components of a planar chain: the model's
zeros, not the families', see DESIGN.md; a family whose multipliers are all zero forms no
values, S19); SuperLU
counts them as nonzeros, and they doubled the factors' fill (10⁴ links: 2.3 M → 1.0 M entries in
L and U, the same pivots). That halved the LU and its solves — and with it the floor's unit, so
the ratios rose while every solve got faster. Outside
Newton, redundancy detection factorises a Gram matrix (twice when a candidate row is
ambiguous, as on these closed chains) and the least-squares multipliers a weighted Gram matrix
(normal equations; banded on these chains: LAPACK's banded Cholesky, a few percent of an LU), and
the classification needs its own sparse LDLᵀ (inertia: an LU with partial pivoting has none) and
a Krylov iteration for the lowest mode (one-column solves until the angle bound of its Ritz
vector is below 10⁻⁵: 5 on these chains). The classification factorises once: SuperLU's CSC copies of L and U, read for
the pivots and the backward error, are made absolute in place and emptied one after the other.
That LDLᵀ costs 1.5–3.0 of Newton's LUs (S20, 10³–10⁵ links). At 10⁴ its L has 0.93 M
entries, as many as Newton's L and U together, but SciPy's only sparse direct solver computes
U = D Lᵀ as well, twice an LDLᵀ's work, and its pivots are read from a copy of U. The table *What a solve with a
certified verdict cannot leave out* adds up what no certified FIM_S solve with a stability verdict
can skip on these chains, each part as poise does it. At 10⁴ and 10⁵ links it comes to the
target's whole budget (2 × iterations) or within a few tenths of an LU of it (S20: 9.5 and 11.0
LUs of 10) before redundancy detection (1.3–2.4 LUs there; these closed chains have redundant
rows), the initial multipliers, the line search, refinement, reactions and outputs are counted;
at 10³ it leaves 2–3 LUs, less than those measure there (≈ 4).
From 10⁴ to 10⁵ links the solve's *user* CPU time grows ≈ 9.5× but its *system* time ≈ 20×
(0.13 → 2.9–3.4 s): at 10⁵ links every array above glibc's mmap threshold (32 MB at most; the KKT
matrix's data are 140 MB, a family's tangent blocks 50–200 MB) is mapped afresh and its pages
zeroed by the kernel at every allocation — ≈ 7 GB per solve — where at 10⁴ links the same arrays
reuse freed heap memory. That, more than cache misses, sets the solve-time exponent. The
assembler's column order and column-ordered CSC layout are built from index arrays (no sparse
products, conversions or column selections) and pooled assembly widens its int32 slots a chunk
at a time; families above 2¹⁵ instances make their kernel outputs in chunks of instances, and
the classification's equilibration works in passes over small buffers, so its temporaries stay
below the threshold (≈ 0.5–1 GB fewer fresh pages per 10⁵ solve); its permuted KKT matrix is
gathered by scipy's compiled kernels from whole-size arrays, which the kept heap serves (S17:
no more page faults in the 10⁵ classification than the former chunked scatter).
What remains (S14, one 10⁵ solve: user 5.0–5.6 s, system 1.4–2.4 s run to run, ≈ 0.4 M small
and ≈ 1.2 k huge-page faults, ≈ 4 GB zeroed) is, by allocation site: SuperLU's factor storage in
its six factorisations (3 in Newton, the LDLᵀ, the Gram matrix of the left null basis, the COLAMD
ordering), ≈ 300 k small-page faults (1.2 GB, 0.4 s of system time inside `splu`; scipy offers no
way to hand SuperLU a reused workspace); numpy/scipy arrays above the threshold, ≈ 1.5 GB in ≈ 40
allocations, nearly all made once per solve (column order, CSC layout, the classification's
permuted KKT, SuperLU's CSC copy of U for the pivots, Krylov blocks; 3 tangent blocks of 58 MB);
and the heap regrown after trims (≈ 1.2 GB by `brk`, 0.6 GB given back by `malloc_trim` between
stages). Reuse that the peak allows gains nothing measurable against the run-to-run noise: no trims
inside the solve (the classification's own peak 1.26 → 1.31–1.35 GB, same CPU), a 128–512 MB trim
threshold (80 k fewer faults, same system time, peak +40 MB), the CSC layout from the first
factorisation (35 k fewer faults, same time). Huge pages for SuperLU's storage too
(`GLIBC_TUNABLES=glibc.malloc.hugetlb=1`) cut the faults 0.41 → 0.06 M but not the time (7
alternations: system medians 2.15 s both, solve CPU 7.3 vs 7.5 s): the kernel's cost is per byte
zeroed, not per fault; only fewer fresh bytes would lower it.
Keeping big arrays in the heap (a raised mmap threshold) cuts ≈ 1 s of system time at 10⁵ links
but lifts the peak RSS to 1.50 GB (heap fragmentation). S16: a large model's solve runs with the
heap kept (`core/memory.kept_heap` around `Driver.run`, ≥ 2¹⁹ unknowns: glibc `mallopt`, no mmap
and no trim of the heap's top; glibc's defaults restored and the heap trimmed after), and each
SuperLU factorisation inside it trims the heap and maps its storage afresh (`memory.mapped`):
SuperLU reserves its factors' storage by its fill estimate and touches what it fills (S17, strace:
no reallocation); from a kept heap, arrays made between two factorisations shift the next one's
storage, and the pages both touched stayed resident and set the peak (whole `poise solve`
1.47–1.61 GB without `mapped`). With both, 10⁵ links (3 lockstep pairs): system 2.19 → 1.84 s, solve CPU 9.67 → 9.47 s, whole `poise solve`
peak 1.41 → 1.37–1.38 GB.
The solve's memory peaks in Newton
(*after newton*); the *whole worker* column adds the bench's own reference LU (COLAMD, default
options) and evaluations after the solve, which a `poise solve` does not run. The parsed deck is
dropped before the solve and its pages returned to the OS (`malloc_trim`).

**BLAS threads.** numpy's OpenBLAS defaulted to 2 threads; on vectors and 3×3 blocks they
only busy-wait, and with another process on the machine a 1000-link solve took 1.8× longer
(0.73 s vs 0.41 s). `import poise` now sets `OPENBLAS_NUM_THREADS=1` unless the environment
says otherwise.

**Start-up** (`poise --help`, small deck end to end). `--help` imports only click and the
command modules. A solve imports numpy, scipy.sparse and scipy.linalg (≈ 0.25 s), lxml and h5py
(≈ 0.1 s) before any work, then the solver modules of every analysis kind (≈ 0.1 s more). The
expression syntax check in `deck/validate.py` imported `poise.expr` — and through its spline
module `scipy.interpolate`, 0.5–0.9 s — for every deck; it now returns before importing when
the deck has no expression attribute. What is left of the small-deck miss is interpreter +
library import time (≈ 0.35 s of the budget) plus machine load: on this shared 2-core machine
the same command varies between 0.4 and 1 s.
"""


def render_markdown(results: list[dict], machine: dict) -> str:
    chains = [r for r in results if r["bench"] == "chain"]
    cli = [r for r in results if r["bench"] in ("help", "small_deck")]
    out = ["# Performance", "",
           "Generated by `make bench` (`python -m benchmarks`); do not edit by hand. Targets are "
           "those of issue 2 §9 on a 2-core machine; they are measured here and never asserted in "
           "timed tests.", "",
           "## Machine", "",
           f"- CPU: {machine['cpu'] or 'unknown'}; {machine['cores']} cores "
           f"({machine['usable_cores']} usable)",
           f"- {machine['system']}, {machine['implementation']} {machine['python']}",
           f"- numpy {machine['numpy']}, scipy {machine['scipy']}, lxml {machine['lxml']}, "
           f"h5py {machine['h5py']}", "",
           "## Targets", "",
           "| target | limit | measured (median) | result |", "|---|---|---|---|"]
    for name, lim, meas, ok in targets(results):
        out.append(f"| {name} | {lim} | {meas} | {_pf(ok)} |")
    if chains:
        reps = sorted({c["repeat"] for c in chains})
        more = ", ".join(str(c["n"]) for c in chains if c["repeat"] != reps[0])
        rep = f"{reps[0]} runs" + (f" ({more} links: {reps[-1]}, the sizes of the floor targets)"
                                   if more else "")
        out += ["", "## Hanging chains (revolute joints)", "",
                f"`poise.gen.chain` decks (link 100 mm, span 0.8·N·100 mm, 3 redundant "
                f"equations). Median of {rep} (min–max), each in a fresh process; times in "
                "seconds. *LU* is one `splu` (COLAMD) of the KKT matrix at the solution; "
                "*iter/LU* is the Newton time per iteration over that. *Peak RSS* is the whole "
                "worker process (`ru_maxrss`, interpreter and libraries included).", "",
                "| N | unknowns | nnz | parse | compile | solve | iterations | time/iteration | "
                "one LU | iter/LU | peak RSS | status |",
                "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for c in chains:
            it = c["iteration_s"]
            out.append(
                f"| {c['n']} | {c['kkt_size']} | {c['nnz']} | {_mmm(c['parse_s'])} | "
                f"{_mmm(c['compile_s'])} | {_mmm(c['solve_s'])} | {c['iterations']} | "
                f"{_s(it['median']) if it else '—'} | {_s(c['lu_s']['median'])} | "
                f"{_s(c['iteration_per_lu'], 2) if c['iteration_per_lu'] else '—'} | "
                f"{c['peak_rss_bytes']['max'] / 2**20:.0f} MiB | {c['status']} |")
        names = ["redundancy", "assembly", "multipliers", "newton", "min_norm_reactions",
                 "stability"]
        out += ["", "### Solve phases (median seconds)", "",
                "Phases of the static analysis; *stability* is the classification of the "
                "converged frame (dense eigen-decomposition up to 3000 coordinates, sparse "
                "LDLᵀ inertia of the KKT matrix above: N ≥ 500); *evaluate* is one residual + "
                "KKT Jacobian evaluation at the solution; counters are for the whole analysis.",
                "",
                "| N | " + " | ".join(names) + " | evaluate | residuals | Jacobians | "
                "factorisations |", "|---" * (len(names) + 5) + "|"]
        for c in chains:
            ph = c["phases"]
            cells = [_s(ph[p]["median"]) if p in ph else "—" for p in names]
            k = c["counters"]
            out.append(f"| {c['n']} | " + " | ".join(cells) + f" | {_s(c['evaluate_s']['median'])}"
                       f" | {k['residuals']} | {k['jacobians']} | {k['factorizations']} |")
    if cli:
        out += ["", "## Command line", "",
                f"Wall time of the console script, median of {cli[0]['repeat']} runs (min–max).",
                "", "| command | wall time (s) | exit code |", "|---|---|---|"]
        for c in cli:
            out.append(f"| `{c['command']}` | {_mmm(c['wall_s'])} | {c['returncode']} |")
    out += ["", PROFILE_NOTES]
    return "\n".join(out).rstrip() + "\n"


# --------------------------------------------------------------------------- main


if __name__ == "__main__":      # the fresh-process worker of bench_chain: DECK N
    print(json.dumps(_worker(sys.argv[1], int(sys.argv[2]))))
