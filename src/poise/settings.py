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
        Load perturbation of the ``fd`` compliance method [force units; torques x L].
    compliance_markers : str
        Markers of the compliance matrix (poise.solvers.compliance): ``auto`` (every body's CG
        marker up to 100 bodies), ``all``, ``none`` or marker ids (``"10 20"``).
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
    """

    method: str = "FIM_D"
    max_ke_tol: float = 1e-5
    max_dq_tol: float = 1e-3
    max_num_iter: int = 100
    max_imbalance: float = 1e-4
    max_error: float = 1e-4
    stability: float = 1e-10
    compliance_delta: float = 1e-3
    compliance_markers: str = "auto"
    compliance_method: str = "exact"
    max_translation_step: float = 1.0
    max_rotation_step: float = 6.283185307179586 * 4
    line_search: bool = True
    fallback: bool = True

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")
        for name in ("max_ke_tol", "max_dq_tol", "max_imbalance", "max_error"):
            v = getattr(self, name)
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
        if not (self.stability >= 0 and math.isfinite(self.stability)):
            raise ValueError(f"stability must be a finite number >= 0, got {self.stability!r}")
        if not (self.compliance_delta > 0 and math.isfinite(self.compliance_delta)):
            raise ValueError(f"compliance_delta must be a finite number > 0, got "
                             f"{self.compliance_delta!r}")
        from poise.solvers.compliance import METHODS as CM, parse_markers
        object.__setattr__(self, "compliance_markers", parse_markers(self.compliance_markers))
        cm = str(self.compliance_method).lower()
        if cm not in CM:
            raise ValueError(f"compliance_method must be one of {', '.join(CM)}, "
                             f"got {self.compliance_method!r}")
        object.__setattr__(self, "compliance_method", cm)
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
                v[k] = val
        return replace(self, **v)

    def as_dict(self) -> dict:
        return asdict(self)
