"""Parameter sweeps on Dask distributed (``poise sweep`` and ``poise.sweep(...)``).

A sweep substitutes attribute values into the parsed deck (:class:`~poise.deck.spec.DeckSpec`),
one *case* per combination (:mod:`poise.app.cases`). Cases are grouped by structure (their
enum and boolean values) and sent to the workers in chunks, one Dask task per chunk
(:mod:`poise.app.chunks`), on a ``LocalCluster`` (worker processes, one thread each, no
dashboard) or on an existing cluster given by its scheduler address. The workers send each
chunk's rows back; this process writes them, as they come, into **one sweep file**
``OUT_DIR/sweep.h5`` (:mod:`poise.results.sweepfile`: netCDF-4, dimension ``case``, the swept
parameters as coordinates, declared in :mod:`poise.results.schema_sweep`) and a journal of
finished chunks (:mod:`poise.app.sweep_journal`). The file is written to a temporary name and
renamed when the sweep ends; then ``OUT_DIR/index.csv`` and ``index.json`` (one row per case,
:mod:`poise.app.sweep_index`) are written from it. With ``per_case_files`` each case also
writes ``OUT_DIR/case_NNNNN.h5`` from its worker (with a remote cluster OUT_DIR must then be on
a filesystem the workers share). Resuming: cases already solved with the same deck, options
and values are taken from the journal or the previous sweep file instead of solved again.
Decks naming Python user routines need ``allow_user_code``, passed on to the workers.
"""
from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import dataclass, field, replace

import numpy as np

from poise.app.batch import check_outputs, ensure_out_dir, worst_exit_code
from poise.app.cases import MAX_CASES, Param, apply_case, check_case_count, chunks
from poise.app.cases import chunk_size as auto_chunk_size
from poise.app.cases import group_cases, make_cases, parse_set, resolve_param
from poise.app.chunks import (FrameLayout, SweepJob, make_template, overrides_with_ignore,
                              pack, run_chunk, solve_chunk)
from poise.app.engine import WORKER_TIMEOUT, NoWorkers, check_scheduler, dask_client, run_tasks
from poise.app.runner import check_ignore, ignore_kinds, plan
from poise.app.sweep_index import (INDEX_KEYS, INDEX_VERSION, index_keys, index_rows,  # noqa: F401
                                   output_groups, output_units, outputs_of, parse_outputs,
                                   source_item, write_index)
from poise.app.sweep_journal import Journal, reuse, value_keys
from poise.core.atomic import atomic_output
from poise.core.dirlock import directory_lock
from poise.core.errors import DeckError, UsageError
from poise.core.extras import require
from poise.core.progress import Bar, ending, note
from poise.core.version import __version__
from poise.deck.parser import parse_deck_bytes
from poise.solvers.settings import check_override_names
from poise.results.sweepfile import SweepWriter

SWEEP_FILE = "sweep.h5"


@dataclass
class SweepOutcome:
    """What a sweep did: ``path`` (the sweep file), ``index`` (``index.csv``), ``n_cases``,
    ``counts`` (cases per status), ``exit_code`` (the worst case's), ``n_resumed`` (cases
    taken from an earlier run), ``timings`` (seconds: ``wall``, ``start`` (the cluster),
    ``solve`` (the cases' own wall times, summed over the workers), ``write`` (the sweep file,
    journal and index), ``resume``), ``workers`` and ``chunk_size``; ``rows``: the index rows
    when asked for."""

    path: str
    index: str
    n_cases: int
    counts: dict
    exit_code: int
    n_resumed: int
    timings: dict = field(default_factory=dict)
    workers: int = 0
    chunk_size: int = 0
    rows: list | None = None
    ignored: str = ""


