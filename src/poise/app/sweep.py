"""Parameter sweeps on Dask distributed (``poise sweep`` and ``poise.app.sweep(...)``).

A sweep substitutes attribute values into the parsed deck (:class:`~poise.deck.spec.DeckSpec`),
one *case* per combination, and runs the cases as Dask tasks: on a ``LocalCluster`` (worker
processes, one thread each, no dashboard) by default, or on an existing cluster given by its
scheduler address. Each case writes ``OUT_DIR/case_NNNNN.h5`` (from the worker: with a remote
cluster OUT_DIR must be on a filesystem the workers share); the index ``OUT_DIR/index.csv`` and
``OUT_DIR/index.json`` hold one row per case.

Parameters (``--set``): ``Tag[id].attr=VALUES`` or ``Tag.attr=VALUES`` (an element that occurs
once, e.g. ``Param_Static``, ``Force_Gravity``). VALUES: an inclusive range ``a:b:step`` or a
list ``v1,v2,…``. Values are checked against the schema (kind, bounds, enum choices); the
substituted deck is validated again in the worker (an invalid combination gives an
``invalid_deck`` row). ``Param_Static.attr`` for a deck without a model ``Param_Static`` becomes
a solver override.

Modes: ``grid`` (Cartesian product, first parameter slowest), ``zip`` (parameters in lock-step,
equal lengths), ``random`` (``n`` cases; ranges of real attributes are sampled uniformly in
[a, b], other parameters uniformly from their values; ``numpy.random.default_rng(seed)``).

Resuming: a case whose file exists, has a ``status`` root attribute and records the same
``sweep_case_hash`` (SHA-256 of deck hash, case values, overrides and poise version) is not
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
``message``. Outputs
``group[id].dataset`` (``bodies[2].position``, ``joints[1].force``, ``requests[1].values``, …)
give the last frame of the last analysis, flattened: ``bodies[2].position[0]`` … ``[2]``.
"""
from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import re
import sys
from dataclasses import dataclass, replace
from typing import Any

from poise.app.batch import ensure_out_dir, inputs_fresh, result_stats, sanitize, write_table
from poise.app.run_warnings import collected_warnings
from poise.app.runner import run_spec
from poise.core.atomic import OutputError
from poise.core.errors import DeckError, UsageError
from poise.core.version import __version__
from poise.deck.parser import parse_deck_bytes, parse_number
from poise.deck.schema import element_schema, ENUM_ALIASES
from poise.elements.registry import output_groups as registry_output_groups
from poise.results.hdf5 import read_results, write_results
from poise.results.schema import element_outputs
from poise.solvers.settings import check_override_names

INDEX_VERSION = 1
INDEX_KEYS = ("case", "file", "status", "exit_code", "iterations", "wall_time", "imbalance",
              "imbalance_analysis", "imbalance_frame", "stability_class", "stability_analysis",
              "stability_frame", "n_negative", "n_zero", "stability_modes", "modes",
              "resumed", "message")

_SPEC = re.compile(r"^\s*([A-Za-z][A-Za-z0-9_]*)\s*(?:\[\s*(-?\d+)\s*\])?\s*\.\s*"
                   r"([A-Za-z][A-Za-z0-9_]*)\s*$")
_OUT = re.compile(r"^\s*([a-z_]+)\s*\[\s*(-?\d+)\s*\]\s*\.\s*([A-Za-z_][A-Za-z0-9_]*)\s*$")
_SWEEPABLE = ("real", "int", "real_or_expr", "enum", "bool")

def output_groups() -> dict:
    """Output group -> deck tags whose ids it holds (for checking ``--output`` ids; None: any
    tag): the bodies and every group an element type declares
    (:func:`poise.elements.registry.output_groups`) whose per-element datasets the results
    schema declares."""
    declared = element_outputs()
    groups = {"bodies": ("Body_Rigid", "Body_Point"), **registry_output_groups()}
    return {g: tags for g, tags in groups.items() if g in declared}


