"""Chunks of sweep cases solved in a worker: the seam of a vectorised sweep solver.

A sweep's cases are grouped by *structure* (the values of its enum and boolean parameters:
method, joint type, ...; :func:`poise.app.cases.group_cases`) and sent to the workers in
chunks of one group. A worker builds the group's :class:`CaseTemplate` once per chunk (the deck
with the group's values substituted, compiled once) and calls :func:`solve_chunk`, which
returns one :class:`CaseRecord` per case. Today it loops over the cases, each validated and
solved exactly as ``poise solve`` would (so a case gives the same bits alone, in any chunk, or
resumed); cases that change only solver settings reuse the template's compiled model. A
vectorised solver replaces that loop, same records out: one batched evaluation and one batched
factorisation per Newton iteration for the whole chunk. :func:`run_chunk` is the Dask task:
template (cached per worker), solve_chunk, and :func:`pack` into columns for the sweep file.
"""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from poise.app.batch import overrides_json
from poise.app.cases import apply_case, case_hash
from poise.app.run_warnings import collected_warnings
from poise.app.runner import run_spec
from poise.core.atomic import OutputError
from poise.core.errors import DeckError
from poise.deck.parser import parse_deck_bytes
from poise.model.compile import compile_model
from poise.results.hdf5 import write_results
from poise.results.schema_sweep import NO_INT
from poise.results.summary import summarize_run


@dataclass(frozen=True)
class FrameLayout:
    """The frames of a sweep file: each frame's time and analysis (``Simulate``)."""

    time: tuple = ()
    analysis: tuple = ()

    @property
    def n(self) -> int:
        return len(self.time)


@dataclass(frozen=True)
class Output:
    """One ``--output group[id].dataset``: its text (the sweep variable's name), the results
    group, element id and dataset, and the dataset's trailing shape and dtype kind."""

    text: str
    group: str
    id: int
    dataset: str
    trailing: tuple = ()
    kind: str = "f"


@dataclass(frozen=True)
class SweepJob:
    """What every chunk of one sweep needs (sent with each task). ``case_dir``: write each
    case's results file there (``--per-case-files``), named ``case_<NNNNN>.h5`` with ``width``
    digits; ``key``: digest of the sweep's inputs (the workers' template cache)."""

    data: bytes
    path: str
    params: tuple
    overrides: dict
    outputs: tuple
    layout: FrameLayout
    allow_user_code: bool = False
    ignore: tuple = ()
    case_dir: str | None = None
    width: int = 5
    key: str = ""

    @property
    def structural(self) -> tuple:
        return tuple(p for p in self.params if p.structural)

    @property
    def numeric(self) -> tuple:
        return tuple(p for p in self.params if not p.structural)


@dataclass(frozen=True)
class CaseTemplate:
    """The structure shared by one group's cases: ``spec`` (the deck with the group's values
    substituted), ``overrides`` (the sweep's solver options), and ``model`` compiled from it
    once (None when that deck does not compile: each case then reports its own problems).
    ``settings_only``: the cases change nothing but ``Param_Static`` values, so every case is
    solved on ``model`` itself."""

    job: SweepJob
    group: dict
    spec: Any
    overrides: dict
    model: Any = None
    settings_only: bool = False


@dataclass
class CaseRecord:
    """What the sweep file keeps of one case (:mod:`poise.results.schema_sweep`)."""

    case: int
    status: str
    exit_code: int
    iterations: int = NO_INT
    wall_time: float = math.nan
    imbalance: float = math.nan
    imbalance_analysis: int = NO_INT
    imbalance_frame: int = NO_INT
    error: float = math.nan
    stability: str = ""
    stability_analysis: int = NO_INT
    stability_frame: int = NO_INT
    n_negative: int = NO_INT
    n_zero: int = NO_INT
    stability_modes: str = ""
    modes: str = "[]"
    message: str = ""
    file: str = ""
    converged: np.ndarray | None = None
    outputs: dict = field(default_factory=dict)
    input_files: str = ""


#: per-case scalar fields of a record, in the sweep file's order
FIELDS = ("status", "exit_code", "iterations", "wall_time", "imbalance", "imbalance_analysis",
          "imbalance_frame", "error", "stability", "stability_analysis", "stability_frame",
          "n_negative", "n_zero", "stability_modes", "modes", "message", "file")


# ---------------------------------------------------------------------------- templates
_SPECS: dict[str, Any] = {}
_TEMPLATES: dict[str, CaseTemplate] = {}


def _base_spec(job: SweepJob):
    """The parsed deck of ``job``, parsed once per process: a private copy each call (its own
    elements and attribute dicts), so that nothing done with one template can reach the
    cached parse or another template."""
    key = hashlib.sha256(job.data).hexdigest() + "\0" + job.path + "\0" + ",".join(job.ignore)
    spec = _SPECS.get(key)
    if spec is None:
        spec = parse_deck_bytes(job.data, job.path,
                                **({"ignore": job.ignore} if job.ignore else {}))
        if len(_SPECS) > 8:
            _SPECS.clear()
        _SPECS[key] = spec
    return spec.copy(elements=True)