def run_sweep(deck, sets, mode: str = "grid", out_dir: str = "sweep", scheduler=None,
              outputs=(), n=None, seed=0, workers=None, overrides=None, force=False,
              progress: bool | None = None, on_row=None, client=None,
              allow_user_code: bool = False, max_cases: int | None = MAX_CASES,
              worker_timeout: float | None = WORKER_TIMEOUT, ignore=(),
              chunk_size: int | None = None, per_case_files: bool = False,
              rows: bool = False, command: str = "poise.sweep") -> SweepOutcome:
    """Run a sweep: write ``OUT_DIR/sweep.h5`` and ``index.csv``/``.json``; return a
    :class:`SweepOutcome`.

    Parameters
    ----------
    deck : str
        Deck path.
    sets : dict or list
        ``{"Tag[id].attr": values}`` (values: list, ``"a:b:step"`` or ``"v1,v2"``), or a list
        of ``"Tag[id].attr=values"`` strings.
    mode : ``"grid"``, ``"zip"`` or ``"random"`` (with ``n`` cases and ``seed``).
    out_dir : str
        The sweep file, the index (and the case files of ``per_case_files``).
    scheduler : str, optional
        Address of an existing Dask scheduler (``tcp://host:port``); default: a LocalCluster
        with ``workers`` processes (default: CPU count), one thread each, no dashboard.
    outputs : list of str
        ``group[id].dataset`` variables of the sweep file (every frame) and columns of the
        index (the last frame).
    overrides : dict, optional
        Solver overrides for every case (like ``poise solve`` options).
    force : bool
        Solve every case again (nothing taken from an earlier run).
    client : dask.distributed.Client, optional
        Use this client (library use); ``scheduler`` and ``workers`` are then ignored.
    allow_user_code : bool
        Run the Python user routines the deck names, in the workers (default False: such a
        deck gives ``invalid_deck`` cases saying how to allow them).
    max_cases : int or None
        Refuse sweeps with more cases (counted before any is made); None: no cap.
    progress : bool or None
        The cases-done bar (poise.core.progress; None: automatic). False also silences Dask.
    on_row : callable, optional
        Called with ``{"case", parameters..., "status", "exit_code", "message"}`` as each
        case is written.
    worker_timeout : float or None
        Seconds the cluster may have no worker before the sweep gives up
        (:class:`poise.app.engine.NoWorkers`, exit 2; the sweep file and the index keep the
        finished cases, the others have status ``not_run``).
    ignore : iterable of str
        Adams datasets: kinds of statements left out instead of refused (``--ignore``), in
        every case; recorded in the sweep file and the index.
    chunk_size : int, optional
        Cases per Dask task (default: about eight chunks per worker, at most 1000 cases).
    per_case_files : bool
        Also write each case's results file ``case_NNNNN.h5`` (from its worker).
    rows : bool
        Also return the index rows (``SweepOutcome.rows``; for ``--json``).
    command : str
        Recorded in the sweep file.

    Raises
    ------
    poise.core.errors.UsageError
        Bad ``sets``/``outputs``/mode (exit 2 in the CLI).
    poise.core.errors.DeckError
        The base deck is invalid (exit 3).
    """
    t_start = time.perf_counter()
    if client is None:
        require("sweep", "poise sweep")     # exit 2 with the pip command in a lean install
    deck = os.fspath(deck)
    check_ignore(deck, ignore)
    kinds = ignore_kinds(deck, ignore)
    try:
        with open(deck, "rb") as f:
            data = f.read()
    except OSError as e:
        raise UsageError(f"cannot read deck {deck!r}: {e.strerror or e}") from None
    spec = parse_deck_bytes(data, deck, **({"ignore": kinds} if kinds else {}))
    items = [parse_set(s) for s in sets] if isinstance(sets, (list, tuple)) else list(sets.items())
    if not items:
        raise UsageError("nothing to sweep: give at least one --set Tag[id].attr=VALUES")
    params = [resolve_param(spec, k, v) for k, v in items]
    if len({p.key for p in params}) != len(params):
        raise UsageError("the same attribute is given twice in --set")
    parsed = parse_outputs(spec, outputs)
    outs = outputs_of(parsed)
    col_units = output_units(spec, parsed)
    if chunk_size is not None and int(chunk_size) < 1:
        raise UsageError(f"--chunk-size {chunk_size}: expected a positive number of cases")
    check_case_count(params, mode, n=n, max_cases=max_cases)
    if scheduler and client is None:
        check_scheduler(scheduler)
    cases = make_cases(params, mode, n=n, seed=seed)
    check_override_names(overrides)
    overrides = {k: v for k, v in (overrides or {}).items() if v is not None}
    layout = frame_layout(spec, params, cases, overrides)
    width = max(5, len(str(len(cases) - 1)))
    out_abs = os.path.abspath(out_dir)
    sweep_path = os.path.join(out_dir, SWEEP_FILE)
    targets = [sweep_path] + [os.path.join(out_dir, f"index.{x}") for x in ("csv", "json")]
    if per_case_files:
        targets += [os.path.join(out_abs, f"case_{i:0{width}d}.h5") for i in range(len(cases))]
    check_outputs(targets, [deck])
    ensure_out_dir(out_dir)
    hashed = overrides_with_ignore(overrides, kinds)
    sweep_hash = hashlib.sha256(json.dumps(
        {"deck_sha256": spec.sha256, "overrides": hashed, "poise_version": __version__},
        sort_keys=True, default=str).encode()).hexdigest()
    # the parameters without their values: a task carries its own cases' values only
    job = SweepJob(data, deck, tuple(replace(p, values=[]) for p in params), overrides, outs,
                   layout, bool(allow_user_code),
                   tuple(kinds), out_abs if per_case_files else None, width,
                   hashlib.sha256(sweep_hash.encode() + json.dumps(
                       [p.key for p in params]).encode()).hexdigest())
    attrs = {"deck": deck, "deck_sha256": spec.sha256, "units": _units(spec),
             "command": command, "mode": mode,
             "parameters": {p.key: p.values for p in params}, "overrides": hashed,
             "outputs": json.dumps([o.text for o in outs]), "sweep_hash": sweep_hash,
             **({"seed": int(seed)} if mode == "random" and seed is not None else {}),
             **({"ignored": spec.ignored} if kinds and spec.ignored else {})}
    head = {"index_version": INDEX_VERSION, "deck": deck, "deck_sha256": spec.sha256,
            "mode": mode, "parameters": {p.key: p.values for p in params},
            "overrides": overrides, "n_cases": len(cases), "sweep_file": SWEEP_FILE,
            **({"ignore": list(kinds), "ignored": spec.ignored} if kinds else {})}
    with directory_lock(out_dir, "sweep", say=lambda line: note(line, progress)):
        run = _Run(job, params, cases, out_dir, sweep_path, attrs, progress, on_row,
                   per_case_files)
        try:
            with atomic_output(sweep_path, [deck]) as tmp:
                run.open(tmp)
                try:
                    run.resume(force, allow_user_code)
                    run.solve(scheduler, workers, client, chunk_size, worker_timeout)
                except NoWorkers as e:
                    run.gave_up = e
                run.close()
        except BaseException as e:
            run.bar.close(ending(e))       # the last progress line says "interrupted"
            raise
        run.journal.clear()                # every finished case is in the sweep file now
        t0 = time.perf_counter()
        ignored = _ignored_text(spec.ignored) if kinds else ""
        keys = index_keys(params, outs)
        kept: list | None = [] if rows else None

        def stream():
            for r in index_rows(sweep_path, params, outs, run.taken, ignored, run.done):
                if kept is not None:
                    kept.append(r)
                yield r
        write_index(stream(), os.path.join(out_dir, "index"), keys, head, col_units)
        run.timings["write"] += time.perf_counter() - t0
        run.timings["wall"] = time.perf_counter() - t_start
        run.bar.close(ending(run.gave_up))
        done_status = run.status[run.done]
        counts: dict = {}
        for s in done_status.tolist():
            counts[s] = counts.get(s, 0) + 1
        outcome = SweepOutcome(sweep_path, os.path.join(out_dir, "index.csv"), len(cases),
                               counts, worst_exit_code(run.exit[run.done].tolist()),
                               int(run.taken.sum()), run.timings, run.workers, run.size, kept,
                               ignored)
        if run.gave_up is not None:        # the sweep file and the index keep what finished
            run.gave_up.outcome = outcome
            run.gave_up.rows = kept or []
            raise run.gave_up
        return outcome


