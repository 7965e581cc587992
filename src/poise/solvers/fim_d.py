"""FIM_D: quasi-static continuation, ``F(q(t), lam(t), t) = 0`` integrated by SUNDIALS IDA.

Every unknown is algebraic (no ``y'`` terms); IDA's BDF error test controls the step along the
equilibrium path. Unknowns live in a chart around a reference state (solvers/chart.py), re-based
when a rotation exceeds ``REBASE_ANGLE``; IDA runs dense up to ``SPARSE_MIN`` unknowns, sparse
(SuperLU_MT) above (solvers/ida.py). Frame 0 and the last frame are solved by FIM_S, every
output point IDA passes is corrected onto the equilibrium to the ``Param_Static`` tolerances
(``Corrector``), and a step IDA cannot take falls back to FIM_S for the next output frame (then
IDA restarts). Budgets are deterministic (:class:`~poise.solvers.limits.Limits`):
``ida_max_steps + ida_steps_per_frame`` x frames accepted steps, a step-size floor, and a body
``ESCAPE`` model sizes away ends the run. The per-step table ``steps/*`` comes from IDA's own
counters. Every history row of a step (its own and those of the Newton and continuation runs
it starts) is collected in order and handed to the loop. Design notes, tolerances and the
measurements behind the constants: docs/fim_d.md.
"""
from __future__ import annotations

import numpy as np

from dataclasses import dataclass, replace
from typing import Any

from poise.solvers import ida, path, singular
from poise.solvers.branch import BranchPath
from poise.solvers.chart import Chart
from poise.solvers.context import AnalysisSolver, Finished, replicated
from poise.solvers.correct import Corrector
from poise.solvers.fallback import solve_frame
from poise.solvers.history import Buffer, Row
from poise.solvers.ida import IdaStats, SparseJacobian, TransientSettings, run_ida  # noqa: F401
from poise.solvers.iterate import Next
from poise.solvers.newton import FrameOutcome
from poise.solvers.quasistatic import fims_step, first_frame, require_stable
from poise.solvers.record import IdaSteps
from poise.solvers.status import Status

REBASE_ANGLE = 1.0        # rad
SPARSE_MIN = 200          # unknowns: above this IDA uses the sparse (SuperLU_MT) linear solver
ESCAPE = 1e6              # a body this many model sizes from its chart's reference: no bounded path
SHRINK = 1e-2             # IDA steps below this fraction of the print interval: near a singularity?
SHRINK_CHECK = 0.25       # ... checked again each time the step shrinks by this factor


#: ``steps/*`` columns, in the order of a recorded step
STEP_COLUMNS = ("time", "step_size", "order", "nonlinear_iterations", "error_test_failures",
                "convergence_failures", "jacobian_evaluations", "rebase")


@dataclass(frozen=True)
class IdaRun:
    """What one FIM_D run holds between its steps: the integrator (IDA's memory, a SUNDIALS
    handle, and the chart it integrates in: external, mutable by nature), the corrector (its
    counters), settings fixed at the start (``tsd``, ``eps``, ``interval``, ``T_end``,
    ``tol``, ``max_steps``, ``sparse``), and the progress: the next output frame ``k_out``,
    starts, the chart's reference, the last IDA point, the step table (rows of
    :data:`STEP_COLUMNS`), the fallbacks and why IDA's counters or coefficient were not
    available. ``done``: no more IDA steps; ``checked``: the path check ran."""

    tsd: Any
    eps: float
    interval: float
    T_end: float
    tol: float
    max_steps: int
    sparse: Any
    correct: Any
    ref: Any
    t_last: float
    k_out: int = 1
    n_starts: int = 0
    rebased: int = 1
    chart: Any = None
    solver: Any = None
    y_last: Any = None
    h_checked: float = np.inf          # step size at the last singularity check
    steps: tuple = ()
    stats_off: tuple = ()              # why IDA's own counters could not be read (order -1)
    conv_coef_off: tuple = ()          # why IDA's corrector coefficient could not be set
    fallbacks: tuple = ()
    done: bool = False
    checked: bool = False


@dataclass(frozen=True)
class NoRun:
    """FIM_D's state when IDA has nothing to integrate (frame 0 failed, one output time,
    nothing depends on time): only the path check is left."""

    done: bool = True
    checked: bool = False


