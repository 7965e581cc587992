"""FIM_D: quasi-static continuation, ``F(q(t), lam(t), t) = 0`` integrated by SUNDIALS IDA.

Every unknown is algebraic (no ``y'`` terms); IDA's BDF error test controls the step along the
equilibrium path. Unknowns live in a chart around a reference state (solvers/chart.py), re-based
when a rotation exceeds ``REBASE_ANGLE``; IDA runs dense up to ``SPARSE_MIN`` unknowns, sparse
(SuperLU_MT) above (solvers/ida.py). Frame 0 and the last frame are solved by FIM_S, every
output point IDA passes is corrected onto the equilibrium to the ``Param_Static`` tolerances
(``Corrector``), and a step IDA cannot take falls back to FIM_S for the next output frame (then
IDA restarts). Budgets are deterministic (:class:`~poise.solvers.limits.Limits`):
``ida_max_steps + ida_steps_per_frame`` x frames accepted steps, a step-size floor, and a body ``ESCAPE`` model sizes away ends the run. The
per-step table ``steps/*`` comes from IDA's own counters. Design notes, tolerances and the
measurements behind the constants: docs/fim_d.md.
"""
from __future__ import annotations

import numpy as np

from poise.solvers.chart import Chart
from poise.solvers.correct import Corrector
from poise.solvers.context import Strategy, replicate
from poise.solvers.fallback import solve_frame
from poise.solvers import ida, path, singular
from poise.solvers.ida import IdaStats, SparseJacobian, TransientSettings, run_ida  # noqa: F401
from poise.solvers.newton import FrameOutcome
from poise.solvers.quasistatic import (
    BranchPath,
    fims_step,
    first_frame,
    require_stable,
)
from poise.solvers.record import IdaSteps
from poise.solvers.status import Status

REBASE_ANGLE = 1.0        # rad
SPARSE_MIN = 200          # unknowns: above this IDA uses the sparse (SuperLU_MT) linear solver
ESCAPE = 1e6              # a body this many model sizes from its chart's reference: no bounded path
SHRINK = 1e-2             # IDA steps below this fraction of the print interval: near a singularity?
SHRINK_CHECK = 0.25       # ... checked again each time the step shrinks by this factor