def make_template(job: SweepJob, group: dict) -> CaseTemplate:
    """The template of the cases with structural values ``group`` (compiled once)."""
    base = _base_spec(job)
    spec, extra = apply_case(base, list(job.structural), group)
    spec.warnings = list(base.warnings)
    settings_only = all(p.tag == "Param_Static" for p in job.numeric)
    try:
        model = compile_model(spec, user_code="run" if job.allow_user_code else "refuse")
    except DeckError:
        model = None
    if model is not None and model.user_routines:
        settings_only = False       # user code may keep state: every case compiles its own
    return CaseTemplate(job, dict(group), spec, {**job.overrides, **extra}, model,
                        settings_only and model is not None)


def template_for(job: SweepJob, group: dict) -> CaseTemplate:
    """:func:`make_template`, cached in the worker (a few groups per sweep)."""
    key = job.key + "\0" + json.dumps(group, sort_keys=True, default=str)
    t = _TEMPLATES.get(key)
    if t is None:
        t = make_template(job, group)
        if len(_TEMPLATES) > 8:
            _TEMPLATES.clear()
        _TEMPLATES[key] = t
    return t


# ---------------------------------------------------------------------------- solving
def solve_chunk(template: CaseTemplate, cases: list[tuple[int, dict]],
                batched: bool = True) -> list[CaseRecord]:
    """Solve ``cases`` (``(case number, {parameter: value})``) of one template; one record
    each, in order: together where they may be (:mod:`poise.app.chunk_batch`), the others
    each on its own exactly as ``poise solve`` solves its deck (also every case with
    ``batched=False``)."""
    if not batched or len(cases) < 2:
        return [solve_case(template, index, values) for index, values in cases]
    from poise.app.chunk_batch import solve_batched    # lazy: only sweeps import it
    return solve_batched(template, cases, batch_record,
                         lambda index, values: solve_case(template, index, values))


def batch_record(index: int, c, wall: float, outputs: dict, input_files: str) -> CaseRecord:
    """The record of a case the batch converged (:class:`poise.solvers.batched.CaseResult`):
    what a single solve's record of that converged, stable, one-frame analysis holds."""
    info = c.info
    return CaseRecord(index, "converged", 0, int(c.iterations), wall, float(c.imbalance), 0, 0,
                      float(c.error), info.klass, 0, 0, int(info.n_negative), int(info.n_zero),
                      "", "[]", "", converged=np.ones(1, bool), outputs=outputs,
                      input_files=input_files)


def solve_case(template: CaseTemplate, index: int, values: dict) -> CaseRecord:
    """One case: substituted, validated and solved; its record (never raises for a case)."""
    job = template.job
    layout = job.layout
    try:
        base = _base_spec(job)
        spec, extra = apply_case(base, list(job.params), values)
        spec.warnings = list(base.warnings)         # run_spec validates the case (once)
        with collected_warnings() as numeric:       # numpy warnings: run warnings
            res = run_spec(spec, {**job.overrides, **extra},
                           command=f"poise sweep case {index}: "
                                   f"{json.dumps(values, default=str)}",
                           allow_user_code=job.allow_user_code,
                           model=template.model if template.settings_only else None)
        res.warnings = list(res.warnings) + numeric
    except DeckError as e:
        problems = [str(p) for p in e.problems] or [str(e)]
        return _empty(index, "invalid_deck", 3, "; ".join(problems), layout)
    except Exception as e:  # noqa: BLE001 - one bad case never stops the sweep
        return _empty(index, "internal_error", 4, f"{type(e).__name__}: "
                      f"{' '.join(str(e).split())}", layout)
    rec = record_of(index, res, job)
    if job.case_dir is not None:
        _write_case_file(rec, res, job, values)
    return rec


def _empty(index: int, status: str, code: int, message: str, layout: FrameLayout) -> CaseRecord:
    return CaseRecord(index, status, code, message=message,
                      converged=np.zeros(layout.n, bool))


def record_of(index: int, res, job: SweepJob) -> CaseRecord:
    """The record of a solved case: the run summary of a batch row
    (:func:`poise.results.summary.summarize_run`), the worst error, and ``converged`` and the
    outputs at each of the sweep's frames."""
    run = summarize_run(res)
    errors = [s.error for s in run.analyses if s.error is not None and math.isfinite(s.error)]
    rec = CaseRecord(
        index, res.status, int(res.exit_code), _int(run.iterations),
        sum(float(res.timings.get(k, 0.0)) for k in ("parse", "compile", "solve")),
        _float(run.imbalance), _int(run.imbalance_analysis), _int(run.imbalance_frame),
        max(errors, default=math.nan), run.stability_class or "",
        _int(run.stability_analysis), _int(run.stability_frame), _int(run.n_negative),
        _int(run.n_zero), run.stability_modes or "",
        json.dumps([m.as_dict() for m in run.modes], separators=(",", ":")), run.message or "",
        input_files=str(res.attrs.get("input_files") or ""))
    rec.converged, rec.outputs, note = frame_values(res, job)
    if note:
        rec.message = f"{rec.message}; {note}" if rec.message else note
    return rec