@dataclass
class Param:
    """One swept attribute: ``key`` as written canonically (``Force_SpringDamper[3].stiffness``)."""

    key: str
    tag: str
    id: int | None
    attr: str
    kind: str
    values: list
    range: tuple | None = None        # (a, b) of an a:b:step range
    override: bool = False            # Param_Static without a model element: solver override


# ---------------------------------------------------------------------------- parameters
def _num(text: str, kind: str, where: str):
    v = parse_number(text)
    if v is None or not math.isfinite(v):
        raise UsageError(f"{where}: {text!r} is not a number")
    if kind == "int":
        if v != int(v):
            raise UsageError(f"{where}: {text!r} is not an integer")
        return int(v)
    return v


def _clean(v: float) -> float:
    """Round range points to 12 significant digits (0.1*3 -> 0.3, not 0.30000000000000004)."""
    return float(f"{v:.12g}")


def _check_value(attr, v, where: str):
    if attr.kind == "enum":
        u = " ".join(str(v).upper().split())
        u = ENUM_ALIASES.get(u, u)
        if attr.choices and u not in attr.choices:
            raise UsageError(f"{where}: {v!r} is not one of {', '.join(attr.choices)}")
        return u
    if attr.kind == "bool":
        u = str(v).strip().upper()
        if u in ("TRUE", "YES", "1", "T", "ON"):
            return True
        if u in ("FALSE", "NO", "0", "F", "OFF"):
            return False
        raise UsageError(f"{where}: {v!r} is not a boolean (TRUE/FALSE)")
    x = _num(str(v), "int" if attr.kind == "int" else "real", where) \
        if not isinstance(v, (int, float)) or isinstance(v, bool) else v
    if attr.kind == "int":
        if float(x) != int(x):
            raise UsageError(f"{where}: {v!r} is not an integer")
        x = int(x)
    else:
        x = float(x)
        if not math.isfinite(x):
            raise UsageError(f"{where}: {v!r} is not finite")
    bad = ((attr.lo is not None and (x < attr.lo or (attr.lo_open and x == attr.lo)))
           or (attr.hi is not None and (x > attr.hi or (attr.hi_open and x == attr.hi))))
    if bad:
        raise UsageError(f"{where}: {x!r} out of bounds; {attr.name} must be {attr.bounds_text()}")
    return x


def parse_values(attr, text, where: str) -> tuple[list, tuple | None]:
    """``a:b:step`` (inclusive) or ``v1,v2,…`` (or a Python list) -> checked values, range."""
    if isinstance(text, (list, tuple)):
        vals = [_check_value(attr, v, where) for v in text]
        if not vals:
            raise UsageError(f"{where}: no values")
        return vals, None
    text = str(text).strip()
    if ":" in text and attr.kind in ("real", "int", "real_or_expr"):
        parts = text.split(":")
        if len(parts) != 3:
            raise UsageError(f"{where}: range must be a:b:step, got {text!r}")
        kind = "int" if attr.kind == "int" else "real"
        a, b, step = (_num(p.strip(), kind, where) for p in parts)
        span = (float(b) - float(a)) / float(step) if step != 0 else math.nan
        if step == 0 or span < 0:
            raise UsageError(f"{where}: step {step!r} does not go from {a!r} to {b!r}")
        if not span < 1_000_000:            # also inf/nan: b - a overflows a float
            raise UsageError(f"{where}: range {text!r} has more than 1000000 values "
                             "(or overflows)")
        n = int(math.floor(span + 1e-9)) + 1
        raw = [a + i * step for i in range(n)]
        vals = [_check_value(attr, v if kind == "int" else _clean(v), where) for v in raw]
        return vals, (a, b)
    items = [t.strip() for t in text.split(",")]
    if not text or any(not t for t in items):
        raise UsageError(f"{where}: expected a:b:step or v1,v2,..., got {text!r}")
    return [_check_value(attr, t, where) for t in items], None


