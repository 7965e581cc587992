"""Solver settings: frozen, validated dataclasses; precedence defaults < deck < CLI.

The settings a deck can write take their names, defaults (static_methods.md: method FIM_D,
max_ke_tol 1e-5, max_dq_tol 1e-3, max_num_iter 100, max_imbalance 1e-4, max_error 1e-4,
stability 1e-10, compliance_delta 1e-3), bounds and choices from the ``Param_Static`` row of
the deck schema (:data:`PARAM_STATIC`, one declaration for the deck, the CLI and the API); the
others (steps, line search, fallback, stability requirements) are poise's own and declared here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import ClassVar

from poise.core.errors import UnknownOptionError
from poise.deck.schema import element_schema
from poise.solvers.compliance import parse_markers
from poise.solvers.limits import LIMITS, Limits

#: The ``Param_Static`` row of the deck schema: attribute name -> its declaration
PARAM_STATIC = dict(element_schema("Param_Static").attrs)
TOL_MIN = PARAM_STATIC["max_error"].lo      # smallest tolerance (poise.deck.schema.TOL_MIN)


def _deck(name: str):
    """The default the deck schema declares for ``Param_Static`` attribute ``name``."""
    return PARAM_STATIC[name].default


def compliance_methods() -> tuple:
    """The compliance methods (``Param_Static compliance_method``'s choices, lower case)."""
    return tuple(c.lower() for c in PARAM_STATIC["compliance_method"].choices)


@dataclass(frozen=True)
class StaticSettings:
    """``Param_Static``.

    Attributes
    ----------
    method : str
        ``MKEAM``, ``FIM_S`` or ``FIM_D``.
    max_ke_tol : float
        MKEAM: largest residual kinetic energy [energy units].
    max_dq_tol : float
        MKEAM: largest relative state change between iterations [-].
    max_num_iter : int
        Iteration cap; unmet tolerances when reached = failure.
    max_imbalance : float
        FIM: largest force imbalance [force units]; moment rows use ``max_imbalance * L``.
    max_error : float
        FIM: largest constraint violation / update [length units / L, radians].
    stability : float
        ``sqrt(stability) * M`` is added to the Jacobian only.
    compliance_delta : float
        Load perturbation of the ``fd`` compliance method [force units; torques x L].
    compliance_markers : str
        Markers of the compliance matrix (poise.solvers.compliance): ``none`` (default: the
        matrix is computed on request, as in MotionSolve), ``auto`` (every body's CG marker up
        to 100 bodies), ``all`` or marker ids (``"10 20"``).
    compliance_method : str
        ``exact`` (analytic KKT tangent) or ``fd`` (re-solve under ``compliance_delta``).
    max_translation_step : float
        Largest translation per Newton iteration as a multiple of the model size L [-].
    max_rotation_step : float
        Largest rotation per Newton iteration [rad] (applied in sub-steps, turns counted).
    line_search : bool
        Backtracking line search on the scaled residual norm.
    fallback : bool
        Run the fallback chain (solvers/fallback.py) when FIM_S fails (``--no-fallback``).
    fallback_max_num_iter : int or None
        Units of work the fallback chain may spend on one frame after plain Newton failed
        (Newton iterations, continuation steps, MKEAM integration and descent steps: each about
        one evaluation and factorisation); None: ``max_num_iter`` (``--fallback-budget``). A frame costs at most ``max_num_iter + fallback_max_num_iter``.
    require_stable : bool
        A static analysis succeeds only at a stable equilibrium (``--require-stable``): FIM_S
        leaves an unstable equilibrium along its negative modes and continues downhill
        (solvers/stable.py); an unstable end point is a failure (status ``unstable``).
    allow_neutral : bool
        With ``require_stable``: a neutral equilibrium (zero stiffness modes: free spins) counts
        as stable enough (``--allow-neutral`` / ``--no-allow-neutral``; default allowed).
    """

    method: str = _deck("method")
    max_ke_tol: float = _deck("max_ke_tol")
    max_dq_tol: float = _deck("max_dq_tol")
    max_num_iter: int = _deck("max_num_iter")
    max_imbalance: float = _deck("max_imbalance")
    max_error: float = _deck("max_error")
    stability: float = _deck("stability")
    compliance_delta: float = _deck("compliance_delta")
    compliance_markers: str = "none"       # the deck schema has no default for these two
    compliance_method: str = "exact"
    max_translation_step: float = 1.0
    max_rotation_step: float = 6.283185307179586 * 4
    line_search: bool = True
    fallback: bool = True
    fallback_max_num_iter: int | None = None
    require_stable: bool = False
    allow_neutral: bool = True
    #: the internal iteration caps (:mod:`poise.solvers.limits`): poise's own, not deck
    #: settings, so not a field (not written, not an override name)
    limits: ClassVar[Limits] = LIMITS

    def __post_init__(self):
        choices = PARAM_STATIC["method"].choices
        if self.method not in choices:
            raise ValueError(f"method must be one of {', '.join(choices)}, got {self.method!r}")
        for name in ("max_ke_tol", "max_dq_tol", "max_imbalance", "max_error", "stability",
                     "compliance_delta"):
            v, a = getattr(self, name), PARAM_STATIC[name]
            if not (math.isfinite(v) and _within(v, a)):
                raise ValueError(f"{name} must be a finite number {a.bounds_text()}, got {v!r}")
        object.__setattr__(self, "compliance_markers", parse_markers(self.compliance_markers))
        cm, cms = str(self.compliance_method).lower(), compliance_methods()
        if cm not in cms:
            raise ValueError(f"compliance_method must be one of {', '.join(cms)}, "
                             f"got {self.compliance_method!r}")
        object.__setattr__(self, "compliance_method", cm)
        for name in ("require_stable", "allow_neutral", "line_search", "fallback"):
            if not isinstance(getattr(self, name), (bool, int)) or isinstance(
                    getattr(self, name), float):
                raise ValueError(f"{name} must be true or false, got {getattr(self, name)!r}")
        a = PARAM_STATIC["max_num_iter"]
        if not _within(int(self.max_num_iter), a):
            raise ValueError(f"max_num_iter must be {a.bounds_text()}, got "
                             f"{self.max_num_iter!r}")
        if self.fallback_max_num_iter is not None and int(self.fallback_max_num_iter) < 0:
            raise ValueError(f"fallback_max_num_iter must be >= 0, got "
                             f"{self.fallback_max_num_iter!r}")

    @property
    def fallback_budget(self) -> int:
        """Units of work the fallback chain may spend on one frame."""
        b = self.fallback_max_num_iter
        return int(self.max_num_iter if b is None else b)

    def updated(self, values: dict) -> "StaticSettings":
        """A copy with ``values`` (Param_Static attribute names) applied; unknown keys ignored."""
        names = _FIELD_SET
        v = {}
        for k, val in values.items():
            k = k.lower()
            k = OVERRIDE_ALIASES.get(k, k)
            if k in names and val is not None:
                if k == "method":
                    val = str(val).upper()
                elif k in ("max_num_iter", "fallback_max_num_iter"):
                    val = int(val)
                elif k in ("require_stable", "allow_neutral") and isinstance(val, str):
                    low = val.strip().lower()
                    if low not in ("true", "false", "yes", "no", "1", "0"):
                        raise ValueError(f"{k} must be true or false, got {val!r}")
                    val = low in ("true", "yes", "1")
                v[k] = val
        return replace(self, **v) if v else self      # frozen: nothing to apply, no copy

    def as_dict(self) -> dict:
        """The fields by name (all plain values: no nested copies needed, unlike ``asdict``)."""
        return {name: getattr(self, name) for name in _FIELD_NAMES}


_FIELD_NAMES = tuple(f.name for f in fields(StaticSettings))
_FIELD_SET = frozenset(_FIELD_NAMES)


def _within(v, a) -> bool:
    """``v`` satisfies the bounds of the schema attribute ``a``."""
    if a.lo is not None and not (v > a.lo if a.lo_open else v >= a.lo):
        return False
    return a.hi is None or (v < a.hi if a.hi_open else v <= a.hi)


#: Override names accepted besides the field names (deck attribute aliases).
OVERRIDE_ALIASES = {alias: a.name for a in PARAM_STATIC.values() for alias in a.aliases}


def check_override_names(overrides, where: str = "solver option", also=()) -> None:
    """Raise :class:`poise.core.errors.UnknownOptionError` if a key of ``overrides`` is not a
    :class:`StaticSettings` field (case-insensitive, aliases allowed).

    The one check of override names behind every public entry (``solve``, ``run_deck``,
    ``batch``, ``sweep``): :meth:`StaticSettings.updated` ignores unknown keys, so a typo
    (``max_imbalanse``) would otherwise run at the deck's tolerances without a word. ``also``:
    the caller's other keyword names, offered as suggestions and listed.
    """
    if not overrides:
        return
    names = [f.name for f in fields(StaticSettings)]
    valid = set(names) | set(OVERRIDE_ALIASES)
    bad = [k for k in overrides if not (isinstance(k, str) and k.lower() in valid)]
    if not bad:
        return
    import difflib
    parts = []
    for k in bad:
        close = difflib.get_close_matches(str(k).lower(), sorted(valid | set(also)), n=1,
                                          cutoff=0.6)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        parts.append(f"{k!r}{hint}")
    s = "s" if len(bad) > 1 else ""
    raise UnknownOptionError(f"unknown {where}{s} {', '.join(parts)}; valid names: "
                             f"{', '.join([*names, *also])}")
