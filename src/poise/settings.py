"""Solver settings: frozen, validated dataclasses; precedence defaults < deck < CLI.

Defaults follow the specification (static_methods.md): method FIM_D, max_ke_tol 1e-5,
max_dq_tol 1e-3, max_num_iter 100, max_imbalance 1e-4, max_error 1e-4, stability 1e-10,
compliance_delta 1e-3.
"""
from __future__ import annotations

import math

from dataclasses import asdict, dataclass, fields, replace

METHODS = ("MKEAM", "FIM_S", "FIM_D")


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
    fallback_max_num_iter : int or None
        Iterations (Newton, continuation and MKEAM iterations together) the fallback chain may
        spend on one frame after plain Newton used its ``max_num_iter``; None: ``max_num_iter``
        (``--fallback-budget``). A frame costs at most ``max_num_iter + fallback_max_num_iter``.
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
    fallback_max_num_iter: int | None = None

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")
        for name in ("max_ke_tol", "max_dq_tol", "max_imbalance", "max_error"):
            v = getattr(self, name)
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
        if not (self.stability >= 0 and math.isfinite(self.stability)):
            raise ValueError(f"stability must be a finite number >= 0, got {self.stability!r}")
        if int(self.max_num_iter) < 1:
            raise ValueError(f"max_num_iter must be >= 1, got {self.max_num_iter!r}")
        if self.fallback_max_num_iter is not None and int(self.fallback_max_num_iter) < 0:
            raise ValueError(f"fallback_max_num_iter must be >= 0, got "
                             f"{self.fallback_max_num_iter!r}")

    @property
    def fallback_budget(self) -> int:
        """Iterations the fallback chain may spend on one frame."""
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
                v[k] = val
        return replace(self, **v)

    def as_dict(self) -> dict:
        return asdict(self)
