"""FIM_D's output-frame corrector: IDA's output points brought onto the equilibrium.

:class:`Corrector` corrects the output points of one IDA step together
(:class:`BatchCorrection`), then any frame still off alone (:class:`FrameCorrection`), both
:class:`~poise.solvers.iterate.Solver` runs within ``limits.correct_max_iter`` corrections, to
the ``Param_Static`` tolerances. Notes: docs/fim_d.md.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from poise.core.errors import EvaluationError
from poise.elements.rotation import se3_left_jacobian
from poise.model.frame_batch import batchable
from poise.solvers.iterate import Next, Solver, iterate
from poise.solvers.newton import Scales
from poise.solvers.status import Status

CORRECT_RATE = 0.25       # contraction slower than this: refactorise at the frame (once a frame)


class Corrector:
    """Brings IDA's output points onto the equilibrium, to the ``Param_Static`` tolerances.

    IDA's interpolant (or corrector, with ``dae_interpolation`` FALSE) meets IDA's local error
    test, not ``max_imbalance`` / ``max_error``: on ``decks/bench/slider_crank_qs_1000.xml`` the
    output frames were up to 0.013 N off against 1e-8. The output points passed by one IDA step
    are corrected together (:meth:`batch`, a :class:`BatchCorrection`): Newton corrections in
    the chart's coordinates, ``y <- y - F_y(y_0)^{-1} F(y, t)``, with each frame's Jacobian taken once at its
    interpolated point (one batched residual + Jacobian evaluation,
    :func:`~poise.model.evaluate.evaluate`), then one batched residual and one
    stacked back-substitution per further correction. A frame is accepted when its residual
    meets the FIM_S scales (force rows ``max_imbalance``, moment rows ``max_imbalance * L``,
    constraint rows ``max_error`` (x L)) and the next correction — its error estimate — is
    ``<= max_error`` (translations / L, rotations in rad); that correction is applied, so the
    error reported bounds the error of the point written. Frames still off after
    ``limits.correct_max_iter`` corrections, or models that are not batched, go through
    :meth:`one` (a :class:`FrameCorrection`): simplified Newton with a factorisation held per
    chart (refactorised at the frame when the contraction is slower than ``CORRECT_RATE``);
    the caller runs a full Newton (FIM_S) on a
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
        self.limits = settings.limits
        self.chart = None
        self.solve = None
        self.stats = dict(frames=0, corrections=0, residuals=0, factorisations=0, newton=0,
                          seconds=0.0)

    # ------------------------------------------------------------------ measures
    def z(self, F):
        """Tolerance-scaled infinity norm of residual rows ``F`` (..., N)."""
        nq = self.model.nq
        zr = np.abs(F[..., :nq]) / self.sc.r_tol
        zp = np.abs(F[..., nq:]) / self.sc.phi_tol
        return np.maximum(zr.max(axis=-1, initial=0.0), zp.max(axis=-1, initial=0.0))

    def err(self, dy):
        """Error estimate of the corrections ``dy`` (..., N): translations / L, rad."""
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
            counted = data.residuals, data.factorizations
            try:
                run = iterate(BatchCorrection(self, chart, T), self.limits.correct_max_iter + 1,
                              (), Y)
                Y = run.Y
                st["corrections"] += run.corrections
                if run.failed is None:
                    its, errs, ok, done = run.its, run.errs, run.ok, True
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

    def chart_jacobian(self, J, Y, inact):
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
        """Simplified Newton on one output point with the chart's held factorisation
        (:class:`FrameCorrection`): ``(y, corrections, error estimate, ok)``."""
        import time as _t
        t0 = _t.perf_counter()
        st = self.stats
        counted = self.data.residuals, self.data.factorizations
        if chart is not self.chart:
            self.chart, self.solve = chart, chart.held
        run = iterate(FrameCorrection(self, chart, t), self.limits.correct_max_iter + 1, (),
                      np.array(y, float))
        self.solve = run.solve
        st["corrections"] += run.it
        st["residuals"] += self.data.residuals - counted[0]
        st["factorisations"] += self.data.factorizations - counted[1]
        st["seconds"] += _t.perf_counter() - t0
        return run.y, run.it, run.err, run.done is Status.CONVERGED


@dataclass(frozen=True)
class Batch:
    """Where a :class:`BatchCorrection` stands: the points ``Y`` (F, N), their residuals
    ``Fv``, the stacked factorisation ``J``, the frames still ``live``, the tests done
    ``it``, per frame its corrections, error estimate and whether it was accepted; the
    corrections applied; ``failed``: the error that ended it (the points as far as they
    got)."""

    Y: np.ndarray
    Fv: np.ndarray
    J: Any
    live: np.ndarray
    its: np.ndarray
    errs: np.ndarray
    ok: np.ndarray
    it: int = 0
    corrections: int = 0
    failed: BaseException | None = None