def _int(v) -> int:
    return NO_INT if v is None else int(v)


def _float(v) -> float:
    return math.nan if v is None else float(v)


def frame_values(res, job: SweepJob) -> tuple[np.ndarray, dict, str]:
    """``converged (F,)`` and ``{output: (F, ...)}`` of a run at the sweep's frames,
    and a note when a frame the run has is at another time than the sweep's (its values are then
    left out: NaN, not converged)."""
    layout = job.layout
    times = np.asarray(layout.time, float)
    which = np.asarray(layout.analysis, int)
    conv = np.zeros(layout.n, bool)
    outs = {o.text: np.full((layout.n, *o.trailing), np.nan if o.kind == "f" else NO_INT,
                            float if o.kind == "f" else np.int64) for o in job.outputs}
    moved = []
    for k, a in enumerate(res.analyses):
        slots = np.nonzero(which == k)[0]
        t = np.asarray(a.datasets.get("time", ()), float)
        n = min(len(t), len(slots))
        same = t[:n] == times[slots[:n]]
        if not same.all():
            moved.append(k)
        at, rows = slots[:n][same], np.nonzero(same)[0]
        c = a.datasets.get("frames/converged")
        if c is not None:
            conv[at] = np.asarray(c, bool)[rows]
        for o in job.outputs:
            arr = _element(res, a, o)
            if arr is not None:
                outs[o.text][at] = arr[rows]
    note = "" if not moved else (
        f"frames of analysis {', '.join(map(str, moved))} are not at the sweep's frame times (an "
        "analysis before stopped early): left out of the sweep file")
    return conv, outs, note


def _element(res, a, o: Output):
    ids = a.datasets.get(f"{o.group}/id")
    if ids is None:
        ids = res.model_datasets.get(f"{o.group}/id")
    data = a.datasets.get(f"{o.group}/{o.dataset}")
    if ids is None or data is None or np.ndim(data) < 2:
        return None
    hit = np.nonzero(np.asarray(ids) == o.id)[0]
    return np.asarray(data)[:, hit[0]] if len(hit) else None


def _write_case_file(rec: CaseRecord, res, job: SweepJob, values: dict) -> None:
    """``--per-case-files``: the case's own results file (root attributes ``sweep_case``,
    ``sweep_values``, ``sweep_case_hash``, ``run_overrides``)."""
    import os
    name = f"case_{rec.case:0{job.width}d}.h5"
    res.attrs.update(sweep_case=int(rec.case),
                     sweep_case_hash=case_hash(_base_spec(job).sha256, values,
                                               overrides_with_ignore(job.overrides, job.ignore)),
                     sweep_values=json.dumps(values, sort_keys=True, default=str),
                     run_overrides=overrides_json(job.overrides, job.ignore))
    try:
        write_results(res, os.path.join(job.case_dir, name))
    except OutputError as e:            # disk full: an I/O error, the sweep goes on
        rec.status, rec.exit_code = "io_error", 2
        rec.message = " ".join(str(e).split())
        return
    rec.file = name


def overrides_with_ignore(overrides: dict | None, ignore=()) -> dict:
    """The solver options a case hash covers: ``overrides`` and the ``--ignore`` kinds."""
    return {**(overrides or {}), **({"ignore": list(ignore)} if ignore else {})}


# ---------------------------------------------------------------------------- the Dask task
def run_chunk(job: SweepJob, group: dict, cases: list[tuple[int, dict]]) -> dict:
    """A Dask task: the chunk's records as columns (:func:`pack`)."""
    return pack(solve_chunk(template_for(job, group), cases), job)


def pack(records: list[CaseRecord], job: SweepJob) -> dict:
    """Records -> ``{variable: array}`` with one row per case (``case`` first), plus
    ``input_files`` (the scripts the cases read, JSON; empty when none)."""
    n = len(records)
    out: dict[str, Any] = {"case": np.array([r.case for r in records], np.int64)}
    for name in FIELDS:
        vals = [getattr(r, name) for r in records]
        out[name] = np.array(vals, dtype=object if isinstance(vals[0], str) else None) \
            if n else np.zeros(0)
    out["converged"] = np.array([r.converged for r in records], bool).reshape(n, job.layout.n)
    for o in job.outputs:
        out[o.text] = np.array([r.outputs.get(o.text) if o.text in r.outputs else
                                np.full((job.layout.n, *o.trailing), np.nan)
                                for r in records]).reshape(n, job.layout.n, *o.trailing)
    out["input_files"] = next((r.input_files for r in records if r.input_files), "")
    return out