class _Run:
    """The state of one sweep between the lock and the index: the sweep file being written,
    the journal, which cases are done (and taken from an earlier run), the progress bar."""

    def __init__(self, job: SweepJob, params, cases, out_dir, sweep_path, attrs, progress,
                 on_row, files):
        n = len(cases)
        self.job, self.params, self.cases, self.out_dir = job, params, cases, out_dir
        self.sweep_path, self.attrs, self.on_row, self.files = sweep_path, attrs, on_row, files
        self.done = np.zeros(n, bool)
        self.taken = np.zeros(n, bool)
        self.status = np.full(n, "not_run", dtype=object)
        self.exit = np.full(n, -1, np.int64)
        self.bar = Bar(n, "sweep", "cases", enabled=progress, delay=0.0)
        self.quiet = progress is False
        self.journal = Journal(out_dir, {"sweep_hash": attrs["sweep_hash"],
                                         "n_frames": job.layout.n,
                                         "outputs": [o.text for o in job.outputs]})
        self.timings = {"start": 0.0, "solve": 0.0, "write": 0.0, "resume": 0.0}
        self.input_files = ""
        self.gave_up: NoWorkers | None = None
        self.writer: SweepWriter | None = None
        self.workers = 0
        self.size = 0
        self._batch_template = False        # not decided yet (see _together)

    def open(self, tmp: str) -> None:
        layout = self.job.layout
        self.writer = SweepWriter(
            tmp, len(self.cases), layout.time, layout.analysis,
            [(p.key, p.kind, [c[p.key] for c in self.cases]) for p in self.params],
            [(o.text, source_item(o.group, o.dataset)) for o in self.job.outputs],
            self.attrs, files=self.files)

    def write(self, rows: dict, fresh: bool = True) -> None:
        """Rows of finished cases into the sweep file (and, when ``fresh``, the journal)."""
        t0 = time.perf_counter()
        idx = np.asarray(rows["case"], np.int64)
        self.writer.write(rows)
        if fresh:
            self.journal.add(rows, {p.key: np.asarray([self.cases[i][p.key] for i in idx])
                                    for p in self.params})
            self.timings["solve"] += float(np.nansum(np.asarray(rows["wall_time"], float)))
        if rows.get("input_files"):
            self.input_files = rows["input_files"]
        self.done[idx] = True
        self.status[idx] = np.asarray(rows["status"], dtype=object)
        self.exit[idx] = np.asarray(rows["exit_code"], np.int64)
        self.timings["write"] += time.perf_counter() - t0
        if self.on_row:
            self.bar.clear()
            for j, i in enumerate(idx.tolist()):
                self.on_row({"case": i, **self.cases[i], "status": self.status[i],
                             "exit_code": int(self.exit[i]),
                             "message": str(np.asarray(rows["message"])[j])})
        self.bar.step(len(idx))

    def resume(self, force: bool, allow_user_code: bool) -> None:
        t0 = time.perf_counter()
        if force:
            self.journal.clear()
        else:
            keys = value_keys(self.params, {p.key: [c[p.key] for c in self.cases]
                                            for p in self.params})
            names = [n for n in self.writer.items if n not in ("case", "time", "analysis")]
            self.taken = reuse(self.journal, self.sweep_path,
                               {"sweep_hash": self.attrs["sweep_hash"],
                                "n_frames": self.job.layout.n},
                               self.params, keys, [o.text for o in self.job.outputs], names,
                               lambda rows: self.write(rows, fresh=False), self.out_dir,
                               self.files, allow_user_code)
        self.timings["resume"] = time.perf_counter() - t0

    def solve(self, scheduler, workers, client, size, worker_timeout) -> None:
        if scheduler is None and client is None and not size:
            self.head_start()
        todo = np.nonzero(~self.done)[0].tolist()
        if not todo:
            return
        t0 = time.perf_counter()
        with dask_client(scheduler, workers, len(todo), client, quiet=self.quiet,
                         allowed_failures=0, worker_timeout=worker_timeout) as cl:
            self.timings["start"] = time.perf_counter() - t0
            self.workers = max(1, _threads(cl) or workers or os.cpu_count() or 1)
            per_case = 8 * self.job.layout.n * (1 + sum(int(np.prod(o.trailing, dtype=int))
                                                        for o in self.job.outputs)) + 512
            groups = group_cases(self.params, self.cases, todo)
            self.size = int(size) if size else auto_chunk_size(
                len(todo), self.workers, per_case, per_worker=2 if self._together(groups) is not None else 8)
            _run_chunks(cl, self, chunks(groups, self.size), worker_timeout)

    def head_start(self) -> None:
        """Cases solved together are solved here, in this process, while that is quicker than
        starting worker processes: a first chunk of the largest batched group is timed, and the
        rest follows here only if it would take less than :data:`HEAD_START_S` (about what a
        local cluster takes to start and close). Groups that are not solved together, and the
        rest of a large sweep, go to the cluster as before."""
        todo = np.nonzero(~self.done)[0].tolist()
        groups = group_cases(self.params, self.cases, todo)
        template = self._together(groups)
        if template is None:
            return
        group, idx = max(groups.values(), key=lambda g: len(g[1]))
        size = max(1, min(HEAD_CHUNK, -(-len(idx) // 10)))      # progress every 10 %
        t0 = time.perf_counter()
        for k in range(0, len(idx), size):
            part = idx[k:k + size]
            if k == size:                # the first chunk timed: the rest here, or not
                per_case = (time.perf_counter() - t0) / size
                if per_case * (len(idx) - size) > HEAD_START_S:
                    break
            try:
                self.write(pack(solve_chunk(template, [(i, self.cases[i]) for i in part]),
                                self.job))
            except Exception:  # noqa: BLE001 - such cases go to the workers, case by case
                break
        self.workers = max(self.workers, 1)

    def _together(self, groups):
        """The template of the largest group when its cases are solved together (None when
        not), decided once per run: the head start solves with it, and such sweeps get fewer,
        larger chunks (a chunk's fixed cost is a few single solves; :mod:`poise.app.chunk_batch`).
        Made from the deck parsed now, not the process's cache of parsed decks (the sweeping
        process itself, whose other work may have filled that cache)."""
        if self._batch_template is not False:
            return self._batch_template
        self._batch_template = None
        if groups:
            group, idx = max(groups.values(), key=lambda g: len(g[1]))
            from poise.app.chunk_batch import plan_for      # lazy: only sweeps that solve
            try:
                template = make_template(self.job, group)
                if plan_for(template, self.cases[idx[0]]) is not None:
                    self._batch_template = template
            except Exception:  # noqa: BLE001 - the workers find out case by case
                pass
        return self._batch_template

    def close(self) -> None:
        left = np.nonzero(~self.done)[0]
        if len(left):                      # gave up: the rest were not run
            self.writer.write({"case": left, "status": np.full(len(left), "not_run", object),
                               "exit_code": np.full(len(left), -1)})
        extra = {"input_files": self.input_files} if self.input_files else {}
        t0 = time.perf_counter()
        self.writer.close(int(self.done.sum()), extra)
        self.timings["write"] += time.perf_counter() - t0


#: a sweep's cases solved together are solved in the sweeping process while they take less
#: than this (seconds, estimated from a first chunk of at most HEAD_CHUNK cases, a tenth of
#: the group for the progress line): about the start and close of a local cluster with its
#: workers' imports on a 2-core machine
HEAD_START_S = 2.0
HEAD_CHUNK = 256


def _threads(client) -> int:
    try:
        return int(sum(client.nthreads().values()))
    except Exception:  # noqa: BLE001 - no scheduler answer: the caller's guess
        return 0


#: message of a case whose worker died while solving it alone
WORKER_DIED = ("the worker process solving this case died (killed by a signal, e.g. out of "
               "memory, or a crash in native code)")


def _run_chunks(client, run: _Run, todo: list[tuple[dict, list]], worker_timeout) -> None:
    """Solve the chunks on the cluster. A chunk whose task failed (its worker died, or the
    task could not run) is split into single cases, solved in parallel; a single case that
    fails again is solved alone, and reported as ``internal_error`` if it fails then."""
    job_f = run.job          # sent with each task (a scatter would fail with no worker yet)
    rounds = [(todo, False), None, None]
    for r in range(3):
        work = rounds[r]
        if not work:
            continue
        work, alone = work
        failed: list[tuple[dict, list, BaseException]] = []

        def done(k, value, exc, work=work, failed=failed):
            if exc is None:
                run.write(value)
            else:
                failed.append((work[k][0], work[k][1], exc))

        if alone:
            for k, (group, idx) in enumerate(work):     # one at a time, nothing else running
                run_tasks(client, {k: (run_chunk, job_f, group,
                                       [(i, run.cases[i]) for i in idx])},
                          done, worker_timeout=worker_timeout, what="cases", say=run.bar.note)
        else:
            run_tasks(client, {k: (run_chunk, job_f, group, [(i, run.cases[i]) for i in idx])
                               for k, (group, idx) in enumerate(work)},
                      done, worker_timeout=worker_timeout, what="chunks of cases",
                      say=run.bar.note)
        singles = [(g, [i]) for g, idx, _ in failed for i in idx]
        if r == 0:
            rounds[1] = (singles, False) if singles else None
        elif r == 1:
            rounds[2] = (singles, True) if singles else None
        else:
            for _g, idx, exc in failed:
                _fail(run, idx, exc)


def _fail(run: _Run, idx: list, exc: BaseException) -> None:
    from distributed.scheduler import KilledWorker
    msg = WORKER_DIED if isinstance(exc, KilledWorker) else \
        f"worker failed: {type(exc).__name__}: {' '.join(str(exc).split())}"
    n = len(idx)
    run.write({"case": np.asarray(idx, np.int64),
               "status": np.full(n, "internal_error", object), "exit_code": np.full(n, 4),
               "wall_time": np.full(n, np.nan), "message": np.full(n, msg, object),
               "converged": np.zeros((n, run.job.layout.n), bool)}, fresh=False)


def frame_layout(spec, params, cases, overrides) -> FrameLayout:
    """The planned frames of the sweep (each frame's time and analysis): those of the first
    group of cases (:func:`poise.app.cases.group_cases`) whose deck plans; none when no deck
    does (every case then reports its own problem)."""
    structural = [p for p in params if p.structural]
    for group, _ in group_cases(params, cases, range(len(cases))).values():
        s, extra = apply_case(spec, structural, group)
        try:
            reqs = plan(s, {**overrides, **extra})
        except (DeckError, UsageError, ValueError):
            continue
        t, times, which = 0.0, [], []
        for k, req in enumerate(reqs):
            ts = [float(x) for x in req.output_times(t)] if req.kind == "quasistatic" else [t]
            times += ts
            which += [k] * len(ts)
            t = ts[-1] if ts else t
        return FrameLayout(tuple(times), tuple(which))
    return FrameLayout()


def _units(spec) -> str:
    from poise.model.compile import unit_info     # lazy: compiling is the workers' business
    return unit_info(spec)[1]


def _ignored_text(ignored) -> str:
    from poise.app.runner import ignored_counts   # lazy: Adams datasets only
    return ignored_counts(ignored or [])


__all__ = ["run_sweep", "SweepOutcome", "Param", "SWEEP_FILE", "INDEX_KEYS", "INDEX_VERSION",
           "output_groups", "parse_outputs", "output_units"]
