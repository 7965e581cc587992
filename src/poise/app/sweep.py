"""Parameter sweeps on Dask distributed (``poise sweep`` and ``poise.app.sweep(...)``).

A sweep substitutes attribute values into the parsed deck (:class:`~poise.deck.spec.DeckSpec`),
one *case* per combination, and runs the cases as Dask tasks: on a ``LocalCluster`` (worker
processes, one thread each, no dashboard) by default, or on an existing cluster given by its
scheduler address. Each case writes ``OUT_DIR/case_NNNNN.h5`` (from the worker: with a remote
cluster OUT_DIR must be on a filesystem the workers share); the index ``OUT_DIR/index.csv`` and
``OUT_DIR/index.json`` hold one row per case. An Adams dataset is swept like an XML deck
(``--set`` names the XML elements it translates to); ``ignore`` (``--ignore KIND``) leaves out
its refused statements in every case, recorded in each case file and the index.

Parameters and modes: :mod:`poise.app.cases`.

Resuming: a case whose file exists, has a ``status`` root attribute and records the same
``sweep_case_hash`` (SHA-256 of deck hash, case values, overrides, ``--ignore`` kinds and poise
version) is not
run again, unless a user script it read changed (root attribute ``input_files``); its row is
read back from the file (``resumed = true``). Decks naming Python user routines need
``allow_user_code`` (``--allow-user-code``), passed on to the workers.

Index row keys (``INDEX_KEYS``, then one column per parameter, then the ``--output`` columns):
``case``, ``file``, ``status`` (``converged``/``failed``/``invalid_deck``/``internal_error``),
``exit_code``, ``iterations`` (all analyses), ``wall_time`` (parse + compile + solve, s),
``imbalance`` (the worst frame of every analysis) and the other run-summary fields of
:func:`poise.app.batch.result_stats` (``imbalance_analysis``, ``imbalance_frame``,
``stability_class`` — the worst over the analyses and frames — ``stability_analysis``,
``stability_frame``, ``n_negative``, ``n_zero``, ``stability_modes``, ``modes``), ``resumed``,
``message``, ``ignored`` (what ``--ignore`` left out: ``1 CONTACT``). Outputs
``group[id].dataset`` (``bodies[2].position``, ``joints[1].force``, ``requests[1].values``, …)
give the last frame of the last analysis, flattened: ``bodies[2].position[0]`` … ``[2]``.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
from typing import Any

from poise.app.cases import (MAX_CASES, Param, apply_case, case_hash, check_case_count,
                             make_cases, parse_set, resolve_param)
from poise.app.engine import WORKER_TIMEOUT, NoWorkers, dask_client, run_tasks
from poise.core.progress import Bar, ending, note
from poise.app.batch import check_outputs, ensure_out_dir, inputs_fresh, result_stats, sanitize, write_table
from poise.app.run_warnings import collected_warnings
from poise.app.runner import check_ignore, ignore_kinds, run_spec
from poise.core.atomic import OutputError
from poise.core.dirlock import directory_lock
from poise.core.errors import DeckError, UsageError
from poise.core.extras import require
from poise.deck.parser import parse_deck_bytes
from poise.elements.registry import output_groups as registry_output_groups
from poise.results.hdf5 import read_results, write_results
from poise.results.schema import REQUEST_CHANNELS, element_outputs, lookup, unit_string
from poise.solvers.settings import check_override_names

INDEX_VERSION = 1
INDEX_KEYS = ("case", "file", "status", "exit_code", "iterations", "wall_time", "imbalance",
              "imbalance_analysis", "imbalance_frame", "stability_class", "stability_analysis",
              "stability_frame", "n_negative", "n_zero", "stability_modes", "modes",
              "resumed", "message", "ignored")

_OUT = re.compile(r"^\s*([a-z_]+)\s*\[\s*(-?\d+)\s*\]\s*\.\s*([A-Za-z_][A-Za-z0-9_]*)\s*$")

def output_groups() -> dict:
    """Output group -> deck tags whose ids it holds (for checking ``--output`` ids; None: any
    tag): the bodies and every group an element type declares
    (:func:`poise.elements.registry.output_groups`) whose per-element datasets the results
    schema declares."""
    declared = element_outputs()
    groups = {"bodies": ("Body_Rigid", "Body_Point"), **registry_output_groups()}
    return {g: tags for g, tags in groups.items() if g in declared}


def parse_outputs(spec, outputs) -> list[tuple[str, str, int, str]]:
    """``bodies[2].position`` -> (text, group, id, dataset); ids checked against the deck."""
    out = []
    for text in outputs or ():
        m = _OUT.match(text)
        groups = output_groups()
        if not m or m.group(1) not in groups:
            raise UsageError(f"--output {text!r}: expected group[id].dataset with group one of "
                             f"{', '.join(groups)}, e.g. bodies[2].position")
        g, i, ds = m.group(1), int(m.group(2)), m.group(3)
        known = element_outputs()[g]
        if ds not in known:
            import difflib
            near = difflib.get_close_matches(ds, known, n=1)
            raise UsageError(f"--output {text!r}: {g} has no dataset {ds!r}"
                             + (f"; did you mean {g}[{i}].{near[0]}?" if near else "")
                             + f" ({g} datasets: {', '.join(known)})")
        tags = groups[g]
        if tags and not any(e.tag in tags and e.id == i for e in spec.model):
            raise UsageError(f"--output {text!r}: the deck has no {'/'.join(tags)} id={i}")
        out.append((f"{g}[{i}].{ds}", g, i, ds))
    return out


def output_units(spec, outputs) -> dict:
    """``{column: unit}`` of the ``--output`` columns in the deck's units (``"mm"``, ``"N"``):
    one per output from the results schema, one per channel for ``requests[i].values``; and
    ``wall_time`` in seconds. Columns of a dataset without one unit are left out."""
    from poise.model.compile import unit_info     # lazy: compiling is the workers' business
    units = unit_info(spec)[1]
    out = {"wall_time": "s"}
    for text, g, i, ds in outputs:
        if (g, ds) == ("requests", "values"):
            el = next((e for e in spec.model if e.tag == "Post_Request" and e.id == i), None)
            t = str(el.attrs.get("type", "EXPRESSION") if el is not None else "").upper()
            chans = REQUEST_CHANNELS.get(t, REQUEST_CHANNELS["EXPRESSION"])[1]
            out.update({f"{text}[{k}]": unit_string(u, units) for k, u in enumerate(chans) if u})
            continue
        it = lookup("analysis", "dataset", f"{g}/{ds}")
        if it is None or not it.unit or it.unit == "mixed":
            continue
        u = unit_string(it.unit, units)
        n = 1
        for d in it.shape[2:]:
            n *= d if isinstance(d, int) else 0
        out.update({text: u} if n == 1 else {f"{text}[{k}]": u for k in range(n)})
    return out


def output_columns(res, outputs, analysis: int = -1) -> dict:
    """Flattened last-frame values of the chosen outputs (NaN when absent)."""
    import numpy as np
    cols: dict[str, Any] = {}
    a = res.analyses[analysis] if res is not None and res.analyses else None
    for text, g, i, ds in outputs:
        arr = None
        if a is not None:
            ids = a.datasets.get(f"{g}/id")
            if ids is None:
                ids = res.model_datasets.get(f"{g}/id")
            data = a.datasets.get(f"{g}/{ds}")
            if ids is not None and data is not None and np.ndim(data) >= 2 and len(data):
                hit = np.nonzero(np.asarray(ids) == i)[0]
                if len(hit):
                    arr = np.asarray(data[-1][hit[0]], dtype=float).ravel()
        if arr is None:
            cols[text] = None
        elif arr.size == 1:
            cols[text] = float(arr[0])
        else:
            for k, x in enumerate(arr.tolist()):
                cols[f"{text}[{k}]"] = x
    return cols


# ---------------------------------------------------------------------------- worker side
_SPEC_CACHE: dict[str, Any] = {}


def _spec_from_bytes(data: bytes, path: str, ignore=()):
    key = hashlib.sha256(data).hexdigest() + "\0" + path + "\0" + ",".join(ignore)
    spec = _SPEC_CACHE.get(key)
    if spec is None:
        spec = parse_deck_bytes(data, path, **({"ignore": ignore} if ignore else {}))
        if len(_SPEC_CACHE) > 8:
            _SPEC_CACHE.clear()
        _SPEC_CACHE[key] = spec
    return spec


def run_case(data: bytes, path: str, params: list[Param], index: int, values: dict,
             overrides: dict | None, out_file: str, chash: str, outputs,
             allow_user_code: bool = False, ignore=()) -> dict:
    """Solve one case and write its results file; return its index row (a Dask task).
    ``allow_user_code``: run the deck's Python user routines (in the worker); ``ignore``: the
    ``--ignore`` kinds of an Adams dataset."""
    row = {"case": index, "file": None, **values}
    try:
        base = _spec_from_bytes(data, path, ignore)
        spec, extra = apply_case(base, params, values)
        spec.warnings = list(base.warnings)     # run_spec validates the case (once)
        with collected_warnings() as numeric:          # numpy warnings: run warnings
            res = run_spec(spec, {**(overrides or {}), **extra},
                           command=f"poise sweep case {index}: {json.dumps(values, default=str)}",
                           allow_user_code=allow_user_code)
        res.warnings = list(res.warnings) + numeric
    except DeckError as e:
        problems = [str(p) for p in e.problems] or [str(e)]
        row.update(status="invalid_deck", exit_code=3, message="; ".join(problems))
        row.update(output_columns(None, outputs))
        return row
    except Exception as e:  # noqa: BLE001 - one bad case never stops the sweep
        row.update(status="internal_error", exit_code=4,
                   message=f"{type(e).__name__}: {' '.join(str(e).split())}")
        row.update(output_columns(None, outputs))
        return row
    res.attrs.update(sweep_case=int(index), sweep_case_hash=chash,
                     sweep_values=json.dumps(values, sort_keys=True, default=str),
                     run_overrides=json.dumps({**(overrides or {}),
                                               **({"ignore": list(ignore)} if ignore else {})},
                                              sort_keys=True, default=str))
    try:
        write_results(res, out_file)
    except OutputError as e:         # disk full: an I/O error row, the sweep goes on
        row.update(status="io_error", exit_code=2, message=" ".join(str(e).split()))
        row.update(output_columns(None, outputs))
        return row
    st = result_stats(res)
    row.update(file=out_file, wall_time=st.pop("time"), **st)
    row.update(output_columns(res, outputs))
    return row


def resumable(out_file: str, chash: str, allow_user_code: bool = False) -> bool:
    """The case file exists, is complete (``status`` root attribute), has this case hash and
    the scripts it read are unchanged (and still allowed to run)."""
    if not os.path.isfile(out_file):
        return False
    try:
        import h5py

        with h5py.File(out_file, "r") as f:
            a = f.attrs
            h = a.get("sweep_case_hash")
            h = h.decode() if isinstance(h, bytes) else h
            return "status" in a and h == chash and inputs_fresh(a, allow_user_code)
    except (OSError, ValueError):
        return False


def resumed_row(out_file: str, index: int, values: dict, outputs) -> dict:
    res = read_results(out_file)
    st = result_stats(res)
    row = {"case": index, "file": out_file, **values}
    row.update(wall_time=st.pop("time"), **st)
    row.update(output_columns(res, outputs))
    return row


# ---------------------------------------------------------------------------- driver
def run_sweep(deck, sets, mode: str = "grid", out_dir: str = "sweep", scheduler=None,
              outputs=(), n=None, seed=0, workers=None, overrides=None, force=False,
              progress: bool | None = None, on_row=None, client=None,
              allow_user_code: bool = False, max_cases: int | None = MAX_CASES,
              worker_timeout: float | None = WORKER_TIMEOUT, ignore=()) -> list[dict]:
    """Run a sweep; return the index rows (sorted by case) and write ``index.csv``/``.json``.

    Parameters
    ----------
    deck : str
        Deck path.
    sets : dict or list
        ``{"Tag[id].attr": values}`` (values: list, ``"a:b:step"`` or ``"v1,v2"``), or a list
        of ``"Tag[id].attr=values"`` strings.
    mode : ``"grid"``, ``"zip"`` or ``"random"`` (with ``n`` cases and ``seed``).
    out_dir : str
        Case files ``case_NNNNN.h5`` and the index.
    scheduler : str, optional
        Address of an existing Dask scheduler (``tcp://host:port``); default: a LocalCluster
        with ``workers`` processes (default: CPU count), one thread each, no dashboard.
    outputs : list of str
        ``group[id].dataset`` columns for the index (last frame of the last analysis).
    overrides : dict, optional
        Solver overrides for every case (like ``poise solve`` options).
    force : bool
        Rerun cases whose file is complete and up to date.
    client : dask.distributed.Client, optional
        Use this client (library use); ``scheduler`` and ``workers`` are then ignored.
    allow_user_code : bool
        Run the Python user routines the deck names, in the workers (default False: such a
        deck gives ``invalid_deck`` rows saying how to allow them).
    max_cases : int or None
        Refuse sweeps with more cases (counted before any is made); None: no cap.
    progress : bool or None
        The cases-done bar (poise.core.progress; None: automatic). False also silences Dask.
    worker_timeout : float or None
        Seconds the cluster may have no worker before the sweep gives up
        (:class:`poise.app.engine.NoWorkers`, exit 2; the index keeps the finished cases).
    ignore : iterable of str
        Adams datasets: kinds of statements left out instead of refused (``--ignore``), in
        every case; recorded in the case files, the rows and the index.

    Raises
    ------
    poise.core.errors.UsageError
        Bad ``sets``/``outputs``/mode (exit 2 in the CLI).
    poise.core.errors.DeckError
        The base deck is invalid (exit 3).
    """
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
    outs = parse_outputs(spec, outputs)
    col_units = output_units(spec, outs)
    check_case_count(params, mode, n=n, max_cases=max_cases)
    if scheduler and client is None:
        check_scheduler(scheduler)
    cases = make_cases(params, mode, n=n, seed=seed)
    check_override_names(overrides)
    overrides = {k: v for k, v in (overrides or {}).items() if v is not None}
    width = max(5, len(str(len(cases) - 1)))
    files = [os.path.join(os.path.abspath(out_dir), f"case_{i:0{width}d}.h5")
             for i in range(len(cases))]
    check_outputs(files + [os.path.join(out_dir, f"index.{x}") for x in ("csv", "json")], [deck])
    ensure_out_dir(out_dir)
    with directory_lock(out_dir, "sweep", say=lambda line: note(line, progress)):
        bar = Bar(len(cases), "sweep", "cases", enabled=progress, delay=0.0)
        hashes = [case_hash(spec.sha256, c, {**overrides, **({"ignore": list(kinds)} if kinds
                                                              else {})}) for c in cases]
        rows: list[Any] = [None] * len(cases)
        todo = []
        for i, c in enumerate(cases):
            if not force and resumable(files[i], hashes[i], allow_user_code):
                try:
                    rows[i] = {**resumed_row(files[i], i, c, outs), "resumed": True}
                    if on_row:
                        bar.clear()
                        on_row(rows[i])
                    bar.step()
                    continue
                except Exception:  # noqa: BLE001 - unreadable: run again
                    pass
            todo.append(i)

        def finish():
            done = [r for r in rows if r is not None]
            for r in done:
                r.setdefault("resumed", False)
                if r.get("file"):
                    r["file"] = os.path.relpath(r["file"], os.path.abspath(out_dir))
            keys = ["case", *[p.key for p in params], *INDEX_KEYS[1:]]
            keys += [k for r in done for k in r if k not in keys]
            keys = list(dict.fromkeys(keys))
            ordered = [{k: r.get(k) for k in keys} for r in done]
            write_table(ordered, os.path.join(out_dir, "index"), keys=keys, units=col_units,
                        extra={"index_version": INDEX_VERSION, "deck": deck,
                               "deck_sha256": spec.sha256, "mode": mode,
                               "parameters": {p.key: p.values for p in params},
                               "overrides": overrides, "n_cases": len(cases),
                               **({"ignore": list(kinds), "ignored": spec.ignored} if kinds
                                  else {})})
            return [sanitize(r) for r in ordered]

        try:
            if todo:
                _run_dask(todo, rows, data, deck, params, cases, overrides, files, hashes, outs,
                          scheduler, workers, client, bar, on_row, allow_user_code,
                          quiet=progress is False, worker_timeout=worker_timeout,
                          ignore=kinds)
        except BaseException as e:
            bar.close(ending(e))            # the last progress line says "gave up", "interrupted"
            if isinstance(e, NoWorkers):    # the index keeps the finished cases
                e.rows = finish()
            raise
        bar.close()
        return finish()


def check_scheduler(address: str) -> None:
    """A Dask scheduler address (``tcp://host:8786``, ``host:8786``) or a ``UsageError``."""
    where = f"--scheduler {address!r}"
    text = str(address).strip()
    try:
        from distributed.comm.addressing import parse_address, parse_host_port
        scheme, loc = parse_address(text if "://" in text else f"tcp://{text}", strict=False)
        if scheme in ("tcp", "tls"):
            host, port = parse_host_port(loc, default_port=8786)
            if not host or not 0 < int(port) < 65536:
                raise ValueError("no host or bad port")
    except Exception as e:  # noqa: BLE001 - whatever the parser says, the address is unusable
        raise UsageError(f"{where}: not a scheduler address (expected e.g. "
                         f"tcp://host:8786): {' '.join(str(e).split())}") from None


def _run_dask(todo, rows, data, deck, params, cases, overrides, files, hashes, outs,
              scheduler, workers, client, bar, on_row, allow_user_code=False, quiet=False,
              worker_timeout=WORKER_TIMEOUT, ignore=()):
    tasks = {i: (run_case, data, deck, params, i, cases[i], overrides, files[i], hashes[i], outs,
                 bool(allow_user_code), tuple(ignore)) for i in todo}

    def done(i, row, exc):
        if exc is not None:          # lost worker, serialisation ...
            row = {"case": i, "file": None, **cases[i], "status": "internal_error",
                   "exit_code": 4, "message": f"{type(exc).__name__}: {exc}"}
        rows[i] = row
        rows[i]["resumed"] = False
        if on_row:
            bar.clear()
            on_row(rows[i])
        bar.step()

    with dask_client(scheduler, workers, len(todo), client, quiet=quiet,
                     worker_timeout=worker_timeout) as cl:
        run_tasks(cl, tasks, done, worker_timeout=worker_timeout, what="cases", say=bar.note)
