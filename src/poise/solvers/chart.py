"""FIM_D's chart (unknowns relative to a reference state) and the output-frame corrector.

:class:`Chart` maps IDA's unknowns ``y`` (CG translations and rotation vectors relative to a
reference state, then the multipliers) to states, provides IDA's residual and Jacobian
callbacks and a consistent start (its chord-Newton polish a :class:`StartPolish`); the
output points are brought onto the equilibrium by solvers/correct.py. Notes: docs/fim_d.md.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np

from poise.core.errors import EvaluationError
from poise.elements.rotation import expm_so3, se3_left_jacobian, wrap_angle
from poise.model.model import State, principal_angles
from poise.solvers.iterate import Next, Solver, iterate
from poise.solvers.limits import LIMITS
from poise.solvers.status import Status

START_POLISH = 1e-3       # a (re)start's correction below this (weighted RMS norm): polished


class Chart:
    """The map y -> State around a reference state, its Jacobian factor, and IDA callbacks."""

    def __init__(self, model, ref, eps, counters, sparse=None, tol=1e-6):
        self.model = model
        self.tol = tol
        self.ref = ref.copy()
        self.eps = eps
        self.cnt = counters
        self.sparse = sparse            # SparseJacobian, or None: dense
        self.stats = None               # IdaStats of the current IDA instance (set by run_ida)
        self.conv_coef_set = False      # NONLIN_CONV_COEF applied to that instance (by run_ida)
        self.trial_times = set()
        self.held = None                # a factorisation of dF/dy in this chart (Corrector)

    def state(self, y, t):
        m, ref = self.model, self.ref
        st = ref.copy()
        st.t = float(t)
        st.pos = ref.pos + y[m.trans_idx].reshape(-1, 3)
        if len(m.rot_idx):
            w = y[m.rot_idx].reshape(-1, 3)
            st.rot[m.rot_body] = np.matmul(expm_so3(w), ref.rot[m.rot_body])
            m.track_rotation(st, ref, w)
        st.lam = np.array(y[m.nq:], float)
        if m.n_extra:                   # scalar unknowns: algebraic, y = extra - ref.extra
            st.extra = ref.extra + y[m.extra_idx]
        if len(m.angle_I):
            p = m._principal_angles(st)
            st.angle = ref.angle + wrap_angle(p - ref.angle)
        return st

    def states(self, Y, T):
        """:meth:`state` of many points ``Y`` (F, N) at times ``T`` (F,): the rotations of every
        frame in one ``expm_so3`` call and the continuous angles in one pass."""
        m, ref = self.model, self.ref
        F_ = len(Y)
        pos = ref.pos[None] + Y[:, m.trans_idx].reshape(F_, -1, 3)
        rot = np.repeat(ref.rot[None], F_, axis=0)
        if len(m.rot_idx):
            E = expm_so3(Y[:, m.rot_idx].reshape(-1, 3)).reshape(F_, -1, 3, 3)
            rot[:, m.rot_body] = np.matmul(E, ref.rot[m.rot_body][None])
        ang = np.repeat(ref.angle[None], F_, axis=0)
        if len(m.angle_I):
            rx = np.concatenate([rot, np.broadcast_to(np.eye(3), (F_, 1, 3, 3))], axis=1)
            A = np.matmul(rx[:, m.marker_body], m.marker_A0)                # (F, nm, 3, 3)
            p = principal_angles(A, m.angle_I, m.angle_J, m.angle_axis)
            ang = ref.angle[None] + wrap_angle(p - ref.angle[None])
        out = []
        for k in range(F_):
            st = State(pos[k], rot[k], np.array(Y[k, m.nq:], float), ang[k], float(T[k]),
                       None if ref.extra is None else ref.extra.copy())
            if m.n_extra:
                st.extra = ref.extra + Y[k, m.extra_idx]
            out.append(st)
        return out

    def max_rotation(self, y):
        m = self.model
        if not len(m.rot_idx):
            return 0.0
        return float(np.max(np.linalg.norm(y[m.rot_idx].reshape(-1, 3), axis=1)))

    def F(self, st):
        ev = self.cnt.evaluate(self.model, st, "residual")
        return np.concatenate([ev.r, ev.phi])

    def jac(self, y, t):
        """``dF/dy``: dense ndarray, or the CSC data on ``self.sparse``'s pattern."""
        m = self.model
        st = self.state(y, t)
        ev = self.cnt.evaluate(m, st, "jacobian", eps=self.eps, residual=False)
        if self.sparse is not None:
            return self.sparse.values(ev.J, y[m.rot_idx].reshape(-1, 3))
        J = ev.J.toarray() if hasattr(ev.J, "toarray") else np.array(ev.J)
        if len(m.rot_idx):
            w = y[m.rot_idx].reshape(-1, 3)
            Jl = se3_left_jacobian(w)
            Jr = J[:, m.rot_idx].reshape(J.shape[0], -1, 3)
            J[:, m.rot_idx] = np.einsum("nbi,bij->nbj", Jr, Jl).reshape(J.shape[0], -1)
        return J

    # IDA callbacks
    def resfn(self, t, y, yp, res):
        self.trial_times.add(float(t))
        try:
            res[:] = self.F(self.state(y, t))
        except EvaluationError:
            res[:] = 1e30

    def jacfn(self, t, y, yp, res, cj, JJ):
        try:
            JJ[:, :] = self.jac(y, t)
        except EvaluationError:
            JJ[:, :] = np.eye(len(y))

    def jacfn_sparse(self, t, y, yp, res, cj, JJ):
        """``JJ``: the CSC data (1-D, pattern ``self.sparse.pattern()``)."""
        try:
            JJ[:] = self.jac(y, t)
        except EvaluationError:
            JJ[:] = self.sparse.identity()

    def factor(self, y, t):
        """Solver for ``dF/dy`` at (y, t): a callable b -> F_y^{-1} b."""
        return self.cnt.factor(self.jac(y, t), self._lu)

    def _lu(self, J):
        """``b -> J^{-1} b``: SuperLU on the sparse pattern, else LAPACK's LU."""
        if self.sparse is not None:
            import scipy.sparse.linalg as spla
            return spla.splu(self.sparse.matrix(J), permc_spec="COLAMD").solve
        import scipy.linalg as sla
        with warnings.catch_warnings():
            warnings.simplefilter("error", sla.LinAlgWarning)   # singular: LinAlgError below
            try:
                lu = sla.lu_factor(J)
            except sla.LinAlgWarning as e:
                raise np.linalg.LinAlgError(str(e)) from None
        return lambda b: sla.lu_solve(lu, b)

    def start(self, y, t, dt_scale, weight, span, want_h0=True):
        """Consistent start of an IDA run at (y, t): ``(y0, y0', h0)``.

        * ``y0``: ``y`` polished by chord-Newton on ``F(y, t) = 0`` (:class:`StartPolish`: at
          most ``limits.start_newton`` corrections, until the correction is below
          ``START_POLISH`` in the weighted RMS norm ``weight`` = IDA's error weights). A rebase restarts from IDA's last corrector, which
          met IDA's convergence test in the old chart's weights only; left as it is, that
          remainder is the first step's local error (see the module notes).
        * ``y0' = -F_y^{-1} F_t`` (``F_t`` by central differences in t).
        * ``h0``: first step from the path's curvature, ``y'' = -F_y^{-1} d2F/ds2`` along
          ``(y0', 1)`` (second central difference), ``h0 = 1 / sqrt(||y''||)`` in the same
          weighted norm: the order-1 local error ``h^2 |y''| / 2`` is then about half a tolerance
          unit. 0 when the estimate is not usable (IDA then uses its own) or not wanted.
        Cost: one Jacobian and 5-7 residuals (3 fewer without ``h0``). Any linear-algebra
        failure gives ``(y, 0, 0)``.
        """
        n = len(y)
        try:
            solve = self.factor(y, t)
            self.held = solve                   # kept for the output-frame corrections
            y, status = iterate(StartPolish(self, solve, t, weight), LIMITS.start_newton,
                                (), np.array(y, float))
            if status is Status.NONFINITE:
                raise np.linalg.LinAlgError
            h = 1e-6 * max(1.0, abs(t), dt_scale)
            Ft = (self.F(self.state(y, t + h)) - self.F(self.state(y, t - h))) / (2 * h)
            yp = solve(-Ft)
            if not np.all(np.isfinite(yp)):
                raise np.linalg.LinAlgError
        except (np.linalg.LinAlgError, RuntimeError, ValueError, EvaluationError):
            return np.asarray(y, float), np.zeros(n), 0.0
        h0 = 0.0
        if not want_h0:
            return y, yp, h0
        try:
            # path parameter step: a 1e-3 part of the span, and at most 1e-3 of the model's
            # scales per coordinate (y' / weight, in tolerance units, times the tolerance)
            rate = float(np.max(np.abs(yp) * weight)) * self.tol
            d = min(1e-3 * span, 1e-3 / rate) if rate > 0 else 1e-3 * span
            g = (self.F(self.state(y + d * yp, t + d)) - 2.0 * self.F(self.state(y, t))
                 + self.F(self.state(y - d * yp, t - d))) / (d * d)
            ypp = solve(-g)
            c = float(np.sqrt(np.mean((ypp * weight) ** 2)))
            if np.isfinite(c) and c > 0:
                h0 = 1.0 / np.sqrt(c)
        except (np.linalg.LinAlgError, RuntimeError, ValueError, EvaluationError):
            pass
        return y, yp, h0


