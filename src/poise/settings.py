"""Solver settings: frozen, validated dataclasses; precedence defaults < deck < CLI.

Defaults follow the specification (static_methods.md): method FIM_D, max_ke_tol 1e-5,
max_dq_tol 1e-3, max_num_iter 100, max_imbalance 1e-4, max_error 1e-4, stability 1e-10,
compliance_delta 1e-3.
"""
from __future__ import annotations

import math

from dataclasses import asdict, dataclass, fields, replace

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
        Perturbation for compliance computations.
    max_translation_step : float
        Largest translation per Newton iteration as a multiple of the model size L [-].
    max_rotation_step : float
        Largest rotation per Newton iteration [rad] (applied in sub-steps, turns counted).
    line_search : bool
        Backtracking line search on the scaled residual norm.
    fallback : bool
        Run the fallback chain (solvers/fallback.py) when FIM_S fails (``--no-fallback``).
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
    max_translation_step: float = 1.0
    max_rotation_step: float = 6.283185307179586 * 4
    line_search: bool = True
    fallback: bool = True
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
        for name in ("require_stable", "allow_neutral", "line_search", "fallback"):
            if not isinstance(getattr(self, name), (bool, int)) or isinstance(
                    getattr(self, name), float):
                raise ValueError(f"{name} must be true or false, got {getattr(self, name)!r}")
        if int(self.max_num_iter) < 1:
            raise ValueError(f"max_num_iter must be >= 1, got {self.max_num_iter!r}")

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
                elif k == "max_num_iter":
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
