"""Public library API: run a deck, check a deck, solve, sweep (``poise.solve`` / ``poise.sweep``).

The CLI (``cli/poise_cli``) is a thin adapter over these functions.
"""
from __future__ import annotations

from poise.app.check import CheckReport, check
from poise.app.engine import WORKER_TIMEOUT
from poise.app.runner import run_deck, run_spec
from poise.deck.spec import DeckSpec
from poise.results.data import RunResult
from poise.solvers.settings import check_override_names

__all__ = ["CheckReport", "RunResult", "check_deck", "run_deck", "solve", "sweep"]


def check_deck(path: str, ignore=()) -> CheckReport:
    """Parse and compile a deck, detect redundant equations; no solve, and no deck code runs
    (user routines are reported in ``user_routines``, not imported). ``ignore``: kinds an
    Adams dataset leaves out instead of refusing them (``--ignore``)."""
    return check(path, ignore)


def solve(deck_or_path, allow_user_code: bool = False, ignore=(), **overrides) -> RunResult:
    """Convenience wrapper: ``poise.solve("deck.xml", method="FIM_S")``.

    ``deck_or_path`` is a deck path (str or path-like) or an already parsed (possibly modified)
    :class:`poise.deck.spec.DeckSpec` from ``poise.load_deck``. Keyword arguments are
    ``Param_Static`` overrides (``method``, ``max_num_iter``, ``max_imbalance``, ...), except
    ``allow_user_code`` and ``ignore`` (see :func:`run_deck`). An unknown keyword raises
    :class:`poise.core.errors.UnknownOptionError` (a ``TypeError``) naming the closest valid one; a
    DeckSpec is validated again exactly as its file would be (edits included).
    """
    check_override_names(overrides, "keyword argument", also=("allow_user_code", "ignore"))
    if isinstance(deck_or_path, DeckSpec):
        return run_spec(deck_or_path, overrides=overrides, command="poise.solve",
                        allow_user_code=allow_user_code)
    return run_deck(str(deck_or_path), overrides=overrides, command="poise.solve",
                    allow_user_code=allow_user_code, ignore=ignore)


def sweep(deck, sets: dict, mode: str = "grid", out_dir: str = "sweep", scheduler=None,
          outputs=(), n=None, seed=0, workers=None, overrides=None, force=False,
          allow_user_code: bool = False,
          worker_timeout: float | None = WORKER_TIMEOUT) -> list[dict]:
    """Parameter sweep on Dask distributed; returns the index rows (one dict per case).

    ``sets`` maps ``"Tag[id].attr"`` / ``"Tag.attr"`` to a list of values or a range string
    (``"10:100:10"``, ``"FIM_S,MKEAM"``); ``mode`` is ``grid``, ``zip`` or ``random`` (``n``
    cases, ``seed``). ``worker_timeout``: seconds without a Dask worker before giving up
    (:class:`poise.app.engine.NoWorkers`). See :func:`poise.app.sweep.run_sweep` for the rest.
    """
    check_override_names(overrides)
    from poise.app.sweep import run_sweep   # lazy: keeps `poise solve` start-up light
    return run_sweep(deck, sets, mode=mode, out_dir=out_dir, scheduler=scheduler,
                     outputs=outputs, n=n, seed=seed, workers=workers, overrides=overrides,
                     force=force, allow_user_code=allow_user_code,
                     worker_timeout=worker_timeout)
