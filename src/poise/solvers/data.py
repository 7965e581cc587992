"""Per-solve data: what a solve changes, kept off the read-only compiled model.

The compiled :class:`~poise.model.model.Model` is immutable (MuJoCo's ``mjModel``/``mjData``
split). A :class:`SolveData` carries the mutable part of one analysis: the active constraint-row
mask (redundant rows removed), the counters and the solve's
:class:`~poise.model.workspace.Workspace` (what evaluations keep between calls: assembly buffers,
tiled families, kernels' caches), and it is the one counted way to evaluate and
to factorise: :meth:`SolveData.evaluate` (residual, Jacobian,
deferred Jacobian, constraint values; one frame or many), :meth:`SolveData.jacobian` (a
deferred Jacobian assembled) and :meth:`SolveData.factor`. Every solver strategy (Newton,
continuation, the fallback chain, MKEAM, FIM_D, ``--require-stable``) goes through them, so
the totals written to ``/counts`` are counted in one place.
"""
from __future__ import annotations

import numpy as np

from poise.model.evaluate import evaluate as _engine
from poise.model.workspace import Workspace
from poise.solvers.linalg import Factor


class SolveData:
    """Active rows and counters of one solve.

    ``active``: (nc,) bool, or None (every row active). Counters: ``residuals``,
    ``jacobians``, ``factorizations`` (``as_dict()``), incremented only by :meth:`evaluate`,
    :meth:`jacobian` and :meth:`factor`. ``workspace``: the solve's, passed to every
    evaluation.
    """

    def __init__(self, active=None):
        self.active = None if active is None else np.array(active, bool)
        self.workspace = Workspace()
        self.residuals = 0
        self.jacobians = 0
        self.factorizations = 0
        # (state, StabilityInfo): a solution the solve has classified already (the output
        # reuses it for that very state object instead of classifying it again)
        self.classified = None
        # id(state) -> (state, StabilityInfo): the frames a path check classified (solvers/path)
        self.infos = {}

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

    # ------------------------------------------------------------------ counted work
    def evaluate(self, model, states, what="jacobian", *, eps=0.0, every_row=False,
                 residual=True):
        """Evaluate ``model`` at ``states`` (one State, or a sequence: frames) with the
        evaluation engine (:func:`poise.model.evaluate.evaluate`), counted per frame.

        ``what``: ``"residual"``, ``"jacobian"``, ``"phi_q"`` (its constraint blocks alone:
        counted as a Jacobian), ``"defer"`` (the Jacobian assembled later by
        :meth:`jacobian`, counted then) or ``"phi"`` (constraint values only, inactive rows 0;
        counted as a residual evaluation). ``eps``: mass multiple added to the Jacobian's
        coordinate block. ``every_row``: evaluate every constraint row, not only the active
        ones (one frame). ``residual=False``: the caller uses only the Jacobian (IDA's Jacobian
        callback), counted as a Jacobian evaluation only.
        """
        n = 1 if hasattr(states, "pos") else len(states)
        if residual:
            self.residuals += n
        if what in ("jacobian", "phi_q"):
            self.jacobians += n
        active = None if every_row else (self.mask(model) if what == "phi" else self.active)
        return _engine(model, states, what, active=active, eps_mass=eps,
                       workspace=self.workspace)

    def jacobian(self, model, ev):
        """The Jacobian of an evaluation made with ``what="defer"`` (assembled and counted on
        first use)."""
        if ev.J is None:
            self.jacobians += 1
            model.jacobian(ev)
        return ev.J

    def factor(self, J, factorise=None, *, equilibrate=False, count=1):
        """A counted factorisation of ``J``: ``factorise(J)`` (default
        :class:`~poise.solvers.linalg.Factor`, ``equilibrate`` passed on), its result
        returned. ``count``: matrices factorised (a stack of frames)."""
        self.factorizations += count
        if factorise is None:
            return Factor(J, equilibrate=equilibrate)
        return factorise(J)

    def as_dict(self):
        return dict(residuals=self.residuals, jacobians=self.jacobians,
                    factorizations=self.factorizations)
