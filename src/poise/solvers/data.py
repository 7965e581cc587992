"""Per-solve data: what a solve changes, kept off the read-only compiled model.

The compiled :class:`~poise.model.model.Model` is frozen after compile (MuJoCo's
``mjModel``/``mjData`` split). A :class:`SolveData` carries the mutable part of one analysis:
the active constraint-row mask (redundant rows removed), and the evaluation / Jacobian /
factorisation counters. Solvers pass it where they evaluate the model
(``model.evaluate(state, active=data.active)``).
"""
from __future__ import annotations

import numpy as np


class SolveData:
    """Active rows and counters of one solve.

    ``active``: (nc,) bool, or None (every row active). Counters: ``residuals``,
    ``jacobians``, ``factorizations`` (``as_dict()``).
    """

    def __init__(self, active=None):
        self.active = None if active is None else np.array(active, bool)
        self.residuals = 0
        self.jacobians = 0
        self.factorizations = 0
        # (state, StabilityInfo): a solution the solve has classified already (the output
        # reuses it for that very state object instead of classifying it again)
        self.classified = None

    @classmethod
    def for_model(cls, model, redundancy=()) -> "SolveData":
        """Data with every row of ``model`` active except the ``redundancy`` rows."""
        d = cls(np.ones(model.nc, bool))
        d.set_redundancy(redundancy)
        return d

    def set_redundancy(self, redundancy) -> None:
        """Rows ``redundancy`` inactive, every other row active."""
        self.active[:] = True
        self.active[np.asarray(redundancy, int)] = False

    def mask(self, model) -> np.ndarray:
        """The active-row mask (all rows when none was set)."""
        return np.ones(model.nc, bool) if self.active is None else self.active

    def as_dict(self):
        return dict(residuals=self.residuals, jacobians=self.jacobians,
                    factorizations=self.factorizations)