class IdaContinuation(AnalysisSolver):
    """FIM_D: the equilibrium path integrated by IDA between the output frames (module notes);
    frame 0 and the last frame by FIM_S, FIM_S fallbacks where IDA fails. One ``step`` is one
    IDA step (it may pass several output frames); after the last, the path check."""

    name = "FIM_D"

    def start(self, a, state):
        env = self.env
        model, s, ts = env.model, env.settings, a.times
        a, st, out = first_frame(env, a, state)
        if out.ok and s.require_stable:
            a, st, out = require_stable(env, a, st, out)
        a = replace(a.added(st, out), method=NoRun())
        if not out.ok or len(ts) == 1:
            return a
        if a.time_independent:
            return replicated(a)
        tsd = TransientSettings.from_attrs(env.request.transient,
                                           max(float(ts[-1] - ts[0]), 1e-300))
        lim = s.limits    # deterministic budget (an exploding load must end, not integrate on)
        return replace(a, method=IdaRun(
            tsd=tsd, eps=float(np.sqrt(s.stability)), interval=float(np.min(np.diff(ts))),
            T_end=float(ts[-1]), tol=tsd.tol,
            max_steps=lim.ida_max_steps + lim.ida_steps_per_frame * len(ts),
            sparse=SparseJacobian(model) if model.N > SPARSE_MIN else None,
            correct=Corrector(model, s, env.data), ref=st, t_last=st.t))

    @staticmethod
    def _integrated(a) -> bool:
        """No more IDA steps: done, every output frame reached, or the last frame failed."""
        m = a.method
        return m.done or m.k_out >= len(a.times) or not a.outcomes[-1].ok

    def terminate(self, a):
        if a.method is not None and not (self._integrated(a) and a.method.checked):
            return False, None
        return True, a.outcomes[-1].status

    def _atol(self, model, st, tol):
        a = np.empty(model.N)
        a[:model.nq] = np.where(model.q_kind == 1, tol, tol * model.L)
        lam = np.abs(st.lam)
        for kind in (0, 1):
            sel = model.row_kind == kind
            if sel.any():
                a[model.nq:][sel] = tol * max(1.0, float(lam[sel].max()) if sel.any() else 1.0)
        return a

    def _start(self, m, first):
        model, tsd, ref = self.env.model, m.tsd, m.ref
        chart = Chart(model, ref, m.eps, self.env.data, m.sparse, m.tol)
        y0 = np.concatenate([np.zeros(model.nq), ref.lam])
        atol = self._atol(model, ref, m.tol)
        capped = first and tsd.h0 > 0       # the user's (or the deck schema's) h0_max
        y0, yp0, h0 = chart.start(y0, ref.t, m.interval,
                                  1.0 / (m.tol * np.abs(y0) + atol), m.T_end - ref.t,
                                  want_h0=not capped)
        # no first step beyond the output resolution
        h0 = min(tsd.h0, m.interval) if capped else min(h0, m.interval)
        solver = run_ida(chart, tsd, atol, ref.t, y0, yp0, h0)
        return chart, solver, y0

    def _fall_back(self, a, m, reason, last_state, rows):
        """FIM_S for output frame ``k_out`` from ``last_state``; ends the run if it fails."""
        a = _fallback(self.env, a, m.k_out, reason, last_state, rows)
        m = replace(m, k_out=m.k_out + 1, fallbacks=m.fallbacks + (reason,))
        if not a.outcomes[-1].ok:
            return replace(a, method=replace(m, done=True))
        return replace(a, method=replace(m, ref=a.frames[-1]))

    def step(self, a, left):
        if self._integrated(a):             # the path check: outside the nonfinite guard
            a, rows = path.check(self.env, a, fims_step)
            return Next(replace(a, method=replace(a.method, checked=True)), 0, rows)
        return super().step(a, left)

    def advance(self, a, left):
        rows = Buffer()
        n0 = len(a.frames)
        a = self._advance(a, rows)
        return Next(a, len(a.frames) - n0, tuple(rows.rows))

    def _advance(self, a, hist):
        env = self.env
        model, s, ts, data, m = env.model, env.settings, a.times, env.data, a.method
        T_end = m.T_end
        if m.solver is None:
            try:
                chart, solver, y_last = self._start(m, m.n_starts == 0)
                m = replace(m, chart=chart, solver=solver, y_last=y_last, n_starts=m.n_starts + 1,
                            t_last=m.ref.t)
                if not chart.conv_coef_set and not m.conv_coef_off:
                    m = replace(m, conv_coef_off=(chart.stats.reason,))
            except (RuntimeError, ValueError) as e:
                return self._fall_back(a, replace(m, solver=None),
                                       f"IDA could not start at t={m.ref.t:.9g}: {e}", m.ref,
                                       hist)
        chart, solver = m.chart, m.solver
        stop = T_end if m.tsd.interpolate else float(ts[m.k_out])
        # IDA's callbacks per step, when its own counters cannot be read: the solve's counts
        n0r, nj0 = data.residuals, data.jacobians
        chart.trial_times = set()
        try:
            r = solver.step(stop, method="onestep", tstop=stop)
            ok_step = bool(r.success)
            msg = r.message
        except (RuntimeError, ValueError) as e:
            ok_step, msg = False, str(e)
        if not ok_step:
            reason = f"IDA failed after t={m.t_last:.9g}: {msg}"
            last = (chart.state(m.y_last, m.t_last) if m.y_last is not None else a.frames[-1])
            return self._fall_back(a, replace(m, solver=None, rebased=1), reason, last, hist)
        d = chart.stats.step(r) if chart.stats is not None else None
        if (d["NumSteps"] == 0) if d is not None else (r.t == m.t_last and data.residuals == n0r):
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
                if chart.stats is not None and chart.stats.reason not in m.stats_off:
                    m = replace(m, stats_off=m.stats_off + (chart.stats.reason,))
                row = (r.t - m.t_last, -1, data.residuals - n0r,
                       max(len(chart.trial_times) - 1, 0), -1, data.jacobians - nj0)
            m = replace(m, steps=m.steps + ((r.t, *row, m.rebased),), rebased=0)
        m = replace(m, t_last=float(r.t), y_last=np.array(r.y, float))
        t_last, y_last = m.t_last, m.y_last
        over = _over_budget(len(m.steps), m.max_steps, y_last, model, t_last)
        if over is not None:
            hist.append(Row(m.k_out, 0, np.nan, np.nan, np.nan, np.nan, over.message, "ida"))
            return replace(a.added(chart.state(y_last, t_last), over),
                           method=replace(m, k_out=m.k_out + 1, done=True))
        tol_t = 1e-12 * max(1.0, abs(T_end))
        # output frames passed by this step (interpolated), except the last one
        pend = []
        k_out = m.k_out
        while k_out < len(ts) - 1 and ts[k_out] <= t_last + tol_t:
            tk = float(ts[k_out])
            if abs(tk - t_last) <= tol_t:
                yk = y_last
            else:
                yk = np.array(solver.step(tk).y, float)
            pend.append((k_out, tk, yk))
            k_out += 1
        m = replace(m, k_out=k_out)
        # onto the equilibrium to the Param_Static tolerances (Corrector, all the output points
        # of this step at once); imbalance / constraint error / worst equation of each "ida"
        # row: from the frame's output evaluation at the result (the same state)
        if pend:
            Tp = np.array([p[1] for p in pend])
            Yc, n_c, errs, ok_c = m.correct.batch(chart, np.array([p[2] for p in pend]), Tp)
            sts = chart.states(Yc, Tp)
            for j, (k, tk, yk) in enumerate(pend):
                hist.append(Row(k, n_c[j], np.nan, np.nan, errs[j], np.nan, "", "ida",
                                measured_at=len(a.frames)))
                if ok_c[j]:
                    st, o = sts[j], FrameOutcome(Status.CONVERGED, int(n_c[j]), np.nan, errs[j],
                                                 "ida")
                else:
                    m.correct.stats["newton"] += 1
                    start = chart.state(yk, tk)
                    st, o = solve_frame(model, start, s, hist, k, data, event="ida_newton")
                    why = _off_branch(env, a.frames, start, st, o)
                    if why:         # Newton left the branch IDA was on: continuation instead
                        hist.append(Row(k, 0, o.imbalance, o.error, np.nan, np.nan, why,
                                        "substep_retry"))
                        st, o, _ = fims_step(model, list(a.frames), tk, s, hist, data, k,
                                             s.limits.min_substep_fraction
                                             * (tk - a.frames[-1].t))
                    o = replace(o, iterations=o.iterations + int(n_c[j]))
                a = a.added(st, o)
                env.report("FIM_D", k + 1, len(ts))
                if not o.ok:
                    return replace(a, method=replace(m, done=True))
        if m.k_out == len(ts) - 1 and t_last >= T_end - tol_t:
            # last frame: FIM_S polish of IDA's end state
            start = chart.state(y_last, T_end)
            st, o = solve_frame(model, start, s, hist, m.k_out, data, event="final_fim_s")
            why = _off_branch(env, a.frames, start, st, o)
            if not o.ok or why:
                reason = (f"Newton polish of the last frame failed ({o.status.value})" if not o.ok
                          else f"Newton polish of the last frame left the branch: {why}")
                a = _fallback(env, a, m.k_out, reason, chart.state(y_last, t_last), hist)
                m = replace(m, fallbacks=m.fallbacks + (reason,))
            else:
                a = a.added(st, o)
            return replace(a, method=replace(m, k_out=m.k_out + 1, done=True))
        m, near = self._towards_singular(a, m, chart, y_last, t_last)
        if near:
            return self._fall_back(a, replace(m, solver=None, rebased=1),
                                   f"IDA's steps shrink to {m.steps[-1][1]:.3g} at "
                                   f"t={t_last:.9g}, next to a singular configuration",
                                   chart.state(y_last, t_last), hist)
        if chart.max_rotation(y_last) > REBASE_ANGLE:
            m = replace(m, ref=chart.state(y_last, t_last), solver=None, rebased=1)
        return replace(a, method=m)

    def _towards_singular(self, a, m, chart, y, t):
        """IDA's steps shrinking below ``SHRINK`` of the print interval (every further factor
        ``SHRINK_CHECK``): is the path approaching a singular configuration
        (:meth:`~poise.solvers.branch.BranchPath.near_singular`)? IDA would otherwise creep
        towards a fold in ever smaller steps until its step-size floor. Returns ``(run,
        near)``."""
        h = m.steps[-1][1] if m.steps else np.inf
        if not h < SHRINK * m.interval or not h < m.h_checked * SHRINK_CHECK:
            return m, False
        env = self.env
        branch = BranchPath(env.model, list(a.frames) + [chart.state(y, t)], env.settings,
                            env.data, m.interval)
        return replace(m, h_checked=h), branch.near_singular(list(a.frames))

    def finish(self, a, status, used):
        m = a.method
        if not isinstance(m, IdaRun):       # frame 0 failed or nothing to integrate
            return Finished(a, None, singular.located_attrs(a.outcomes))
        model, fallbacks = self.env.model, m.fallbacks
        notes = []
        if fallbacks:
            notes.append(f"{len(fallbacks)} FIM_S fallbacks: " + "; ".join(fallbacks[:3])
                         + (" ..." if len(fallbacks) > 3 else ""))
        nsteps = len(m.steps)
        notes.append(f"IDA: {nsteps} steps, tol {m.tol:g}"
                     + (f", sparse linear solver (SuperLU_MT, N = {model.N})"
                        if m.sparse else ""))
        if m.stats_off:
            notes.append("IDA step order not available: " + "; ".join(m.stats_off))
        if m.conv_coef_off:
            notes.append(f"IDA corrector coefficient left at IDA's default 0.33 (not "
                         f"{ida.NONLIN_CONV_COEF:g}): " + "; ".join(m.conv_coef_off))
        attrs = {"ida_steps": nsteps}
        for k, v in m.correct.stats.items():
            attrs[f"correction_{k}"] = v
        attrs["fim_s_fallbacks"] = len(fallbacks)
        attrs["dae_tol"] = m.tol
        attrs["ida_linear_solver"] = "sparse" if m.sparse is not None else "dense"
        attrs.update(singular.located_attrs(a.outcomes))
        columns = {c: [row[i] for row in m.steps] for i, c in enumerate(STEP_COLUMNS)}
        return Finished(a.noted(*notes), IdaSteps(columns=columns), attrs)


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


def _off_branch(env, frames, start, st, out) -> str:
    """Why the Newton solution ``st`` from IDA's point ``start`` is not on the branch of the
    ``frames`` before (:meth:`~poise.solvers.branch.BranchPath.jump`), or ``""``."""
    if not out.ok or not frames:
        return ""
    interval = max(start.t - frames[-1].t, 1e-300)
    return BranchPath(env.model, list(frames), env.settings, env.data, interval).jump(start, st,
                                                                                      True)


def _fallback(env, a, k_out, reason, last_state, rows):
    """Solve output frame ``k_out`` with FIM_S from ``last_state``; the reason is its first
    row (into ``rows``, the step's). Returns the analysis with the frame."""
    rows.append(Row(k_out, 0, np.nan, np.nan, np.nan, np.nan, reason, "fallback_fim_s"))
    ts = a.times
    hist = list(a.frames[-2:])
    if last_state.t > hist[-1].t:
        hist.append(last_state)
    min_dt = env.settings.limits.min_substep_fraction * (ts[k_out] - ts[k_out - 1])
    st, o, _ = fims_step(env.model, hist, float(ts[k_out]), env.settings, rows, env.data,
                         k_out, min_dt)
    return a.added(st, o)
