"""Public library API: run a deck, check a deck, solve, sweep (``poise.solve`` / ``poise.sweep``).

The CLI (``cli/poise_cli``) is a thin adapter over these functions. ``solve`` lists every
``Param_Static`` option as a keyword argument (a test keeps the list equal to
:class:`poise.solvers.settings.StaticSettings`), so a notebook shows them.
"""
from __future__ import annotations

from poise.app.check import CheckReport, check
from poise.app.engine import WORKER_TIMEOUT
from poise.app.runner import run_deck, run_spec
from poise.core.errors import require_file
from poise.deck.parser import load_deck as _load_deck
from poise.deck.spec import DeckSpec
from poise.results.data import RunResult
from poise.solvers.settings import check_override_names

__all__ = ["CheckReport", "RunResult", "check_deck", "load_deck", "run_deck", "solve", "sweep"]


def check_deck(path, ignore=()) -> CheckReport:
    """Parse and compile a deck, detect redundant equations; no solve, and no deck code runs
    (user routines are reported in ``user_routines``, not imported). ``ignore``: kinds an
    Adams dataset leaves out instead of refusing them (``--ignore``). A missing file raises
    ``FileNotFoundError``."""
    if not isinstance(path, DeckSpec):
        require_file(path, "deck")
    return check(path, ignore)


def load_deck(path) -> DeckSpec:
    """Parse and validate the deck at ``path`` into a :class:`DeckSpec` (edit its elements'
    ``attrs``, then ``poise.solve(spec)``). A missing file raises ``FileNotFoundError``; an
    invalid deck :class:`poise.core.errors.DeckError` with every located problem."""
    require_file(path, "deck")
    return _load_deck(str(path))


def solve(deck, *, method: str | None = None, max_num_iter: int | None = None,
          max_imbalance: float | None = None, max_error: float | None = None,
          stability: float | None = None, max_ke_tol: float | None = None,
          max_dq_tol: float | None = None, max_translation_step: float | None = None,
          max_rotation_step: float | None = None, line_search: bool | None = None,
          fallback: bool | None = None, fallback_max_num_iter: int | None = None,
          require_stable: bool | None = None, allow_neutral: bool | None = None,
          compliance_markers=None, compliance_method: str | None = None,
          compliance_delta: float | None = None, allow_user_code: bool = False,
          ignore=(), quiet: bool = False, **param_static) -> RunResult:
    """Solve every analysis of a deck and return the :class:`RunResult` (nothing written:
    ``poise.results.hdf5.write_results(result, "out.h5")``).

    ``deck``: a deck path, or a parsed (possibly edited) :class:`DeckSpec` from
    :func:`load_deck`, validated again exactly as its file would be (an unknown attribute name
    in ``attrs`` is an error). The options override the deck's ``Param_Static``; ``None``
    keeps the deck's value (else poise's default):

    * ``method``: ``"FIM_S"`` (Newton), ``"FIM_D"`` (quasi-static DAE; default) or
      ``"MKEAM"``; ``max_num_iter``: iteration cap per frame.
    * ``max_imbalance`` [force units; moments ×L], ``max_error`` [length/L, rad]: convergence
      tolerances; ``max_ke_tol``, ``max_dq_tol``: MKEAM's.
    * ``stability``: ``sqrt(stability)·M`` added to the Newton Jacobian only.
    * ``max_translation_step`` (×L), ``max_rotation_step`` [rad], ``line_search``: Newton
      step control; ``fallback``, ``fallback_max_num_iter``: the recovery chain and its budget.
    * ``require_stable``, ``allow_neutral``: succeed only at a stable (or neutral) equilibrium.
    * ``compliance_markers``: the compliance matrix's markers (``"none"``, the default;
      ``"all"``: every body's CG marker; ``"auto"``; or marker ids ``[10, 20]``),
      ``compliance_method`` ``"exact"``/``"fd"``, ``compliance_delta`` (``fd``'s load).
    * ``allow_user_code``: run the deck's Python user routines (default: refuse such a deck).
    * ``ignore``: kinds of Adams statements left out instead of refused (``--ignore``).
    * ``quiet``: no progress output on stderr.

    Other ``Param_Static`` attribute names (case-insensitive, e.g. ``max_residual``) go in
    ``param_static``; an unknown name raises :class:`poise.core.errors.UnknownOptionError` (a
    ``TypeError``) naming the closest valid one. A missing deck file raises
    ``FileNotFoundError``; an invalid deck :class:`poise.core.errors.DeckError`.
    """
    named = dict(method=method, max_num_iter=max_num_iter, max_imbalance=max_imbalance,
                 max_error=max_error, stability=stability, max_ke_tol=max_ke_tol,
                 max_dq_tol=max_dq_tol, max_translation_step=max_translation_step,
                 max_rotation_step=max_rotation_step, line_search=line_search,
                 fallback=fallback, fallback_max_num_iter=fallback_max_num_iter,
                 require_stable=require_stable, allow_neutral=allow_neutral,
                 compliance_markers=compliance_markers, compliance_method=compliance_method,
                 compliance_delta=compliance_delta)
    check_override_names(param_static, "keyword argument", also=("allow_user_code", "ignore",
                                                                         "quiet"))
    overrides = {**param_static, **{k: v for k, v in named.items() if v is not None}}
    if isinstance(overrides.get("compliance_markers"), (list, tuple)):
        overrides["compliance_markers"] = " ".join(str(int(m)) for m in
                                                   overrides["compliance_markers"])
    if isinstance(deck, DeckSpec):
        return run_spec(deck, overrides=overrides, command="poise.solve",
                        allow_user_code=allow_user_code, quiet=quiet)
    require_file(deck, "deck")
    more = {"ignore": ignore} if ignore else {}      # Adams datasets only
    return run_deck(str(deck), overrides=overrides, command="poise.solve", quiet=quiet,
                    allow_user_code=allow_user_code, **more)


def sweep(deck, sets: dict, mode: str = "grid", out_dir: str = "sweep", scheduler=None,
          outputs=(), n=None, seed=0, workers=None, overrides=None, force=False,
          allow_user_code: bool = False, client=None,
          worker_timeout: float | None = WORKER_TIMEOUT, ignore=()) -> list[dict]:
    """Parameter sweep on Dask distributed; returns the index rows (one dict per case).

    ``sets`` maps ``"Tag[id].attr"`` / ``"Tag.attr"`` to a list of values or a range string
    (``"10:100:10"``, ``"FIM_S,MKEAM"``); ``mode`` is ``grid``, ``zip`` or ``random`` (``n``
    cases, ``seed``). ``client``: an existing ``dask.distributed.Client`` to run on
    (``scheduler`` and ``workers`` are then ignored); otherwise ``scheduler`` (an address) or
    a local cluster of ``workers`` processes. ``overrides``: solver options for every case
    (the names of :func:`solve`'s). ``worker_timeout``: seconds without a Dask worker before
    giving up (:class:`poise.app.engine.NoWorkers`). ``ignore``: kinds of Adams statements
    left out instead of refused (``--ignore``). See :func:`poise.app.sweep.run_sweep`.
    """
    check_override_names(overrides)
    require_file(deck, "deck")
    from poise.app.sweep import run_sweep   # lazy: keeps `poise solve` start-up light
    return run_sweep(deck, sets, mode=mode, out_dir=out_dir, scheduler=scheduler,
                     outputs=outputs, n=n, seed=seed, workers=workers, overrides=overrides,
                     force=force, allow_user_code=allow_user_code, client=client,
                     worker_timeout=worker_timeout, **({"ignore": ignore} if ignore else {}))
