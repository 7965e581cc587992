"""Batch runs: solve many decks in parallel, one results file per deck.

Used by ``poise batch``. Decks run on the engine of ``poise sweep`` (:mod:`poise.app.engine`,
Dask: a local cluster of ``jobs`` worker processes by default, an existing cluster with
``scheduler``); a worker solves a deck with :func:`poise.app.runner.run_deck`, writes
``OUT_DIR/<stem>.h5`` itself and returns only a small summary row. A cluster without a worker
for ``worker_timeout`` seconds ends the batch (``NoWorkers``, exit 2) keeping the finished rows.
Without Dask installed (``pip install poise`` without ``[sweep]``) the decks run in a local
``spawn`` process pool instead; ``scheduler`` then needs the extra.

A worker that dies (killed by a signal, e.g. out of memory, or a crash in native code or in a
user routine) takes the decks it was running down with it. On Dask those are solved again one
at a time, alone on the cluster; in the process pool (which a dead worker breaks) the first
unfinished decks are solved again each in a process of its own, the others in a fresh pool.
Either way only the deck that kills its process is reported (``internal_error``,
:data:`WORKER_DIED`) and the batch, its other decks and the summary files are unaffected.

Up-to-date check (re-runs skip work): a results file is reused when its root attributes record
the same ``deck_sha256`` (hash of the deck bytes now), the same ``poise_version`` and the same
``run_overrides`` (JSON of the solver options given to ``poise batch`` and, for an Adams
dataset, the ``--ignore`` kinds), it has a ``status``,
and every other file the run read (``input_files``: the Python user scripts, path -> SHA-256)
still has the recorded hash; a file whose run read scripts is stale without
``allow_user_code`` (the deck would now be refused).

User code: decks naming Python user routines are solved only with ``allow_user_code=True``
(``--allow-user-code``), otherwise they are ``invalid_deck`` rows. Whatever a deck's code does
(raise, ``SystemExit``), it is that deck's row; the other decks and the summary carry on.

Summary rows (``BATCH_KEYS``, stable; ``batch_version`` 1):

``deck`` path as given, ``output`` results file (``null`` when none was written), ``status``
(``converged``, ``failed``, ``invalid_deck``, ``internal_error``), ``exit_code`` (0, 1, 3, 4),
``iterations`` (total over analyses), ``time`` (parse + compile + solve wall time, seconds, of
the run that produced the file), ``imbalance`` (the largest over every analysis and frame, at
``imbalance_analysis`` / ``imbalance_frame``), ``stability_class`` (the worst over every analysis
and frame: ``stable < neutral < unknown < unstable``, at ``stability_analysis`` /
``stability_frame``, with that frame's ``n_negative``, ``n_zero``, ``stability_modes`` text and
``modes``: the numeric modes, a JSON list in the CSV), ``skipped`` (true when the file was up to
date), ``message`` (failed analyses' messages, the located deck problems joined by ``"; "``, or
``skipped (up to date)``), ``ignored`` (what ``--ignore`` left out of an Adams dataset:
``1 CONTACT, 2 USER``; empty when nothing). One definition with ``poise solve`` / ``poise show``:
:mod:`poise.results.summary`.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path

from poise.app.engine import WORKER_TIMEOUT, NoWorkers, dask_client, run_tasks
from poise.core.progress import Bar, ending
from poise.app.run_warnings import collected_warnings
from poise.app.runner import check_ignore, ignore_kinds, ignored_counts, run_deck
from poise.core.atomic import atomic_output, output_target, OutputError
from poise.core.dirlock import directory_lock
from poise.core.errors import DeckError, UsageError
from poise.core.extras import available, require
from poise.core.version import __version__
from poise.results.hdf5 import read_results, write_results
from poise.results.summary import summarize_run
from poise.solvers.settings import check_override_names
from typing import Any

BATCH_VERSION = 1
BATCH_KEYS = ("deck", "output", "status", "exit_code", "iterations", "time", "imbalance",
              "imbalance_analysis", "imbalance_frame", "stability_class", "stability_analysis",
              "stability_frame", "n_negative", "n_zero", "stability_modes", "modes",
              "skipped", "message", "ignored")

#: severity order of exit codes (worst last)
_RANK = {0: 0, 1: 1, 3: 2, 2: 3, 4: 4}     # 2: a results file could not be written


def worst_exit_code(codes) -> int:
    codes = list(codes)
    return max(codes, key=lambda c: _RANK.get(c, 4)) if codes else 0


def overrides_json(overrides: dict | None, ignore=()) -> str:
    """The ``run_overrides`` record: the solver options and the ``--ignore`` kinds that
    apply (:func:`poise.app.runner.ignore_kinds`; absent when none)."""
    d = {k: v for k, v in (overrides or {}).items() if v is not None}
    if ignore:
        d["ignore"] = list(ignore)
    return json.dumps(d, sort_keys=True, default=str)


def check_ignore_decks(decks, ignore) -> None:
    """``--ignore`` kinds for a batch: known kinds (:func:`poise.app.runner.check_ignore`),
    and at least one deck an Adams dataset (they apply to those only); else a UsageError."""
    if not ignore:
        return
    adams = [d for d in decks if ignore_kinds(d, ignore)]
    if not adams:
        raise UsageError("--ignore applies to Adams datasets (.adm, .acf); none of the decks "
                         "is one")
    check_ignore(adams[0], ignore)


def file_sha256(path: str) -> str:
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def result_stats(res) -> dict:
    """The row fields of a :class:`~poise.results.data.RunResult` (fresh or read back from a
    file): ``status``, ``exit_code``, ``time`` and the run summary
    (:func:`poise.results.summary.summarize_run`: iterations summed, the worst imbalance and
    stability over the analyses and frames, the failed analyses' messages)."""
    t = sum(float(res.timings.get(k, 0.0)) for k in ("parse", "compile", "solve"))
    return dict(summarize_run(res).row(), exit_code=res.exit_code, time=t,
                ignored=_ignored(res.attrs.get("ignored")))


def _ignored(text) -> str:
    """``1 CONTACT, 2 USER`` from a results file's ``ignored`` root attribute (JSON)."""
    if not text:
        return ""
    try:
        return ignored_counts(json.loads(text.decode() if isinstance(text, bytes) else text))
    except (ValueError, TypeError, KeyError):
        return "unreadable record"


def output_paths(decks: list[str], out_dir: str) -> list[str]:
    """``out_dir/<stem>.h5``; later decks with an already used stem get ``<stem>-2.h5``, …"""
    used: set[str] = set()
    out = []
    for d in decks:
        stem = Path(d).stem
        name, k = stem, 1
        while name.lower() in used:
            k += 1
            name = f"{stem}-{k}"
        used.add(name.lower())
        out.append(os.path.join(out_dir, name + ".h5"))
    return out


def check_outputs(outputs: list[str], inputs: list[str]) -> None:
    """Refuse a run one of whose outputs is one of its inputs (a deck given as ``p.h5`` next
    to ``p.xml``, whose results would replace it): :class:`UsageError` (exit 2) before any work,
    as ``poise solve -o`` refuses the deck."""
    for o in outputs:
        output_target(o, inputs)


def inputs_fresh(attrs, allow_user_code: bool = False) -> bool:
    """Whether the files besides the deck that a run read (root attribute ``input_files``, JSON
    ``{path: sha256}``) still hold the same bytes, and may still be run (``allow_user_code``)."""
    text = attrs.get("input_files")
    if text is None:
        return True
    text = text.decode() if isinstance(text, bytes) else str(text)
    try:
        files = json.loads(text)
    except ValueError:
        return False
    if not isinstance(files, dict):
        return False
    # scripts need allow_user_code; an Adams command file's dataset is data, not code
    if not allow_user_code and any(not str(p).lower().endswith(".adm") for p in files):
        return False
    for path, digest in files.items():
        try:
            if file_sha256(path) != digest:
                return False
        except OSError:
            return False
    return True


def up_to_date(deck: str, output: str, overrides: dict | None,
               allow_user_code: bool = False, ignore=()) -> bool:
    """Whether ``output`` holds the results of ``deck`` with these overrides, ``--ignore``
    kinds and the same scripts (see module doc)."""
    if not os.path.isfile(output):
        return False
    try:
        import h5py

        with h5py.File(output, "r") as f:
            a = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
        return (a.get("format") == "poise-results" and "status" in a
                and a.get("poise_version") == __version__
                and a.get("deck_sha256") == file_sha256(deck)
                and a.get("run_overrides") == overrides_json(overrides,
                                                             ignore_kinds(deck, ignore))
                and inputs_fresh(a, allow_user_code))
    except (OSError, ValueError, KeyError):
        return False


def _row(deck, output, **kw) -> dict:
    row = dict.fromkeys(BATCH_KEYS)
    row.update(deck=deck, output=output, skipped=False, message="", ignored="")
    row.update(kw)
    return row


def skipped_row(deck: str, output: str) -> dict:
    st = result_stats(read_results(output))
    st["message"] = "skipped (up to date)"
    return _row(deck, output, skipped=True, **st)


def _error_row(deck: str, message: str) -> dict:
    """The row of a deck that produced no results file because of an internal error."""
    return _row(deck, None, status="internal_error", exit_code=4, message=message)


def solve_one(deck: str, output: str, overrides: dict | None, command: str,
              allow_user_code: bool = False, ignore=()) -> dict:
    """Solve one deck and write its results file (runs in a worker process). ``ignore``: the
    ``--ignore`` kinds, applied to an Adams dataset only."""
    kinds = ignore_kinds(deck, ignore)
    try:
        with collected_warnings() as numeric:          # numpy warnings: run warnings
            res = run_deck(deck, overrides, command=command, allow_user_code=allow_user_code,
                           **({"ignore": kinds} if kinds else {}))
        res.warnings = list(res.warnings) + numeric
    except DeckError as e:
        problems = [str(p) for p in e.problems] or [str(e)]
        return _row(deck, None, status="invalid_deck", exit_code=3,
                    message="; ".join(problems), problems=problems)
    except (Exception, SystemExit) as e:  # noqa: BLE001 - a row, never kills the batch
        return _error_row(deck, f"{type(e).__name__}: {' '.join(str(e).split())}")
    try:
        res.attrs["run_overrides"] = overrides_json(overrides, kinds)
        write_results(res, output)
    except OutputError as e:         # disk full, no permission: an I/O error, not a bug
        return _row(deck, None, status="io_error", exit_code=2, message=" ".join(str(e).split()))
    except Exception as e:  # noqa: BLE001
        return _error_row(deck, f"writing {output}: {type(e).__name__}: {e}")
    return _row(deck, output, **result_stats(res))


def run_batch(decks: list[str], out_dir: str, jobs: int = 0, overrides: dict | None = None,
              force: bool = False, command: str = "poise batch",
              on_row=None, allow_user_code: bool = False,
              progress: bool | None = None, scheduler: str | None = None,
              worker_timeout: float | None = WORKER_TIMEOUT, ignore=()) -> list[dict]:
    """Solve ``decks`` (in parallel), return one row per deck in the order given.

    ``jobs`` ≤ 0 means ``os.cpu_count()``. ``on_row(row)`` is called as each deck finishes.
    ``allow_user_code``: run the Python user routines decks name (else ``invalid_deck``).
    ``progress``: the decks-done bar (:class:`poise.core.progress.Bar`; False: none, None: auto;
    False also silences Dask). ``scheduler``: an existing Dask scheduler's address (default: a
    local cluster of ``jobs`` workers; without Dask installed: a local process pool).
    ``worker_timeout``: seconds the cluster may have no worker before the batch gives up
    (:class:`poise.app.engine.NoWorkers`, exit 2, its ``rows`` the finished decks).
    ``ignore``: kinds of Adams statements left out instead of refused (``--ignore``), applied
    to the Adams datasets among ``decks`` (a UsageError when none is one).
    """
    check_override_names(overrides)
    check_ignore_decks(decks, ignore)
    bar = Bar(len(decks), "batch", "decks", enabled=progress, delay=0.0)
    user_on_row = on_row

    def on_row(row):
        if user_on_row:
            bar.clear()
            user_on_row(row)
        bar.step()
    rows: list[Any] = [None] * len(decks)
    try:
        out = _run_batch(decks, out_dir, jobs, overrides, force, command, on_row,
                         allow_user_code, rows, scheduler, progress is False, worker_timeout,
                         say=bar.note, ignore=tuple(ignore or ()))
    except BaseException as e:
        bar.close(ending(e))            # the last progress line says "gave up", "interrupted"
        if isinstance(e, NoWorkers):
            e.rows = [r for r in rows if r is not None]
        raise
    bar.close()
    return out


def _run_batch(decks, out_dir, jobs, overrides, force, command, on_row, allow_user_code, rows,
               scheduler=None, quiet=False, worker_timeout=WORKER_TIMEOUT, say=None, ignore=()):
    if scheduler:
        require("sweep", "poise batch --scheduler")
    import functools
    job = functools.partial(solve_one, allow_user_code=bool(allow_user_code),   # picklable
                            ignore=ignore)
    check_outputs([*output_paths(decks, out_dir), os.path.join(out_dir, "summary.csv"),
                   os.path.join(out_dir, "summary.json")], decks)
    ensure_out_dir(out_dir)
    with directory_lock(out_dir, "batch", say=say):      # a second batch waits, then skips
        return _solve_all(decks, out_dir, jobs, overrides, force, command, on_row,
                          allow_user_code, rows, scheduler, quiet, worker_timeout, say, job,
                          ignore)


def _solve_all(decks, out_dir, jobs, overrides, force, command, on_row, allow_user_code, rows,
               scheduler, quiet, worker_timeout, say, job, ignore=()):
    outs = output_paths(decks, out_dir)
    todo = []
    for k, (d, o) in enumerate(zip(decks, outs)):
        if not force and up_to_date(d, o, overrides, allow_user_code, ignore):
            try:
                rows[k] = skipped_row(d, o)
                if on_row:
                    on_row(rows[k])
                continue
            except Exception:  # noqa: BLE001 - unreadable: solve again
                pass
        todo.append(k)
    jobs = jobs if jobs and jobs > 0 else (os.cpu_count() or 1)
    if not todo:
        return rows
    if scheduler or available("sweep"):
        _solve_on_dask(todo, jobs, decks, outs, overrides, command, rows, on_row, job,
                       scheduler, quiet, worker_timeout, say)
        return rows
    # lean install (no Dask): a local process pool,
    # always in worker processes (also with -j 1): a deck that kills its process (out of memory,
    # a crash in native code or in a user routine) must not take the batch and its summary down
    pending = todo
    while pending:
        broken = _solve_in_pool(pending, jobs, decks, outs, overrides, command, rows, on_row,
                                job)
        # The pool hands decks to its workers in order (at most jobs + 1 at a time), so the
        # deck that killed a worker is among the first unfinished ones: those are re-solved
        # one process each, the rest in a fresh pool (every round finishes at least one deck).
        suspects = broken[:2 * (jobs + 1)]
        if suspects:
            _solve_isolated(suspects, jobs, decks, outs, overrides, command, rows, on_row, job)
        pending = broken[len(suspects):]
    return rows


#: Message of a deck whose own worker process died (see :func:`_solve_isolated`).
WORKER_DIED = ("the worker process solving this deck died (killed by a signal, e.g. out of "
               "memory, or a crash in native code); no results file")


def _solve_on_dask(todo, jobs, decks, outs, overrides, command, rows, on_row, job, scheduler,
                   quiet, worker_timeout, say=None) -> None:
    """Solve ``todo`` on Dask (:mod:`poise.app.engine`). A task whose worker died
    (``KilledWorker``: on the local cluster at the first death) is a suspect; each suspect is
    then solved again alone on the cluster, so only the deck that kills its worker is
    reported (:data:`WORKER_DIED`)."""
    from distributed.scheduler import KilledWorker
    suspects: list[int] = []

    def done(k, row, exc, alone=False):
        if isinstance(exc, KilledWorker):
            if not alone:
                suspects.append(k)
                return
            row = _error_row(decks[k], WORKER_DIED)
        elif exc is not None:
            row = _error_row(decks[k], f"worker failed: {type(exc).__name__}: {exc}")
        rows[k] = row
        if on_row:
            on_row(row)

    with dask_client(scheduler, jobs, len(todo), quiet=quiet, feature="poise batch",
                     allowed_failures=0, worker_timeout=worker_timeout) as client:
        run_tasks(client, {k: (job, decks[k], outs[k], overrides, command) for k in todo},
                  done, worker_timeout=worker_timeout, what="decks", say=say)
        for k in sorted(suspects):      # one at a time, nothing else on the cluster
            run_tasks(client, {k: (job, decks[k], outs[k], overrides, command)},
                      lambda k, row, exc: done(k, row, exc, alone=True),
                      worker_timeout=worker_timeout, what="decks", say=say)


def _spawn_pool(workers: int):
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor
    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"))


def _solve_in_pool(keys, jobs, decks, outs, overrides, command, rows, on_row,
                   job=solve_one) -> list[int]:
    """Solve ``keys`` on one pool of ``jobs`` workers; returns the decks the pool could not
    finish because a worker process died (the pool then fails every unfinished deck)."""
    from concurrent.futures import as_completed
    from concurrent.futures.process import BrokenProcessPool
    broken = []
    with _spawn_pool(min(jobs, len(keys))) as ex:
        futs = {ex.submit(job, decks[k], outs[k], overrides, command): k for k in keys}
        for fut in as_completed(futs):
            k = futs[fut]
            try:
                rows[k] = fut.result()
            except BrokenProcessPool:
                broken.append(k)
                continue
            except (Exception, SystemExit) as e:  # noqa: BLE001 - e.g. row not sent back
                rows[k] = _error_row(decks[k], f"worker failed: {type(e).__name__}: {e}")
            if on_row:
                on_row(rows[k])
    return sorted(broken)


def _solve_isolated(keys, jobs, decks, outs, overrides, command, rows, on_row,
                    job=solve_one) -> None:
    """Re-solve the decks a dead worker took down, each in a process of its own (``jobs`` at a
    time), so that only the deck that kills its process is reported (:data:`WORKER_DIED`) and
    every other deck gets its results."""
    from concurrent.futures import ThreadPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    def one(k):
        try:
            with _spawn_pool(1) as ex:
                return k, ex.submit(job, decks[k], outs[k], overrides, command).result()
        except BrokenProcessPool:
            return k, _error_row(decks[k], WORKER_DIED)
        except (Exception, SystemExit) as e:  # noqa: BLE001
            return k, _error_row(decks[k], f"worker failed: {type(e).__name__}: {e}")

    with ThreadPoolExecutor(max_workers=max(1, min(jobs, len(keys)))) as tp:
        for k, row in tp.map(one, keys):
            rows[k] = row
            if on_row:
                on_row(row)


def ensure_out_dir(out_dir: str) -> None:
    """Create ``out_dir`` (and parents); an output directory that cannot be created or written
    is an I/O error naming it (:class:`poise.core.atomic.OutputError`, exit 2), before any work."""
    try:
        os.makedirs(out_dir, exist_ok=True)
    except OSError as e:
        raise OutputError(f"--out-dir {out_dir!r}: cannot create the directory: "
                          f"{e.strerror or e}") from None
    if not os.access(out_dir, os.W_OK | os.X_OK):
        raise OutputError(f"--out-dir {out_dir!r}: the directory is not writable")


def write_table(rows: list[dict], path_stem: str, keys=None, extra: dict | None = None,
                units: dict | None = None) -> None:
    """``<path_stem>.csv`` and ``<path_stem>.json`` (``{"rows": [...], **extra}``), atomically
    (:func:`poise.core.atomic.atomic_output`: a failed write is an ``OutputError``, exit 2).
    ``units`` (``{column: unit}``): the CSV header says ``column [unit]``, the JSON has them
    as ``"units"`` (its rows keep the bare column names)."""
    import csv

    keys = list(keys) if keys else list(dict.fromkeys(k for r in rows for k in r))
    units = {k: u for k, u in (units or {}).items() if k in keys and u}
    with atomic_output(f"{path_stem}.csv") as tmp, open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow([f"{k} [{units[k]}]" if k in units else k for k in keys])
        for r in rows:
            w.writerow([_cell(r.get(k)) for k in keys])
    head = {**(extra or {}), **({"units": units} if units else {})}
    with atomic_output(f"{path_stem}.json") as tmp, open(tmp, "w") as f:
        json.dump({**head, "rows": [sanitize(r) for r in rows]}, f, indent=1, sort_keys=False)
        f.write("\n")


def _cell(v):
    """A CSV cell: empty for None, JSON for lists and dicts (e.g. the numeric ``modes``)."""
    if v is None:
        return ""
    if isinstance(v, (list, tuple, dict)):
        return json.dumps(sanitize(v), separators=(",", ":"))
    return v


def sanitize(obj):
    """Non-finite floats -> None, numpy scalars -> Python (JSON-safe)."""
    if isinstance(obj, dict):
        return {k: sanitize(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [sanitize(v) for v in obj]
    if hasattr(obj, "item") and not isinstance(obj, (str, bytes)):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