@dataclass(frozen=True)
class Polishing:
    """Where a :class:`StartPolish` stands: the point ``y``, ``done`` once the correction
    fell below ``START_POLISH``."""

    y: np.ndarray
    done: Status | None = None


class StartPolish(Solver):
    """Chord-Newton on ``F(y, t) = 0`` with the factorisation ``solve`` (``b -> F_y^-1 b``)
    until the correction is below ``START_POLISH`` in the weighted RMS norm ``weight``; a
    correction that cannot be computed, or is not finite, ends it ``nonfinite`` at the last
    point. Budget: corrections. Result: ``(y, status)``."""

    def __init__(self, chart, solve, t, weight):
        self.chart, self.solve, self.t, self.weight = chart, solve, t, weight

    def init(self, y):
        return Polishing(y)

    def terminate(self, s):
        return s.done is not None, s.done

    def step(self, s, left):
        try:
            dy = self.solve(-self.chart.F(self.chart.state(s.y, self.t)))
        except (np.linalg.LinAlgError, RuntimeError, ValueError, EvaluationError):
            dy = None
        if dy is None or not np.all(np.isfinite(dy)):
            return Next(replace(s, done=Status.NONFINITE), 0)
        small = np.sqrt(np.mean((dy * self.weight) ** 2)) <= START_POLISH
        return Next(Polishing(s.y + dy, Status.CONVERGED if small else None))

    def postprocess(self, s, status, used):
        return s.y, status
