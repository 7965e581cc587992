"""Solver settings: frozen, validated dataclasses; precedence defaults < deck < CLI.

Defaults follow the specification (static_methods.md): method FIM_D, max_ke_tol 1e-5,
max_dq_tol 1e-3, max_num_iter 100, max_imbalance 1e-4, max_error 1e-4, stability 1e-10,
compliance_delta 1e-3.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

from poise.core.errors import UnknownOptionError
from poise.solvers.compliance import METHODS as CM
from poise.solvers.compliance import parse_markers

METHODS = ("MKEAM", "FIM_S", "FIM_D")
TOL_MIN = 1e-100     # smallest tolerance (poise.deck.schema.TOL_MIN)


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

    method: str = "FIM_D"
    max_ke_tol: float = 1e-5
    max_dq_tol: float = 1e-3
    max_num_iter: int = 100
    max_imbalance: float = 1e-4
    max_error: float = 1e-4
    stability: float = 1e-10
    compliance_delta: float = 1e-3
    compliance_markers: str = "none"
    compliance_method: str = "exact"
    max_translation_step: float = 1.0
    max_rotation_step: float = 6.283185307179586 * 4
    line_search: bool = True
    fallback: bool = True
    fallback_max_num_iter: int | None = None
    require_stable: bool = False
    allow_neutral: bool = True

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")
        for name in ("max_ke_tol", "max_dq_tol", "max_imbalance", "max_error"):
            v = getattr(self, name)
            if not (v >= TOL_MIN and math.isfinite(v)):
                raise ValueError(f"{name} must be a finite number >= {TOL_MIN:g}, got {v!r}")
        if not (self.stability >= 0 and math.isfinite(self.stability)):
            raise ValueError(f"stability must be a finite number >= 0, got {self.stability!r}")
        if not (self.compliance_delta > 0 and math.isfinite(self.compliance_delta)):
            raise ValueError(f"compliance_delta must be a finite number > 0, got "
                             f"{self.compliance_delta!r}")
        object.__setattr__(self, "compliance_markers", parse_markers(self.compliance_markers))
        cm = str(self.compliance_method).lower()
        if cm not in CM:
            raise ValueError(f"compliance_method must be one of {', '.join(CM)}, "
                             f"got {self.compliance_method!r}")
        object.__setattr__(self, "compliance_method", cm)
        for name in ("require_stable", "allow_neutral", "line_search", "fallback"):
            if not isinstance(getattr(self, name), (bool, int)) or isinstance(
                    getattr(self, name), float):
                raise ValueError(f"{name} must be true or false, got {getattr(self, name)!r}")
        if int(self.max_num_iter) < 1:
            raise ValueError(f"max_num_iter must be >= 1, got {self.max_num_iter!r}")
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
        names = {f.name for f in fields(self)}
        v = {}
        for k, val in values.items():
            k = k.lower()
            if k == "max_residual":
                k = "max_error"
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
        return replace(self, **v)

    def as_dict(self) -> dict:
        return asdict(self)


#: Override names accepted besides the field names (deck attribute aliases).
OVERRIDE_ALIASES = {"max_residual": "max_error"}


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
