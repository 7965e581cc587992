"""Run every analysis of a deck: parse -> compile -> solve -> RunResult.

This is the one place that sequences analyses: each ``Simulate`` starts from the state the
previous one left; command versions of ``Param_Static`` between them change the live settings,
command versions of model elements the model of the analyses after them (poise.model.commands);
CLI overrides win over the deck (defaults < deck < CLI).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any, Callable


from poise.app import deck_cache
from poise.app.budget import check_memory
from poise.app.model_outputs import graphics_datasets, joint_marker_datasets, model_datasets
from poise.app.times import output_times, print_arrays
from poise.core import blas, memory, phases
from poise.core.progress import installed, solver_progress
from poise.core.readonly import seal
from poise.core.errors import DeckError, EvaluationError, Problem, SourceLoc, UsageError
from poise.core.version import __version__
from poise.deck.parser import load_deck
from poise.deck.schema import element_schema
from poise.deck.spec import DeckSpec, Element
from poise.deck.validate import validate
from poise.model import commands as model_commands
from poise.model.compile import compile_model
from poise.results.data import STATUS_FAILED, AnalysisResult, RunResult
from poise.results.labels import Labeller
from poise.results.summary import summarize
from poise.results.summary import summary_line as _summary_line
from poise.solvers.driver import Driver, strategy_for
from poise.solvers.settings import StaticSettings, check_override_names


def load_input(path, ignore=()):
    if isinstance(path, DeckSpec):  # already parsed (run_spec: sweeps, poise.solve(spec))
        return revalidated(path)
    check_ignore(path, ignore)
    return load_deck(path, ignore=ignore)


def check_ignore(path, ignore) -> None:
    """``ignore`` (``--ignore KIND``) names kinds an Adams dataset may leave out; a usage
    error for any other kind, or for a deck that is not an Adams dataset."""
    if not ignore:
        return
    from poise.deck.adm.vocab import IGNORABLE  # lazy: only Adams datasets need the vocabulary
    if not str(path).lower().endswith((".adm", ".acf")):
        raise UsageError("--ignore applies to Adams datasets (.adm, .acf); "
                         f"{str(path)!r} is not one")
    bad = [k for k in ignore if str(k).upper() not in IGNORABLE]
    if bad:
        import difflib
        near = difflib.get_close_matches(str(bad[0]).upper(), IGNORABLE, n=1)
        raise UsageError(f"--ignore {bad[0]}: unknown kind" + (f" (did you mean {near[0]}?)"
                         if near else "") + "; expected one of " + ", ".join(IGNORABLE))


def ignored_counts(ignored) -> str:
    """``2 CONTACT, 1 USER`` for the elements an Adams dataset left out (``""``: none)."""
    counts: dict = {}
    for d in ignored:
        counts[d["kind"]] = counts.get(d["kind"], 0) + 1
    return ", ".join(f"{n} {k}" for k, n in counts.items())


def ignored_text(ignored) -> str:
    """``left out (--ignore): 2 CONTACT, 1 USER`` for the elements an Adams dataset left out."""
    return "left out (--ignore): " + ignored_counts(ignored)


def ignore_kinds(path, ignore) -> tuple:
    """The ``--ignore`` kinds that apply to ``path`` (sorted, upper case; none for an XML
    deck): what a batch or sweep records to tell whether a results file is up to date."""
    if not str(path).lower().endswith((".adm", ".acf")):
        return ()
    return tuple(sorted({str(k).upper() for k in ignore or ()}))


def revalidated(spec: DeckSpec) -> DeckSpec:
    """``spec`` validated again exactly as the parser validates a file (same located
    :class:`DeckError`): a DeckSpec may have been edited in memory since it was loaded.

    Always run (no dirty tracking): validation costs ~40 ms on a 1000-link chain deck, less
    than fingerprinting its attributes. Returns ``spec``, or a copy with the validation
    warnings not already in ``spec.warnings`` appended (the caller's spec is not modified).
    """
    from dataclasses import replace

    unknown = _unknown_attributes(spec)
    if unknown:
        raise DeckError(unknown)
    tmp = replace(spec, warnings=[])
    validate(tmp)
    known = {str(w) for w in spec.warnings}
    new = [w for w in tmp.warnings if str(w) not in known]
    return replace(spec, warnings=[*spec.warnings, *new]) if new else spec


def _unknown_attributes(spec: DeckSpec) -> list[Problem]:
    """Attributes of a DeckSpec its element's schema does not know (or spells otherwise): the
    parser drops and warns about those of a file, so here they come from an edit such as
    ``spring.attrs["stifness"] = 1`` that would otherwise be ignored without a word."""
    import difflib
    out = []
    for el in [*spec.model, *spec.commands]:
        known = _attribute_names(el.tag)
        if known is None or known.issuperset(el.attrs):
            continue                      # validate() says what is wrong with the tag
        sch = element_schema(el.tag)
        for k in set(el.attrs) - known:
            a = sch.attr(str(k))
            if a is not None:
                hint = f"; it is spelt '{a.name}'"
            else:
                close = difflib.get_close_matches(str(k).lower(), sorted(sch.attrs), n=1)
                hint = f" (did you mean '{close[0]}'?)" if close else ""
            out.append(Problem(el.loc, f"unknown attribute '{k}' of <{sch.tag}>{hint}"))
    return out


@functools.lru_cache(maxsize=None)
def _attribute_names(tag: str) -> frozenset | None:
    """Canonical attribute names of element ``tag`` (None: unknown tag or open attributes)."""
    sch = element_schema(tag)
    return None if sch is None or sch.open_attrs else frozenset(sch.attrs)


def _static_settings(el_list) -> StaticSettings:
    s = StaticSettings()
    for el in el_list:
        s = _updated(s, el)
    return s


def _updated(s: StaticSettings, el) -> StaticSettings:
    """``s`` with a Param_Static element's attributes; a bad value is the deck's error."""
    try:
        return s.updated(el.attrs)
    except (ValueError, TypeError) as e:
        raise DeckError(Problem(el.loc, f"invalid solver settings: {e}")) from None


def _analysis_kind(el, t_now) -> tuple[str, float | None]:
    at = str(el.attrs.get("analysis_type", "STATIC")).upper().replace("-", "_")
    end = el.attrs.get("end_time")
    if end is None and el.attrs.get("duration") is not None:
        end = t_now + float(el.attrs["duration"])
    if at in ("QUASISTATIC", "QUASI_STATIC"):
        return "quasistatic", end
    if at == "STATIC":
        if end is not None and float(end) > t_now:
            return "quasistatic", float(end)
        return "static", None
    return at.lower(), end


@dataclass
class AnalysisRequest:
    """One ``Simulate`` command with the live settings at that point of the command list.

    Attributes
    ----------
    simulate : Element
    kind : str
        ``"static"`` or ``"quasistatic"`` (or another analysis_type, lower case).
    settings : StaticSettings
        Effective Param_Static (defaults < model element < earlier commands < CLI).
    transient : dict
        Effective Param_Transient attributes (model element, then command versions).
    commands : list[Element]
        Command elements met since the previous Simulate (Force_Gravity changes, ...).
    """

    simulate: Element
    kind: str
    settings: StaticSettings
    transient: dict = field(default_factory=dict)
    commands: list = field(default_factory=list)
    arrays: dict = field(default_factory=dict)     # Reference_Array values by id (PRINT times)

    def output_times(self, t_now: float):
        """Output times of this (quasi-static) analysis starting at ``t_now``."""
        return output_times(self.simulate, t_now, self.arrays)


def plan(spec: DeckSpec, overrides: dict | None) -> list[AnalysisRequest]:
    """The analyses of a deck in command order."""
    check_override_names(overrides)
    overrides = {k: v for k, v in (overrides or {}).items() if v is not None}
    try:      # an invalid override is the caller's error, not the deck's (none: nothing to check)
        if overrides:
            StaticSettings().updated(overrides)
    except (ValueError, TypeError) as e:
        raise UsageError(f"invalid solver option: {e}") from None
    live = _static_settings([e for e in spec.model if e.tag == "Param_Static"])
    transient: dict = {}
    for e in spec.model:
        if e.tag == "Param_Transient":
            transient.update(e.attrs)
    out = []
    pending = []
    arrays = {}
    if any(e.tag == "Reference_Array" for e in spec.model):
        arrays = print_arrays(spec)
    t_now = 0.0
    bad = model_commands.check(spec.commands, spec.warnings)
    if bad:
        raise DeckError(bad)
    for el in spec.commands:
        if el.tag == "Param_Static":
            live = _updated(live, el)
        elif el.tag == "Param_Transient":
            transient.update(el.attrs)
        elif el.tag == "Simulate":
            try:
                s = live.updated(overrides)
            except (ValueError, TypeError) as e:
                raise DeckError(Problem(el.loc, f"invalid solver settings: {e}")) from None
            _check_compliance_markers(spec, s, el, "compliance_markers" in overrides)
            kind, end = _analysis_kind(el, t_now)
            out.append(AnalysisRequest(el, kind, s, dict(transient), pending, arrays))
            if kind == "quasistatic" and end is not None:
                t_now = float(end)
            pending = []
        elif el.tag == "Stop":
            break
        else:
            pending.append(el)
    return out


def _planned(spec: DeckSpec, overrides: dict | None, kept: dict | None) -> list:
    """:func:`plan` of ``spec``; for a kept deck (``kept``: its model's memo, poise.app.deck_cache)
    made once per set of overrides (the deck's file and the overrides decide it) and read only
    afterwards: the settings' validation is not repeated at every run."""
    try:
        key = ("plan", tuple(sorted((overrides or {}).items())))
        hash(key)
    except TypeError:             # an unhashable override value: planned afresh
        key = None
    if kept is None or key is None:
        return plan(spec, overrides)
    got = kept.get(key)
    if got is None:
        got = kept[key] = tuple(plan(spec, overrides))
    return list(got)


def _check_compliance_markers(spec, s, el, from_cli: bool) -> None:
    """Marker ids named by ``compliance_markers`` must exist (checked before any solve): a
    usage error when the ids come from the command line / API, else the deck's."""
    if s.compliance_markers in ("auto", "all", "none"):
        return
    have = {e.attrs.get("id") for e in spec.model if e.tag == "Reference_Marker"}
    bad = [m for m in s.compliance_markers.split() if int(m) not in have and int(m) != 0]
    if not bad:
        return
    msg = f"compliance_markers: marker id {bad[0]} is not a Reference_Marker of the deck"
    if from_cli:
        raise UsageError(msg)
    src = next((e for e in reversed([*spec.model, *spec.commands]) if e.tag == "Param_Static"
                and e.attrs.get("compliance_markers") is not None), el)
    raise DeckError(Problem(src.loc, msg))


def run(path: str, overrides=None, command: str = "", progress=None,
        allow_user_code: bool = False, ignore=(), model=None) -> RunResult:
    """``allow_user_code``: run the Python user routines the deck names (otherwise such a deck
    is a located deck error saying how to allow them). ``ignore``: kinds of Adams dataset
    statements left out instead of refused (recorded in the results). ``model``: the model
    already compiled from this deck's model elements (a sweep's cases that change only
    ``Param_Static`` values share one: :mod:`poise.app.chunks`), else it is compiled here.

    BLAS runs single-threaded meanwhile (poise.core.blas: the dense work is on tiny blocks,
    whatever the caller imported first), and the modules imported on the way are timed as
    their own phase, ``timings['import']``, outside parse/compile/solve (poise.core.phases)."""
    with phases.counting_imports(), blas.limited():
        imported = phases.import_seconds()
        res = _run(path, overrides, command, progress, allow_user_code, ignore, model)
        res.timings["import"] = phases.import_seconds() - imported
        return res


#: Memory of one parsed deck element (its typed attributes, location, label), roughly: how much
#: dropping the deck frees, for :func:`poise.core.memory.release`.
_ELEMENT_BYTES = 1024


def _run(path, overrides, command, progress, allow_user_code, ignore=(),
         model=None) -> RunResult:
    phases.reset()
    now = phases.now            # a clock that stops while modules are imported
    t0 = now()
    spec = deck_cache.load(path, ignore, load_input)     # kept while the file is unchanged
    path = spec.path
    t1 = now()
    user_code = "run" if allow_user_code else "refuse"
    kept = None
    if model is None:
        model = deck_cache.compiled(spec, user_code, compile_model)
        kept = deck_cache.memo(model)      # a kept deck's model: its model datasets made once
    t2 = now()
    analyses = _planned(spec, overrides, kept)
    problems = []
    for req in analyses:
        cls, msg = strategy_for(req)
        if cls is None:
            problems.append(Problem(req.simulate.loc, msg))
    if problems:
        raise DeckError(problems)
    if not analyses:
        raise DeckError(Problem(spec.commands[0].loc if spec.commands else
                                spec.model[0].loc if spec.model else _noloc(path),
                                "no Simulate command; expected at least one "
                                "<Simulate analysis_type=\"Static\"/>"))
    check_memory(spec, model, analyses, overrides)    # a run that cannot fit: refused now
    res = RunResult(deck=path, deck_sha256=spec.sha256, units=model.units,
                    active_effects=list(model.active_effects), command=command)
    res.warnings = [str(w) for w in spec.warnings] + [str(w) for w in model.spec_warnings]
    inputs = {**spec.input_files, **(getattr(model, "input_files", None) or {})}
    if spec.ignored:
        import json
        res.attrs["ignored"] = json.dumps(spec.ignored, sort_keys=True)
    if inputs:           # files read besides the deck (scripts): batch freshness covers them
        import json
        res.attrs["input_files"] = json.dumps(inputs, sort_keys=True)
    if kept is not None and "labeller" in kept:
        labeller = kept["labeller"]
        res.model_datasets = dict(kept["model_datasets"])
    else:
        res.model_datasets = model_datasets(model)
        res.model_datasets.update(joint_marker_datasets(spec, model))
        res.model_datasets.update(graphics_datasets(spec, model))
        labeller = Labeller(spec, model.units, memo=kept is not None)   # labels, request channels
        res.model_datasets.update(labeller.datasets(res.model_datasets, model))
        if kept is not None:       # shared by the runs of this deck: read-only
            kept.update(model_datasets=seal(dict(res.model_datasets)), labeller=labeller)
    models = _analysis_models(spec, model, analyses,
                              lambda sp: compile_model(sp, user_code=user_code))
    for m in models[1:]:
        res.active_effects += [e for e in m.active_effects if e not in res.active_effects]
    ignored = spec.ignored
    dropped = len(spec.model) * _ELEMENT_BYTES
    del spec              # the parsed deck is not needed by the solve: not held meanwhile
    memory.release(dropped)      # its pages back to the OS (large decks), before the solve
    state = model.initial_state()
    counts = {}
    redundancy = None
    for k, req in enumerate(analyses):
        ta = now()
        drv = Driver(models[k], req, redundancy=redundancy, progress=installed())
        state, rec = drv.run(state, index=k)
        ar = AnalysisResult.of(rec)
        redundancy = drv.redundancy
        res.timings[f"analysis_{k:03d}"] = now() - ta
        for key, v in drv.data.as_dict().items():
            counts[key] = counts.get(key, 0) + v
        ar.datasets.update(labeller.datasets(ar.datasets, models[k]))
        res.analyses.append(ar)
        if progress:
            line = summary_line(ar, res.timings[f"analysis_{k:03d}"])
            progress(f"{line}; {ignored_text(ignored)}" if ignored else line)
    t3 = now()
    # solve = its phases (poise.core.phases: evaluate, assemble, factorise) + the rest
    res.timings = dict(parse=t1 - t0, compile=t2 - t1, solve=t3 - t2,
                       **{f"solve_{k}": v for k, v in phases.snapshot().items()},
                       **res.timings)
    res.counts = counts
    return res


def run_deck(
    path: str,
    overrides: dict[str, Any] | None = None,
    command: str = "",
    progress: Callable[[str], None] | None = None,
    quiet: bool = False,
    allow_user_code: bool = False,
    ignore=(),
) -> RunResult:
    """Parse, compile and run every analysis of a deck.

    Parameters
    ----------
    path : str
        Deck file.
    overrides : dict, optional
        ``Param_Static`` (and later ``Param_Transient``) attribute overrides from the CLI, e.g.
        ``{"method": "FIM_S", "max_num_iter": 50, "max_imbalance": 1e-6, "stability": 1e-3}``.
        CLI values win over deck values, which win over defaults.
    command : str
        The command line, recorded in the results.
    progress : callable, optional
        Called with one summary line per finished analysis.
    quiet : bool
        No progress on stderr for long work (quasi-static frames, MKEAM iterations; otherwise
        a bar on a terminal, a plain line every 10 % or 10 s elsewhere, nothing with
        ``POISE_QUIET``: poise.core.progress).
    allow_user_code : bool
        Run the Python user routines the deck names (``script_name``). Default False: decks
        come from anywhere, so such a deck is an invalid deck (a located problem per element
        saying how to allow it). Scripts must lie inside the deck's directory tree either way.
    ignore : iterable of str
        Adams datasets (``.adm``/``.acf``): kinds of statements poise cannot solve (``CONTACT``,
        ``FRICTION``, ``USER``, ...) left out instead of refused; recorded in the results
        (root attribute ``ignored``) and on each analysis' summary line.

    Returns
    -------
    RunResult
        Always returned for a valid deck, converged or not.

    Raises
    ------
    poise.core.errors.DeckError
        Invalid deck (exit code 3).
    """
    check_override_names(overrides)          # before parsing: a typo is the caller's error
    with solver_progress(False if quiet else None):
        return run(path, overrides=overrides, command=command, progress=progress,
                   allow_user_code=allow_user_code, ignore=ignore)


def _analysis_models(spec: DeckSpec, model, analyses, compile_fn) -> list:
    """The model of each analysis: command versions of model elements met before a Simulate
    (``AnalysisRequest.commands``) apply to it and every later one (poise.model.commands),
    compiled with ``compile_fn`` (the same call that compiled ``model``). All are compiled
    before anything is solved, so a rejected command costs no solve."""
    out, cur_spec, cur = [], spec, model
    for req in analyses:
        if model_commands.model_commands(req.commands):
            cur_spec, cur = model_commands.recompile(model, cur_spec, req.commands, compile_fn)
        out.append(cur)
    return out


def run_spec(spec: DeckSpec, overrides=None, command: str = "", progress=None,
             allow_user_code: bool = False, quiet: bool = False, model=None) -> RunResult:
    """Run an already-parsed (possibly modified) :class:`DeckSpec`; same as :func:`run`."""
    with solver_progress(False if quiet else None):
        return run(spec, overrides=overrides, command=command, progress=progress,
                   allow_user_code=allow_user_code, model=model)


def _noloc(path):
    return SourceLoc(path, 0, "MotionSolve", None)


def summary_line(ar: AnalysisResult, seconds: float | None = None) -> str:
    """The one-line summary of an analysis (:func:`poise.results.summary.summary_line`)."""
    return _summary_line(summarize(ar), seconds=seconds)


__all__ = ["run", "run_deck", "run_spec", "plan", "STATUS_FAILED", "EvaluationError", "__version__"]