class IdaContinuation(Strategy):
    """FIM_D: the equilibrium path integrated by IDA between the output frames (module notes);
    frame 0 and the last frame by FIM_S, FIM_S fallbacks where IDA fails. One ``step`` is one
    IDA step (it may pass several output frames)."""

    name = "FIM_D"

    def init(self, ctx, state):
        model, s, ts = ctx.model, ctx.settings, ctx.times
        st, out = first_frame(ctx, state)
        if out.ok and s.require_stable:
            st, out = require_stable(ctx, st, out)
        ctx.frames, ctx.outcomes = [st], [out]
        self.done = not out.ok or len(ts) == 1
        if self.done:
            return
        if ctx.time_independent:
            replicate(ctx)
            self.done = True
            return
        self.sparse = SparseJacobian(model) if model.N > SPARSE_MIN else None
        self.tsd = tsd = TransientSettings.from_attrs(ctx.request.transient,
                                                      max(float(ts[-1] - ts[0]), 1e-300))
        self.eps = float(np.sqrt(s.stability))
        self.interval = float(np.min(np.diff(ts)))
        self.T_end = float(ts[-1])
        self.tol = tsd.tol
        self.steps = dict(time=[], step_size=[], order=[], nonlinear_iterations=[],
                          error_test_failures=[], convergence_failures=[],
                          jacobian_evaluations=[], rebase=[])
        self.stats_off = []          # why IDA's own counters could not be read (order -1)
        self.conv_coef_off = []      # why IDA's corrector coefficient could not be set
        self.fallbacks = []
        self.correct = Corrector(model, s, ctx.data)
        self.k_out = 1
        self.n_starts = 0
        # deterministic budget (a run whose load explodes must end, not integrate forever)
        lim = s.limits
        self.max_steps = lim.ida_max_steps + lim.ida_steps_per_frame * len(ts)
        self.ref = st
        self.rebased = 1
        self.chart = self.solver = None
        self.t_last, self.y_last = st.t, None
        self.h_checked = np.inf          # step size at the last singularity check

    def terminate(self, ctx):
        return self.done or self.k_out >= len(ctx.times)

    def _atol(self, model, st):
        tol = self.tol
        a = np.empty(model.N)
        a[:model.nq] = np.where(model.q_kind == 1, tol, tol * model.L)
        lam = np.abs(st.lam)
        for kind in (0, 1):
            sel = model.row_kind == kind
            if sel.any():
                a[model.nq:][sel] = tol * max(1.0, float(lam[sel].max()) if sel.any() else 1.0)
        return a

    def _start(self, ctx, ref, first):
        model, tsd = ctx.model, self.tsd
        chart = Chart(model, ref, self.eps, ctx.data, self.sparse, self.tol)
        y0 = np.concatenate([np.zeros(model.nq), ref.lam])
        atol = self._atol(model, ref)
        capped = first and tsd.h0 > 0       # the user's (or the deck schema's) h0_max
        y0, yp0, h0 = chart.start(y0, ref.t, self.interval,
                                  1.0 / (self.tol * np.abs(y0) + atol), self.T_end - ref.t,
                                  want_h0=not capped)
        # no first step beyond the output resolution
        h0 = min(tsd.h0, self.interval) if capped else min(h0, self.interval)
        solver = run_ida(chart, tsd, atol, ref.t, y0, yp0, h0)
        return chart, solver, y0

    def _fall_back(self, ctx, reason, last_state):
        """FIM_S for output frame ``k_out`` from ``last_state``; ends the run if it fails."""
        ok = _fallback(ctx, self.k_out, reason, self.fallbacks, last_state)
        self.k_out += 1
        if not ok:
            self.done = True
            return
        self.ref = ctx.frames[-1]

    def step(self, ctx):
        model, s, ts, hist = ctx.model, ctx.settings, ctx.times, ctx.history
        T_end = self.T_end
        if self.solver is None:
            try:
                self.chart, self.solver, self.y_last = self._start(ctx, self.ref,
                                                                   self.n_starts == 0)
                self.n_starts += 1
                if not self.chart.conv_coef_set and not self.conv_coef_off:
                    self.conv_coef_off.append(self.chart.stats.reason)
                self.t_last = self.ref.t
            except (RuntimeError, ValueError) as e:
                self.solver = None
                self._fall_back(ctx, f"IDA could not start at t={self.ref.t:.9g}: {e}",
                                self.ref)
                return
        chart, solver = self.chart, self.solver
        stop = T_end if self.tsd.interpolate else float(ts[self.k_out])
        # IDA's callbacks per step, when its own counters cannot be read: the solve's counts
        n0r, nj0 = ctx.data.residuals, ctx.data.jacobians
        chart.trial_times = set()
        try:
            r = solver.step(stop, method="onestep", tstop=stop)
            ok_step = bool(r.success)
            msg = r.message
        except (RuntimeError, ValueError) as e:
            ok_step, msg = False, str(e)
        if not ok_step:
            reason = f"IDA failed after t={self.t_last:.9g}: {msg}"
            last = (chart.state(self.y_last, self.t_last) if self.y_last is not None
                    else ctx.frames[-1])
            self.solver = None
            self._fall_back(ctx, reason, last)
            self.rebased = 1
            return
        d = chart.stats.step(r) if chart.stats is not None else None
        if (d["NumSteps"] == 0) if d is not None else (r.t == self.t_last and ctx.data.residuals == n0r):
            # no step taken: ONE_STEP after an interpolated output returns IDA's pending
            # solution at t_n first (nothing to record)
            pass
        else:
            if d is not None:
                row = (d["LastStep"], d["LastOrder"], d["NumNonlinSolvIters"],
                       d["NumErrTestFails"], d["NumNonlinSolvConvFails"], d["NumJacEvals"])
            else:
                # IDA's counters unreadable: order -1; iterations = residual evaluations (one
                # per Newton iteration); retries = extra trial times (both failure kinds)
                if chart.stats is not None and chart.stats.reason not in self.stats_off:
                    self.stats_off.append(chart.stats.reason)
                row = (r.t - self.t_last, -1, ctx.data.residuals - n0r,
                       max(len(chart.trial_times) - 1, 0), -1, ctx.data.jacobians - nj0)
            for k, v in zip(("time", "step_size", "order", "nonlinear_iterations",
                             "error_test_failures", "convergence_failures",
                             "jacobian_evaluations", "rebase"), (r.t, *row, self.rebased)):
                self.steps[k].append(v)
            self.rebased = 0
        self.t_last, self.y_last = float(r.t), np.array(r.y, float)
        t_last, y_last = self.t_last, self.y_last
        over = _over_budget(len(self.steps["time"]), self.max_steps, y_last, model, t_last)
        if over is not None:
            ctx.frames.append(chart.state(y_last, t_last))
            ctx.outcomes.append(over)
            hist.add(self.k_out, 0, np.nan, np.nan, np.nan, np.nan, over.message, "ida")
            self.k_out += 1
            self.done = True
            return
        tol_t = 1e-12 * max(1.0, abs(T_end))
        # output frames passed by this step (interpolated), except the last one
        pend = []
        while self.k_out < len(ts) - 1 and ts[self.k_out] <= t_last + tol_t:
            tk = float(ts[self.k_out])
            if abs(tk - t_last) <= tol_t:
                yk = y_last
            else:
                yk = np.array(solver.step(tk).y, float)
            pend.append((self.k_out, tk, yk))
            self.k_out += 1
        # onto the equilibrium to the Param_Static tolerances (Corrector, all the output points
        # of this step at once); imbalance / constraint error / worst equation of each "ida"
        # row: from the frame's output evaluation at the result (the same state)
        if pend:
            Tp = np.array([p[1] for p in pend])
            Yc, n_c, errs, ok_c = self.correct.batch(chart, np.array([p[2] for p in pend]), Tp)
            sts = chart.states(Yc, Tp)
            for j, (k, tk, yk) in enumerate(pend):
                hist.add(k, n_c[j], np.nan, np.nan, errs[j], np.nan, "", "ida",
                         measured_at=len(ctx.frames))
                if ok_c[j]:
                    st, o = sts[j], FrameOutcome(Status.CONVERGED, int(n_c[j]), np.nan, errs[j],
                                                 "ida")
                else:
                    self.correct.stats["newton"] += 1
                    start = chart.state(yk, tk)
                    st, o = solve_frame(model, start, s, hist, k, ctx.data, event="ida_newton")
                    why = _off_branch(ctx, start, st, o)
                    if why:         # Newton left the branch IDA was on: continuation instead
                        hist.add(k, 0, o.imbalance, o.error, np.nan, np.nan, why, "substep_retry")
                        st, o, _ = fims_step(model, ctx.frames, tk, s, hist, ctx.data, k,
                                             s.limits.min_substep_fraction * (tk - ctx.frames[-1].t))
                    o.iterations += int(n_c[j])
                ctx.frames.append(st)
                ctx.outcomes.append(o)
                ctx.report("FIM_D", k + 1, len(ts))
                if not o.ok:
                    self.done = True
                    return
        if self.k_out == len(ts) - 1 and t_last >= T_end - tol_t:
            # last frame: FIM_S polish of IDA's end state
            start = chart.state(y_last, T_end)
            st, o = solve_frame(model, start, s, hist, self.k_out, ctx.data, event="final_fim_s")
            why = _off_branch(ctx, start, st, o)
            if not o.ok or why:
                reason = (f"Newton polish of the last frame failed ({o.status.value})" if not o.ok
                          else f"Newton polish of the last frame left the branch: {why}")
                _fallback(ctx, self.k_out, reason, self.fallbacks, chart.state(y_last, t_last))
            else:
                ctx.frames.append(st)
                ctx.outcomes.append(o)
            self.k_out += 1
            self.done = True
            return
        if self._towards_singular(ctx, chart, y_last, t_last):
            self.solver = None
            self._fall_back(ctx, f"IDA's steps shrink to {self.steps['step_size'][-1]:.3g} "
                            f"at t={t_last:.9g}, next to a singular configuration",
                            chart.state(y_last, t_last))
            self.rebased = 1
            return
        if chart.max_rotation(y_last) > REBASE_ANGLE:
            self.ref = chart.state(y_last, t_last)
            self.solver = None
            self.rebased = 1

    def _towards_singular(self, ctx, chart, y, t) -> bool:
        """IDA's steps shrinking below ``SHRINK`` of the print interval (every further factor
        ``SHRINK_CHECK``): is the path approaching a singular configuration
        (:meth:`~poise.solvers.quasistatic.BranchPath.near_singular`)? IDA would otherwise creep
        towards a fold in ever smaller steps until its step-size floor."""
        h = self.steps["step_size"][-1] if self.steps["step_size"] else np.inf
        if not h < SHRINK * self.interval or not h < self.h_checked * SHRINK_CHECK:
            return False
        self.h_checked = h
        path = BranchPath(ctx.model, ctx.frames + [chart.state(y, t)], ctx.settings, ctx.data,
                     self.interval)
        return path.near_singular(ctx.frames)

    def postprocess(self, ctx):
        path.check(ctx, fims_step)
        if not hasattr(self, "steps"):        # frame 0 failed or nothing to integrate
            return None, singular.located_attrs(ctx.outcomes)
        model, notes, fallbacks = ctx.model, ctx.notes, self.fallbacks
        if fallbacks:
            notes.append(f"{len(fallbacks)} FIM_S fallbacks: " + "; ".join(fallbacks[:3])
                         + (" ..." if len(fallbacks) > 3 else ""))
        nsteps = len(self.steps["time"])
        notes.append(f"IDA: {nsteps} steps, tol {self.tol:g}"
                     + (f", sparse linear solver (SuperLU_MT, N = {model.N})"
                        if self.sparse else ""))
        if self.stats_off:
            notes.append("IDA step order not available: " + "; ".join(self.stats_off))
        if self.conv_coef_off:
            notes.append(f"IDA corrector coefficient left at IDA's default 0.33 (not "
                         f"{ida.NONLIN_CONV_COEF:g}): " + "; ".join(self.conv_coef_off))
        attrs = {"ida_steps": nsteps}
        for k, v in self.correct.stats.items():
            attrs[f"correction_{k}"] = v
        attrs["fim_s_fallbacks"] = len(fallbacks)
        attrs["dae_tol"] = self.tol
        attrs["ida_linear_solver"] = "sparse" if self.sparse is not None else "dense"
        attrs.update(singular.located_attrs(ctx.outcomes))
        return IdaSteps(columns=dict(self.steps)), attrs


