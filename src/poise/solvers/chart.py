"""FIM_D's chart (unknowns relative to a reference state) and the output-frame corrector.

:class:`Chart` maps IDA's unknowns ``y`` (CG translations and rotation vectors relative to a
reference state, then the multipliers) to states, provides IDA's residual and Jacobian
callbacks and a consistent start; :class:`Corrector` brings IDA's output points onto the
equilibrium to the ``Param_Static`` tolerances. Notes: docs/fim_d.md.
"""
from __future__ import annotations

import warnings

import numpy as np

from poise.core.errors import EvaluationError
from poise.elements.rotation import expm_so3, se3_left_jacobian, wrap_angle
from poise.model.frame_batch import batchable
from poise.model.model import State, principal_angles
from poise.solvers.newton import Scales

START_NEWTON = 3          # chord-Newton corrections of a (re)start point, at most
START_POLISH = 1e-3       # ... until the correction is below this (weighted RMS norm)
CORRECT_MAX_ITER = 4      # simplified-Newton corrections of an output frame, at most
CORRECT_RATE = 0.25       # contraction slower than this: refactorise at the frame (once a frame)


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

    def _factor(self, y, t):
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

        * ``y0``: ``y`` polished by chord-Newton on ``F(y, t) = 0`` (at most ``START_NEWTON``
          corrections, until the correction is below ``START_POLISH`` in the weighted RMS norm
          ``weight`` = IDA's error weights). A rebase restarts from IDA's last corrector, which
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
            solve = self._factor(y, t)
            self.held = solve                   # kept for the output-frame corrections
            y = np.array(y, float)
            for _ in range(START_NEWTON):
                dy = solve(-self.F(self.state(y, t)))
                if not np.all(np.isfinite(dy)):
                    raise np.linalg.LinAlgError
                y = y + dy
                if np.sqrt(np.mean((dy * weight) ** 2)) <= START_POLISH:
                    break
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


class Corrector:
    """Brings IDA's output points onto the equilibrium, to the ``Param_Static`` tolerances.

    IDA's interpolant (or corrector, with ``dae_interpolation`` FALSE) meets IDA's local error
    test, not ``max_imbalance`` / ``max_error``: on ``decks/bench/slider_crank_qs_1000.xml`` the
    output frames were up to 0.013 N off against 1e-8. The output points passed by one IDA step
    are corrected together (:meth:`batch`): Newton corrections in the chart's coordinates,
    ``y <- y - F_y(y_0)^{-1} F(y, t)``, with each frame's Jacobian taken once at its
    interpolated point (one batched residual + Jacobian evaluation,
    :func:`~poise.model.evaluate.evaluate`), then one batched residual and one
    stacked back-substitution per further correction. A frame is accepted when its residual
    meets the FIM_S scales (force rows ``max_imbalance``, moment rows ``max_imbalance * L``,
    constraint rows ``max_error`` (x L)) and the next correction — its error estimate — is
    ``<= max_error`` (translations / L, rotations in rad); that correction is applied, so the
    error reported bounds the error of the point written. Frames still off after
    ``CORRECT_MAX_ITER`` corrections, or models that are not batched, go through :meth:`one`:
    simplified Newton with a factorisation held per chart (refactorised at the frame when the
    contraction is slower than ``CORRECT_RATE``); the caller runs a full Newton (FIM_S) on a
    frame that still fails. ``stats``: frames, corrections, residual evaluations,
    factorisations, full-Newton fallbacks and the wall time spent here; its residuals and
    factorisations are the part of the solve's counters (``data``, through which every
    evaluation and factorisation here goes) spent in the corrections.
    """

    def __init__(self, model, settings, data):
        self.model = model
        self.data = data
        self.active = np.asarray(data.mask(model), bool)   # the solve's active constraint rows
        self.sc = Scales(model, settings)
        self.max_error = settings.max_error
        self.chart = None
        self.solve = None
        self.stats = dict(frames=0, corrections=0, residuals=0, factorisations=0, newton=0,
                          seconds=0.0)

    # ------------------------------------------------------------------ measures
    def _z(self, F):
        """Tolerance-scaled infinity norm of residual rows ``F`` (..., N)."""
        nq = self.model.nq
        zr = np.abs(F[..., :nq]) / self.sc.r_tol
        zp = np.abs(F[..., nq:]) / self.sc.phi_tol
        return np.maximum(zr.max(axis=-1, initial=0.0), zp.max(axis=-1, initial=0.0))

    def _err(self, dy):
        return np.max(np.abs(dy[..., :self.model.nq]) / self.sc.q_len, axis=-1, initial=0.0)

    # ------------------------------------------------------------------ batched
    def batch(self, chart, Y, T):
        """Correct the output points ``Y`` (F, N) at times ``T`` (F,). Returns ``(Y, iterations
        (F,), error estimates (F,), ok (F,))``."""
        import time as _t
        m = self.model
        Y = np.array(Y, float)
        F_ = len(Y)
        its = np.zeros(F_, int)
        errs = np.full(F_, np.nan)
        ok = np.zeros(F_, bool)
        if not F_:
            return Y, its, errs, ok
        t0 = _t.perf_counter()
        st, data = self.stats, self.data
        st["frames"] += F_
        done = False
        if batchable(m):
            saved = self.active
            inact = np.nonzero(~saved)[0] + m.nq
            counted = data.residuals, data.factorizations
            try:
                ev = data.evaluate(m, chart.states(Y, T), "jacobian")
                Fv = np.concatenate([ev.r, np.where(saved, ev.phi, 0.0)], axis=1)
                J = data.factor(self._chart_jacobian(ev.J, Y, inact), _Stacked, count=F_)
                live = np.arange(F_)
                for it in range(CORRECT_MAX_ITER + 1):
                    dy = J.solve(live, -Fv[live])
                    if not np.all(np.isfinite(dy)):
                        raise np.linalg.LinAlgError("non-finite correction")
                    e = self._err(dy)
                    good = (self._z(Fv[live]) <= 1.0) & (e <= self.max_error)
                    errs[live], its[live], ok[live[good]] = e, it, True
                    # the last correction is applied too: its size, the error reported,
                    # bounds the error of the point written (Newton: second order smaller)
                    Y[live[good]] += dy[good]
                    its[live[good]] += 1
                    st["corrections"] += int(good.sum())
                    live, dy = live[~good], dy[~good]
                    if not live.size or it == CORRECT_MAX_ITER:
                        break
                    Y[live] += dy
                    st["corrections"] += live.size
                    ev = data.evaluate(m, chart.states(Y[live], T[live]), "residual")
                    Fv[live] = np.concatenate([ev.r, np.where(saved, ev.phi, 0.0)], axis=1)
                done = True
            except (np.linalg.LinAlgError, EvaluationError, ValueError):
                pass
            st["residuals"] += data.residuals - counted[0]
            st["factorisations"] += data.factorizations - counted[1]
        if not done:
            ok[:], its[:] = False, 0
        st["seconds"] += _t.perf_counter() - t0
        for k in np.nonzero(~ok)[0]:
            y, n, e, good = self.one(chart, Y[k], T[k])
            Y[k], its[k], errs[k], ok[k] = y, its[k] + n, e, good
        return Y, its, errs, ok

    def _chart_jacobian(self, J, Y, inact):
        """``dF/dy`` of each frame from its KKT Jacobian (F, N, N) at the chart point: the
        rotation columns times the left Jacobian of SO(3) (as :meth:`Chart.jac`), redundant
        rows as in :meth:`Model.jacobian` (identity on their multiplier, no coupling)."""
        m = self.model
        J = np.array(J, float)
        if len(m.rot_idx):
            F_, N = J.shape[0], J.shape[1]
            w = Y[:, m.rot_idx].reshape(F_, -1, 3)
            Jl = se3_left_jacobian(w.reshape(-1, 3)).reshape(F_, -1, 3, 3)
            Jr = J[:, :, m.rot_idx].reshape(F_, N, -1, 3)
            J[:, :, m.rot_idx] = np.einsum("fnbi,fbij->fnbj", Jr, Jl).reshape(F_, N, -1)
        if len(inact):
            J[:, inact, :] = 0.0
            J[:, :, inact] = 0.0
            J[:, inact, inact] = 1.0
        return J

    # ------------------------------------------------------------------ one frame
    def one(self, chart, y, t):
        """Simplified Newton on one output point with the chart's held factorisation:
        ``(y, corrections, error estimate, ok)``."""
        import time as _t
        t0 = _t.perf_counter()
        st = self.stats
        counted = self.data.residuals, self.data.factorizations
        if chart is not self.chart:
            self.chart, self.solve = chart, chart.held
        y = np.array(y, float)
        it, ok, err = 0, False, np.nan
        refreshed = False

        def step(F):
            dy = -self.solve(F)
            if not np.all(np.isfinite(dy)):
                raise np.linalg.LinAlgError("non-finite correction")
            return dy, float(self._err(dy))

        try:
            F = chart.F(chart.state(y, t))
            z_prev = np.inf
            while True:
                z = float(self._z(F))
                if self.solve is None:
                    self.solve, refreshed = chart._factor(y, t), True
                dy, err = step(F)
                if z <= 1.0 and err <= self.max_error:
                    ok = True
                    y = y + dy          # applied: the error reported bounds the point's
                    it += 1
                    break
                if it >= CORRECT_MAX_ITER:
                    break
                if it > 0 and z > CORRECT_RATE * z_prev and not refreshed:
                    self.solve, refreshed = chart._factor(y, t), True
                    dy, err = step(F)
                y = y + dy
                it += 1
                z_prev = z
                F = chart.F(chart.state(y, t))
        except (np.linalg.LinAlgError, RuntimeError, ValueError, EvaluationError):
            ok = False
        st["corrections"] += it
        st["residuals"] += self.data.residuals - counted[0]
        st["factorisations"] += self.data.factorizations - counted[1]
        st["seconds"] += _t.perf_counter() - t0
        return y, it, err, ok


class _Stacked:
    """A stack of per-frame Jacobians ``J`` (F, N, N): ``solve(frames, b)`` solves the listed
    frames' systems with right-hand sides ``b`` (n, N) (one LAPACK LU solve per frame)."""

    def __init__(self, J):
        self.J = J

    def solve(self, frames, b):
        return np.linalg.solve(self.J[frames], b[..., None])[..., 0]
