"""Public library API: run a deck, check a deck.

The CLI (``cli/poise_cli``) is a thin adapter over these functions.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

from poise.results.data import RunResult


@dataclass
class CheckReport:
    """What ``poise check`` prints: the compiled model without solving.

    Attributes
    ----------
    deck : str
    bodies : list[dict]
        One dict per body: ``id``, ``label``, ``kind`` (``rigid``/``point``/``ground``), ``mass``.
    constraints : list[dict]
        One dict per constraint element: ``tag``, ``id``, ``type``, ``n_equations``, ``line``.
    forces : list[dict]
        One dict per force element: ``tag``, ``id``, ``type``, ``line``.
    n_coordinates : int
        Number of tangent coordinates (6 per rigid body, 3 per point body, + extra unknowns).
    n_equations : int
        Number of constraint equations before redundancy removal.
    n_redundant : int
    dof : int or None
        Degrees of freedom = n_coordinates - rank of the constraint Jacobian; ``None`` when the
        deck has user constraints (``Constraint_UserConstr``): their number of equations is known
        only by running their routine, which ``check`` never does.
    dof_without_user_constraints : int or None
        The degrees of freedom of the model without its user constraints (an upper bound), when
        ``dof`` is ``None``.
    user_routines : list[dict]
        Elements given by Python user routines: ``tag``, ``id``, ``script``, ``function``,
        ``line``. ``check`` validates the reference (inside the deck's directory) but never
        imports the script; the elements are left out of the compiled model.
    redundant : list[dict]
        Removed equations: ``tag``, ``id``, ``equation`` (e.g. ``"rot_x"``), ``line``.
    active_effects : list[str]
    warnings : list[str]
    analyses : list[dict]
        One dict per Simulate: ``analysis_type``, ``method``, ``n_frames``.
    """

    deck: str
    bodies: list = field(default_factory=list)
    constraints: list = field(default_factory=list)
    forces: list = field(default_factory=list)
    n_coordinates: int = 0
    n_equations: int = 0
    n_redundant: int = 0
    dof: int | None = 0
    redundant: list = field(default_factory=list)
    active_effects: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    analyses: list = field(default_factory=list)
    user_routines: list = field(default_factory=list)
    dof_without_user_constraints: int | None = None


def run_deck(
    path: str,
    overrides: dict[str, Any] | None = None,
    command: str = "",
    progress: Callable[[str], None] | None = None,
    quiet: bool = False,
    allow_user_code: bool = False,
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
        No progress bar on stderr for long quasi-static runs (otherwise shown only when stderr
        is a terminal, outside CI and with ``POISE_QUIET`` unset).
    allow_user_code : bool
        Run the Python user routines the deck names (``script_name``). Default False: decks
        come from anywhere, so such a deck is an invalid deck (a located problem per element
        saying how to allow it). Scripts must lie inside the deck's directory tree either way.

    Returns
    -------
    RunResult
        Always returned for a valid deck, converged or not.

    Raises
    ------
    poise.errors.DeckError
        Invalid deck (exit code 3).
    """
    from poise.runner import run
    from poise.solvers.quasistatic import progress_bar
    with progress_bar(False if quiet else None):
        return run(path, overrides=overrides, command=command, progress=progress,
                   allow_user_code=allow_user_code)


def check_deck(path: str) -> CheckReport:
    """Parse and compile a deck, detect redundant equations; no solve, and no deck code runs
    (user routines are reported in ``user_routines``, not imported)."""
    from poise.runner import check
    return check(path)


def solve(deck_or_path, allow_user_code: bool = False, **overrides) -> RunResult:
    """Convenience wrapper: ``poise.solve("deck.xml", method="FIM_S")``.

    ``deck_or_path`` is a deck path (str or path-like) or an already parsed (possibly modified)
    :class:`poise.deck.spec.DeckSpec` from ``poise.load_deck``. Keyword arguments are
    ``Param_Static`` overrides (``method``, ``max_num_iter``, ``max_imbalance``, ...), except
    ``allow_user_code`` (see :func:`run_deck`).
    """
    from poise.deck.spec import DeckSpec
    if isinstance(deck_or_path, DeckSpec):
        from poise.runner import run_spec
        return run_spec(deck_or_path, overrides=overrides, command="poise.solve",
                        allow_user_code=allow_user_code)
    return run_deck(str(deck_or_path), overrides=overrides, command="poise.solve",
                    allow_user_code=allow_user_code)


def sweep(deck, sets: dict, mode: str = "grid", out_dir: str = "sweep", scheduler=None,
          outputs=(), n=None, seed=0, workers=None, overrides=None, force=False,
          allow_user_code: bool = False) -> list[dict]:
    """Parameter sweep on Dask distributed; returns the index rows (one dict per case).

    ``sets`` maps ``"Tag[id].attr"`` / ``"Tag.attr"`` to a list of values or a range string
    (``"10:100:10"``, ``"FIM_S,MKEAM"``); ``mode`` is ``grid``, ``zip`` or ``random`` (``n``
    cases, ``seed``). See :func:`poise.sweep.run_sweep` for everything else.
    """
    from poise.sweep import run_sweep
    return run_sweep(deck, sets, mode=mode, out_dir=out_dir, scheduler=scheduler,
                     outputs=outputs, n=n, seed=seed, workers=workers, overrides=overrides,
                     force=force, allow_user_code=allow_user_code)