def _over_budget(n_steps, max_steps, y, model, t):
    """A failed outcome when the run exceeded its IDA step budget or a body left every scale
    of the model (``ESCAPE`` model sizes from its chart's reference); else None."""
    if n_steps > max_steps:
        return FrameOutcome(Status.MAX_ITERATIONS, 0, np.nan, np.nan,
                            f"IDA step budget exhausted ({max_steps} steps) at t={t:.9g}")
    d = float(np.max(np.abs(y[model.trans_idx]))) if model.nb else 0.0
    if not d <= ESCAPE * model.L:
        return FrameOutcome(Status.DIVERGED, 0, np.nan, np.nan,
                            f"the equilibrium path left every scale of the model at t={t:.9g} "
                            f"(a body moved {d / model.L:.3g} model sizes, more than {ESCAPE:g}: is a load "
                            "unbounded?)")
    return None


def _off_branch(ctx, start, st, out) -> str:
    """Why the Newton solution ``st`` from IDA's point ``start`` is not on the branch of the
    frames before (:meth:`~poise.solvers.quasistatic.BranchPath.jump`), or ``""``."""
    if not out.ok or not ctx.frames:
        return ""
    interval = max(start.t - ctx.frames[-1].t, 1e-300)
    return BranchPath(ctx.model, ctx.frames, ctx.settings, ctx.data, interval).jump(start, st, True)


def _fallback(ctx, k_out, reason, fallbacks, last_state):
    """Solve output frame ``k_out`` with FIM_S from ``last_state``; record the reason."""
    fallbacks.append(reason)
    ctx.history.add(k_out, 0, np.nan, np.nan, np.nan, np.nan, reason, "fallback_fim_s")
    frames, ts = ctx.frames, ctx.times
    hist = list(frames[-2:])
    if last_state.t > hist[-1].t:
        hist.append(last_state)
    min_dt = ctx.settings.limits.min_substep_fraction * (ts[k_out] - ts[k_out - 1])
    st, o, _ = fims_step(ctx.model, hist, float(ts[k_out]), ctx.settings, ctx.history, ctx.data,
                         k_out, min_dt)
    frames.append(st)
    ctx.outcomes.append(o)
    return o.ok