def resolve_param(spec, key: str, values) -> Param:
    """Check ``Tag[id].attr`` against the deck and the schema; parse and check its values."""
    where = f"--set {key!r}"
    m = _SPEC.match(key)
    if not m:
        raise UsageError(f"{where}: expected Tag[id].attr or Tag.attr, "
                         f"e.g. Force_SpringDamper[3].stiffness")
    tag, eid, name = m.group(1), m.group(2), m.group(3)
    sch = element_schema(tag)
    if sch is None:
        raise UsageError(f"{where}: unknown element <{tag}>")
    a = sch.attr(name)
    if a is None:
        raise UsageError(f"{where}: <{sch.tag}> has no attribute {name!r}")
    if a.kind not in _SWEEPABLE or a.ref or a.name == "id":
        raise UsageError(f"{where}: attribute {a.name!r} ({a.kind}{', reference' if a.ref else ''})"
                         f" cannot be swept; numeric, enum and boolean attributes can")
    els = [e for e in spec.model if e.tag == sch.tag]
    override = False
    if eid is not None:
        eid = int(eid)
        if not any(e.id == eid for e in els):
            have = sorted(e.id for e in els if e.id is not None)
            raise UsageError(f"{where}: the deck has no <{sch.tag} id={eid}>"
                             + (f"; ids: {', '.join(map(str, have))}" if have else ""))
        canon = f"{sch.tag}[{eid}].{a.name}"
    else:
        if len(els) > 1:
            raise UsageError(f"{where}: the deck has {len(els)} <{sch.tag}> elements; "
                             f"address one as {sch.tag}[id].{a.name}")
        if not els:
            if sch.tag != "Param_Static":
                raise UsageError(f"{where}: the deck has no <{sch.tag}> element")
            override = True
        canon = f"{sch.tag}.{a.name}"
    vals, rng = parse_values(a, values, f"--set {canon}")
    return Param(canon, sch.tag, eid, a.name, a.kind, vals, rng, override)


def parse_set(text: str) -> tuple[str, str]:
    """``'Tag[id].attr=values'`` -> (key, values)."""
    if "=" not in text:
        raise UsageError(f"--set {text!r}: expected Tag[id].attr=VALUES")
    k, v = text.split("=", 1)
    return k.strip(), v.strip()


#: Default cap on the number of cases of one sweep (``--max-cases``).
MAX_CASES = 100_000


def count_cases(params: list[Param], mode: str = "grid", n: int | None = None) -> int:
    """The number of cases :func:`make_cases` would make, without making them."""
    if mode == "grid":
        return math.prod(len(p.values) for p in params)
    if mode == "zip":
        return max((len(p.values) for p in params), default=0)
    if mode == "random":
        return int(n or 0)
    raise UsageError(f"unknown sweep mode {mode!r}; expected grid, zip or random")


def check_case_count(params: list[Param], mode: str = "grid", n: int | None = None,
                     max_cases: int | None = MAX_CASES) -> int:
    """:func:`count_cases`, refused (``UsageError``) above ``max_cases`` (None: no cap)."""
    total = count_cases(params, mode, n)
    if max_cases is not None and total > max_cases:
        what = "--random N" if mode == "random" else \
            " x ".join(str(len(p.values)) for p in params) + " values"
        raise UsageError(f"the sweep has {total} cases ({what}), more than --max-cases "
                         f"{max_cases}; raise --max-cases to run it")
    return total