class BatchCorrection(Solver):
    """Newton corrections of the output points of one IDA step together
    (:meth:`Corrector.batch`): each step tests every live frame (accepted: its last
    correction applied, so the error reported bounds the point's) and corrects the others
    when the budget allows testing them again. Budget: tests (``limits.correct_max_iter`` + 1).
    Result: the last :class:`Batch`."""

    def __init__(self, corrector, chart, T):
        self.c, self.chart, self.T = corrector, chart, T

    def init(self, Y):
        c, m = self.c, self.c.model
        F_ = len(Y)
        inact = np.nonzero(~c.active)[0] + m.nq
        ev = c.data.evaluate(m, self.chart.states(Y, self.T), "jacobian")
        Fv = np.concatenate([ev.r, np.where(c.active, ev.phi, 0.0)], axis=1)
        J = c.data.factor(c.chart_jacobian(ev.J, Y, inact), _Stacked, count=F_)
        return Batch(Y, Fv, J, np.arange(F_), np.zeros(F_, int), np.full(F_, np.nan),
                     np.zeros(F_, bool))

    def terminate(self, s):
        if s.failed is not None:
            return True, Status.NONFINITE
        return not s.live.size, Status.CONVERGED

    def step(self, s, left):
        c, live = self.c, s.live
        try:
            dy = s.J.solve(live, -s.Fv[live])
            if not np.all(np.isfinite(dy)):
                raise np.linalg.LinAlgError("non-finite correction")
        except (np.linalg.LinAlgError, EvaluationError, ValueError) as e:
            return Next(replace(s, failed=e))
        Y, Fv, its, errs, ok = s.Y.copy(), s.Fv.copy(), s.its.copy(), s.errs.copy(), s.ok.copy()
        e = c.err(dy)
        good = (c.z(Fv[live]) <= 1.0) & (e <= c.max_error)
        errs[live], its[live], ok[live[good]] = e, s.it, True
        # the last correction is applied too: its size, the error reported, bounds the
        # error of the point written (Newton: second order smaller)
        Y[live[good]] += dy[good]
        its[live[good]] += 1
        n = s.corrections + int(good.sum())
        live, dy = live[~good], dy[~good]
        if not live.size or left <= 1:       # done, or no test left for another correction
            return Next(replace(s, Y=Y, live=live, its=its, errs=errs, ok=ok, it=s.it + 1,
                                corrections=n))
        Y[live] += dy
        s = replace(s, Y=Y, live=live, its=its, errs=errs, ok=ok, it=s.it + 1,
                    corrections=n + live.size)
        try:
            ev = c.data.evaluate(c.model, self.chart.states(Y[live], self.T[live]),
                                 "residual")
        except (EvaluationError, ValueError) as e:
            return Next(replace(s, failed=e))
        Fv[live] = np.concatenate([ev.r, np.where(c.active, ev.phi, 0.0)], axis=1)
        return Next(replace(s, Fv=Fv))

    def postprocess(self, s, status, used):
        return s


@dataclass(frozen=True)
class Correcting:
    """Where a :class:`FrameCorrection` stands: the point ``y``, its residual ``F``,
    corrections applied ``it``, the last error estimate, the previous scaled residual, the
    factorisation held and whether it was refreshed at this frame; ``done`` once accepted
    (converged) or not (``max_iterations``, ``nonfinite``)."""

    y: np.ndarray
    F: Any
    solve: Any
    it: int = 0
    err: float = np.nan
    z_prev: float = np.inf
    refreshed: bool = False
    done: Status | None = None


class FrameCorrection(Solver):
    """Simplified Newton on one output point at time ``t`` with the corrector's held
    factorisation, refactorised at the point (once) when the residual contracts slower than
    ``CORRECT_RATE``. Each step tests the point (accepted: the correction applied) and
    corrects it when the budget allows testing it again. Budget: tests
    (``limits.correct_max_iter`` + 1). Result: the last :class:`Correcting`; a linear-algebra or
    evaluation failure ends it ``nonfinite`` where it got."""

    def __init__(self, corrector, chart, t):
        self.c, self.chart, self.t = corrector, chart, t

    def init(self, y):
        try:
            F = self.chart.F(self.chart.state(y, self.t))
        except (np.linalg.LinAlgError, RuntimeError, ValueError, EvaluationError):
            return Correcting(y, None, self.c.solve, done=Status.NONFINITE)
        return Correcting(y, F, self.c.solve)

    def terminate(self, s):
        return s.done is not None, s.done

    def correction(self, solve, F):
        dy = -solve(F)
        if not np.all(np.isfinite(dy)):
            raise np.linalg.LinAlgError("non-finite correction")
        return dy, float(self.c.err(dy))

    def step(self, s, left):
        chart, t = self.chart, self.t
        y, it, err, solve, refreshed = s.y, s.it, s.err, s.solve, s.refreshed
        try:
            z = float(self.c.z(s.F))
            if solve is None:
                solve, refreshed = chart.factor(y, t), True
            dy, err = self.correction(solve, s.F)
            if z <= 1.0 and err <= self.c.max_error:
                # applied: the error reported bounds the point's
                return Next(replace(s, y=y + dy, it=it + 1, err=err, solve=solve,
                                    refreshed=refreshed, done=Status.CONVERGED))
            if left <= 1:
                return Next(replace(s, err=err, solve=solve, refreshed=refreshed,
                                    done=Status.MAX_ITERATIONS))
            if it > 0 and z > CORRECT_RATE * s.z_prev and not refreshed:
                solve, refreshed = chart.factor(y, t), True
                dy, err = self.correction(solve, s.F)
            y, it = y + dy, it + 1
            F = chart.F(chart.state(y, t))
        except (np.linalg.LinAlgError, RuntimeError, ValueError, EvaluationError):
            return Next(replace(s, y=y, it=it, err=err, solve=solve, refreshed=refreshed,
                                done=Status.NONFINITE))
        return Next(replace(s, y=y, F=F, it=it, err=err, z_prev=z, solve=solve,
                            refreshed=refreshed))

    def postprocess(self, s, status, used):
        return s


class _Stacked:
    """A stack of per-frame Jacobians ``J`` (F, N, N): ``solve(frames, b)`` solves the listed
    frames' systems with right-hand sides ``b`` (n, N) (one LAPACK LU solve per frame)."""

    def __init__(self, J):
        self.J = J

    def solve(self, frames, b):
        return np.linalg.solve(self.J[frames], b[..., None])[..., 0]