def make_cases(params: list[Param], mode: str = "grid", n: int | None = None,
               seed: int | None = 0) -> list[dict]:
    """Case values: list of {param key: value} in case order (check the count first:
    :func:`check_case_count`)."""
    keys = [p.key for p in params]
    if mode == "grid":
        return [dict(zip(keys, combo)) for combo in itertools.product(*[p.values for p in params])]
    if mode == "zip":
        lens = {p.key: len(p.values) for p in params}
        if len(set(lens.values())) > 1:
            raise UsageError("--zip needs the same number of values for every --set; got "
                             + ", ".join(f"{k}: {v}" for k, v in lens.items()))
        return [dict(zip(keys, combo)) for combo in zip(*[p.values for p in params])]
    if mode == "random":
        if not n or n < 1:
            raise UsageError("--random N needs N >= 1")
        import numpy as np
        rng = np.random.default_rng(seed)
        cases = []
        for _ in range(n):
            c = {}
            for p in params:
                if p.range is not None and p.kind in ("real", "real_or_expr"):
                    c[p.key] = _clean(float(rng.uniform(p.range[0], p.range[1])))
                else:
                    c[p.key] = p.values[int(rng.integers(len(p.values)))]
            cases.append(c)
        return cases
    raise UsageError(f"unknown sweep mode {mode!r}; expected grid, zip or random")


def case_hash(deck_sha256: str, values: dict, overrides: dict | None) -> str:
    blob = json.dumps({"deck_sha256": deck_sha256, "values": values,
                       "overrides": overrides or {}, "poise_version": __version__},
                      sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()


def apply_case(spec, params: list[Param], values: dict):
    """A copy of ``spec`` with the case values substituted (model elements copied only where
    changed) and the solver overrides of ``Param_Static`` parameters without an element."""
    changes: dict[int, dict] = {}
    overrides = {}
    for p in params:
        v = values[p.key]
        if p.override:
            overrides[p.attr] = v
            continue
        for k, e in enumerate(spec.model):
            if e.tag == p.tag and (p.id is None or e.id == p.id):
                changes.setdefault(k, {})[p.attr] = v
                break
    model = list(spec.model)
    for k, ch in changes.items():
        model[k] = replace(model[k], attrs={**model[k].attrs, **ch})
    return replace(spec, model=model, warnings=[]), overrides


# ---------------------------------------------------------------------------- outputs
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


def _spec_from_bytes(data: bytes, path: str):
    key = hashlib.sha256(data).hexdigest() + "\0" + path
    spec = _SPEC_CACHE.get(key)
    if spec is None:
        spec = parse_deck_bytes(data, path)
        if len(_SPEC_CACHE) > 8:
            _SPEC_CACHE.clear()
        _SPEC_CACHE[key] = spec
    return spec


def run_case(data: bytes, path: str, params: list[Param], index: int, values: dict,
             overrides: dict | None, out_file: str, chash: str, outputs,
             allow_user_code: bool = False) -> dict:
    """Solve one case and write its results file; return its index row (a Dask task).
    ``allow_user_code``: run the deck's Python user routines (in the worker)."""
    row = {"case": index, "file": None, **values}
    try:
        base = _spec_from_bytes(data, path)
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
                     run_overrides=json.dumps(overrides or {}, sort_keys=True, default=str))
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
class _Progress:
    """A one-line progress bar on stderr, only on a terminal and outside CI."""

    def __init__(self, total: int, enabled: bool | None = None):
        if enabled is None:
            try:
                enabled = sys.stderr.isatty() and not os.environ.get("CI")
            except (AttributeError, ValueError):
                enabled = False
        self.total, self.n, self.on = total, 0, bool(enabled) and total > 0

    def step(self, k: int = 1):
        self.n += k
        if self.on:
            w = 30
            f = int(w * self.n / self.total)
            sys.stderr.write(f"\r[{'#' * f}{'.' * (w - f)}] {self.n}/{self.total}")
            sys.stderr.flush()

    def close(self):
        if self.on:
            sys.stderr.write("\n")
            sys.stderr.flush()


def run_sweep(deck, sets, mode: str = "grid", out_dir: str = "sweep", scheduler=None,
              outputs=(), n=None, seed=0, workers=None, overrides=None, force=False,
              progress: bool | None = None, on_row=None, client=None,
              allow_user_code: bool = False, max_cases: int | None = MAX_CASES) -> list[dict]:
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

    Raises
    ------
    poise.core.errors.UsageError
        Bad ``sets``/``outputs``/mode (exit 2 in the CLI).
    poise.core.errors.DeckError
        The base deck is invalid (exit 3).
    """
    deck = os.fspath(deck)
    try:
        with open(deck, "rb") as f:
            data = f.read()
    except OSError as e:
        raise UsageError(f"cannot read deck {deck!r}: {e.strerror or e}") from None
    spec = parse_deck_bytes(data, deck)
    items = [parse_set(s) for s in sets] if isinstance(sets, (list, tuple)) else list(sets.items())
    if not items:
        raise UsageError("nothing to sweep: give at least one --set Tag[id].attr=VALUES")
    params = [resolve_param(spec, k, v) for k, v in items]
    if len({p.key for p in params}) != len(params):
        raise UsageError("the same attribute is given twice in --set")
    outs = parse_outputs(spec, outputs)
    check_case_count(params, mode, n=n, max_cases=max_cases)
    if scheduler and client is None:
        check_scheduler(scheduler)
    cases = make_cases(params, mode, n=n, seed=seed)
    check_override_names(overrides)
    overrides = {k: v for k, v in (overrides or {}).items() if v is not None}
    ensure_out_dir(out_dir)
    width = max(5, len(str(len(cases) - 1)))
    files = [os.path.join(os.path.abspath(out_dir), f"case_{i:0{width}d}.h5")
             for i in range(len(cases))]
    hashes = [case_hash(spec.sha256, c, overrides) for c in cases]
    rows: list[Any] = [None] * len(cases)
    bar = _Progress(len(cases), progress)
    todo = []
    for i, c in enumerate(cases):
        if not force and resumable(files[i], hashes[i], allow_user_code):
            try:
                rows[i] = {**resumed_row(files[i], i, c, outs), "resumed": True}
                bar.step()
                if on_row:
                    on_row(rows[i])
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
        write_table(ordered, os.path.join(out_dir, "index"), keys=keys,
                    extra={"index_version": INDEX_VERSION, "deck": deck,
                           "deck_sha256": spec.sha256, "mode": mode,
                           "parameters": {p.key: p.values for p in params},
                           "overrides": overrides, "n_cases": len(cases)})
        return [sanitize(r) for r in ordered]

    try:
        if todo:
            _run_dask(todo, rows, data, deck, params, cases, overrides, files, hashes, outs,
                      scheduler, workers, client, bar, on_row, allow_user_code)
    finally:
        bar.close()
        result = finish()
    return result


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
              scheduler, workers, client, bar, on_row, allow_user_code=False):
    import logging

    from dask.distributed import Client, LocalCluster, as_completed
    cluster = None
    own = client is None
    if own:
        if scheduler:
            try:
                client = Client(scheduler, timeout="20s")
            except (OSError, TimeoutError, ValueError, TypeError) as e:
                raise UsageError(f"--scheduler {scheduler!r}: cannot connect: {e}") from None
        else:
            nw = workers or os.cpu_count() or 1
            cluster = LocalCluster(n_workers=min(nw, max(1, len(todo))), threads_per_worker=1,
                                   processes=True, dashboard_address=None,
                                   silence_logs=logging.ERROR)
            client = Client(cluster)
    try:
        deck_abs = deck
        futs = {}
        for i in todo:
            f = client.submit(run_case, data, deck_abs, params, i, cases[i], overrides,
                              files[i], hashes[i], outs, bool(allow_user_code),
                              key=f"poise-case-{i}-{hashes[i][:16]}", pure=False)
            futs[f] = i
        for fut in as_completed(list(futs)):
            i = futs[fut]
            try:
                rows[i] = fut.result()
            except Exception as e:  # noqa: BLE001 - lost worker, serialisation ...
                rows[i] = {"case": i, "file": None, **cases[i], "status": "internal_error",
                           "exit_code": 4, "message": f"{type(e).__name__}: {e}"}
            rows[i]["resumed"] = False
            bar.step()
            if on_row:
                on_row(rows[i])
    finally:
        if own:
            client.close()
            if cluster is not None:
                cluster.close()

