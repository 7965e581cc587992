"""FIM_D: quasi-static continuation by integrating F(q(t), lam(t), t) = 0 with SUNDIALS IDA.

Unknowns (``y``, length nq + nc): tangent coordinates relative to a reference state ``ref`` —
per body the CG translation ``pos - ref.pos`` and a rotation vector ``w`` with
``R = expm(w) R_ref`` (spatial) — followed by the multipliers. When a rotation vector exceeds
``REBASE_ANGLE`` the reference is moved to the current state and IDA is re-initialised (BDF
history restarts at order 1). Continuous angles are unwrapped from the reference
(``ref.angle + wrap(principal - ref.angle)``, valid while relative rotations stay < pi).

Residual: ``[Phi_q^T lam - Q; Phi]`` at ``state(y, t)`` — no ``y'`` terms, so every component is
algebraic (``algebraic_idx`` = all; scikit-sundae only passes it to ``IDASetId``, used by
``IDACalcIC``, which we do not call because the consistent ``yp0`` is supplied). All components
stay in IDA's local error test: the test compares the BDF predictor (polynomial extrapolation of
the path) with the Newton corrector, which is what controls the step size along the
equilibrium path. Jacobian: ``dF/dy = J_kkt(state) . diag(I, J_l(w_b))`` (``J_l`` = left
Jacobian of SO(3); the KKT Jacobian is ``Model.evaluate(...).J`` with ``sqrt(stability) M``
added to the coordinate block as in FIM_S), handed to IDA's dense solver. Models with more than
``DENSE_LIMIT`` unknowns are not integrated (FIM_S is used and the reason recorded): a sparse
path through scikit-sundae's SuperLU_MT needs the rotation-column pattern union and is not
implemented yet.

Consistent initial derivative: ``y' = -F_y^{-1} F_t`` with ``F_t`` by central differences in t
(``h = 1e-6 * max(1, |t|, interval)``) at fixed configuration.

Tolerances (``Param_Transient``; defaults in brackets): ``tol = min(integr_tol [1e-3],
dae_constr_tol [1e-6])`` is IDA's ``rtol``; ``atol`` = ``tol * L`` (translations), ``tol``
(rotations), ``tol * max(1, |lam0|)`` per multiplier kind. ``h_max`` [unbounded] (max_step),
``h_min`` [0] (min_step), ``h0_max`` [IDA's estimate] (first_step), ``max_order`` [5],
``dae_corrector_maxit`` [4] (max_nonlin_iters). ``dae_interpolation`` [TRUE]: output frames are
IDA's interpolants at the print times (steps are not limited by the print interval); FALSE:
IDA stops exactly at every print time (``tstop``) and the frame is a converged corrector.
An interpolated frame's imbalance, constraint error and worst equation (``frames/*`` and its
``iterations`` row, event ``ida``) are computed in ``QuasiStaticAnalysis.finish`` from the
frame's output evaluation (the one that feeds reactions, loads and stability): one residual +
Jacobian evaluation per output frame, not two.

FIM_S is used for the first frame (assembly + Newton), the last frame (Newton polish of IDA's
end state) and whenever IDA fails (the next output frame is solved with FIM_S from the last
accepted state, then IDA restarts); each fallback is recorded in ``iterations/event``
(``fallback_fim_s``) with its reason, and listed in the message.

Per-step table ``steps/*`` (one row per accepted internal IDA step): ``time``, ``step_size``,
``order`` (-1: not exposed by scikit-sundae 1.2), ``nonlinear_iterations`` (residual
evaluations of the step minus one), ``error_test_failures`` (retries of the step, i.e.
additional trial times; error-test and convergence failures together), ``jacobian_evaluations``,
``rebase`` (1 where IDA was re-initialised before the step).
"""
from __future__ import annotations

import numpy as np

from poise.errors import EvaluationError
from poise.model.rotation import expm_so3, se3_left_jacobian, wrap_angle
from poise.solvers.newton import FrameOutcome, newton
from poise.solvers.quasistatic import MIN_SUBSTEP_FRACTION, Progress, first_frame, fims_step
from poise.solvers.status import Status

REBASE_ANGLE = 1.0        # rad
DENSE_LIMIT = 1500        # unknowns
DEFAULT_DAE_CONSTR_TOL = 1e-6


def transient_settings(tr: dict, model) -> dict:
    def get(k, d=None):
        v = tr.get(k)
        return d if v is None else v
    tol = min(float(get("integr_tol", 1e-3)), float(get("dae_constr_tol", DEFAULT_DAE_CONSTR_TOL)))
    interp = get("dae_interpolation", True)
    if isinstance(interp, str):
        interp = interp.upper() not in ("FALSE", "NO", "0")
    return dict(tol=tol, h_max=float(get("h_max", 0.0) or 0.0),
                h_min=float(get("h_min", 0.0) or 0.0),
                h0=float(get("h0_max", 0.0) or 0.0),
                max_order=int(get("max_order", 5)),
                maxit=int(get("dae_corrector_maxit", 4)),
                interpolate=bool(interp))


class _Chart:
    """The map y -> State around a reference state, its Jacobian factor, and IDA callbacks."""

    def __init__(self, model, ref, eps, counters):
        self.model = model
        self.ref = ref.copy()
        self.eps = eps
        self.cnt = counters
        self.nres = 0
        self.njac = 0
        self.trial_times = set()

    def state(self, y, t):
        m, ref = self.model, self.ref
        st = ref.copy()
        st.t = float(t)
        st.pos = ref.pos + y[m.trans_idx].reshape(-1, 3)
        if len(m.rot_idx):
            w = y[m.rot_idx].reshape(-1, 3)
            st.rot[m.rot_body] = np.matmul(expm_so3(w), ref.rot[m.rot_body])
        st.lam = np.array(y[m.nq:], float)
        if m.n_extra:                   # scalar unknowns: algebraic, y = extra - ref.extra
            st.extra = ref.extra + y[m.extra_idx]
        if len(m.angle_I):
            p = m._principal_angles(st)
            st.angle = ref.angle + wrap_angle(p - ref.angle)
        return st

    def max_rotation(self, y):
        m = self.model
        if not len(m.rot_idx):
            return 0.0
        return float(np.max(np.linalg.norm(y[m.rot_idx].reshape(-1, 3), axis=1)))

    def F(self, st):
        ev = self.model.evaluate(st, need_jac=False)
        self.cnt.residuals += 1
        return np.concatenate([ev.r, ev.phi])

    def jac(self, y, t):
        m = self.model
        st = self.state(y, t)
        ev = m.evaluate(st, need_jac=True, eps_mass=self.eps)
        self.cnt.jacobians += 1
        J = ev.J.toarray() if hasattr(ev.J, "toarray") else np.array(ev.J)
        if len(m.rot_idx):
            w = y[m.rot_idx].reshape(-1, 3)
            Jl = se3_left_jacobian(w)
            Jr = J[:, m.rot_idx].reshape(J.shape[0], -1, 3)
            J[:, m.rot_idx] = np.einsum("nbi,bij->nbj", Jr, Jl).reshape(J.shape[0], -1)
        return J

    # IDA callbacks
    def resfn(self, t, y, yp, res):
        self.nres += 1
        self.trial_times.add(float(t))
        try:
            res[:] = self.F(self.state(y, t))
        except EvaluationError:
            res[:] = 1e30

    def jacfn(self, t, y, yp, res, cj, JJ):
        self.njac += 1
        try:
            JJ[:, :] = self.jac(y, t)
        except EvaluationError:
            JJ[:, :] = np.eye(len(y))

    def tangent(self, y, t, dt_scale):
        """Consistent y' = -F_y^{-1} F_t (F_t by central differences in t)."""
        h = 1e-6 * max(1.0, abs(t), dt_scale)
        Fp = self.F(self.state(y, t + h))
        Fm = self.F(self.state(y, t - h))
        Ft = (Fp - Fm) / (2 * h)
        try:
            J = self.jac(y, t)
            self.cnt.factorizations += 1
            yp = np.linalg.solve(J, -Ft)
            if not np.all(np.isfinite(yp)):
                raise np.linalg.LinAlgError
        except np.linalg.LinAlgError:
            yp = np.zeros(len(y))
        return yp


def _ida(chart, ts_settings, atol, t0, y0, yp0, interval):
    from sksundae.ida import IDA
    n = len(y0)
    opts = dict(algebraic_idx=list(range(n)), rtol=ts_settings["tol"], atol=atol,
                jacfn=chart.jacfn, linsolver="dense", max_order=ts_settings["max_order"],
                max_nonlin_iters=ts_settings["maxit"], max_num_steps=100000)
    opts["max_step"] = ts_settings["h_max"] if ts_settings["h_max"] > 0 else ts_settings["span"]
    if ts_settings["h_min"] > 0:
        opts["min_step"] = ts_settings["h_min"]
    if ts_settings["h0"] > 0:
        opts["first_step"] = min(ts_settings["h0"], interval)
    solver = IDA(chart.resfn, **opts)
    r = solver.init_step(t0, y0, yp0)
    if not r.success:
        raise RuntimeError(r.message)
    return solver


def run_fim_d(qs, state, index, notes):
    """FIM_D quasi-static run for :class:`~poise.solvers.quasistatic.QuasiStaticAnalysis`."""
    model, s = qs.model, qs.settings
    ts = qs.times(state)
    qs._times = ts
    state = state.copy()
    state.t = float(ts[0])
    state, out, qs.redundancy, n0, moved = first_frame(model, state, s, qs.history,
                                                       qs.counters, qs.redundancy)
    notes += n0
    frames, outcomes = [state], [out]
    time_indep = not model.depends_on_time()
    if not out.ok or len(ts) == 1:
        return qs.finish(frames, outcomes, index, "FIM_D", notes, moved, time_indep)
    if time_indep:
        notes.append("nothing in the scene depends on time: solved once, frame replicated")
        for t in ts[1:]:
            st = state.copy()
            st.t = float(t)
            frames.append(st)
            outcomes.append(FrameOutcome(out.status, 0, out.imbalance, out.error, "replicated"))
        return qs.finish(frames, outcomes, index, "FIM_D", notes, moved, time_indep)
    if model.N > DENSE_LIMIT:
        reason = (f"model too large for IDA's dense solver (N = {model.N} > {DENSE_LIMIT}); "
                  "FIM_S used")
        qs.history.add(0, 0, out.imbalance, out.error, np.nan, np.nan, reason, "fallback_fim_s")
        notes.append(reason)
        st, ar = qs.run_fim_s(state, index, notes)
        return st, ar

    tsd = transient_settings(qs.request.transient, model)
    tsd["span"] = max(float(ts[-1] - ts[0]), 1e-300)
    L = model.L
    eps = float(np.sqrt(s.stability))
    interval = float(np.min(np.diff(ts)))
    T_end = float(ts[-1])
    tol = tsd["tol"]
    steps = dict(time=[], step_size=[], order=[], nonlinear_iterations=[],
                 error_test_failures=[], jacobian_evaluations=[], rebase=[])
    fallbacks = []
    measured = {}                # frame index -> history row of an interpolated IDA frame
    prog = Progress(len(ts), "FIM_D", enabled=qs.progress_enabled)

    def atol_for(st):
        a = np.empty(model.N)
        a[:model.nq] = np.where(model.q_kind == 1, tol, tol * L)
        lam = np.abs(st.lam)
        for kind in (0, 1):
            sel = model.row_kind == kind
            if sel.any():
                a[model.nq:][sel] = tol * max(1.0, float(lam[sel].max()) if sel.any() else 1.0)
        return a

    def start(ref):
        chart = _Chart(model, ref, eps, qs.counters)
        y0 = np.concatenate([np.zeros(model.nq), ref.lam])
        yp0 = chart.tangent(y0, ref.t, interval)
        solver = _ida(chart, tsd, atol_for(ref), ref.t, y0, yp0, interval)
        return chart, solver

    k_out = 1
    ref = state
    rebased = 1
    chart = solver = None
    t_last, y_last = ref.t, None
    while k_out < len(ts):
        if solver is None:
            try:
                chart, solver = start(ref)
                t_last, y_last = ref.t, np.concatenate([np.zeros(model.nq), ref.lam])
            except (RuntimeError, ValueError) as e:
                solver = None
                reason = f"IDA could not start at t={ref.t:.9g}: {e}"
                ok = _fallback(qs, frames, outcomes, ts, k_out, reason, fallbacks, ref)
                k_out += 1
                if not ok:
                    break
                ref = frames[-1]
                continue
        stop = T_end if tsd["interpolate"] else float(ts[k_out])
        n0r, nj0 = chart.nres, chart.njac
        chart.trial_times = set()
        try:
            r = solver.step(stop, method="onestep", tstop=stop)
            ok_step = bool(r.success)
            msg = r.message
        except (RuntimeError, ValueError) as e:
            ok_step, msg = False, str(e)
        if not ok_step:
            reason = f"IDA failed after t={t_last:.9g}: {msg}"
            last = chart.state(y_last, t_last) if y_last is not None else frames[-1]
            solver = None
            ok = _fallback(qs, frames, outcomes, ts, k_out, reason, fallbacks, last)
            k_out += 1
            if not ok:
                break
            ref = frames[-1]
            rebased = 1
            continue
        steps["time"].append(r.t)
        steps["step_size"].append(r.t - t_last)
        steps["order"].append(-1)
        steps["nonlinear_iterations"].append(max(chart.nres - n0r - 1, 0))
        steps["error_test_failures"].append(max(len(chart.trial_times) - 1, 0))
        steps["jacobian_evaluations"].append(chart.njac - nj0)
        steps["rebase"].append(rebased)
        rebased = 0
        t_last, y_last = float(r.t), np.array(r.y, float)
        tol_t = 1e-12 * max(1.0, abs(T_end))
        # output frames passed by this step (interpolated), except the last one
        while k_out < len(ts) - 1 and ts[k_out] <= t_last + tol_t:
            tk = float(ts[k_out])
            if abs(tk - t_last) <= tol_t:
                yk = y_last
            else:
                yk = np.array(solver.step(tk).y, float)
            st = chart.state(yk, tk)
            # imbalance / constraint error / worst equation: from this frame's output
            # evaluation in finish() (the same state, one evaluation instead of two)
            measured[len(frames)] = len(qs.history.rows)
            qs.history.add(k_out, 0, np.nan, np.nan, np.nan, np.nan, "", "ida")
            frames.append(st)
            outcomes.append(FrameOutcome(Status.CONVERGED, 0, np.nan, np.nan, "ida"))
            k_out += 1
            prog.update(k_out)
        if k_out == len(ts) - 1 and t_last >= T_end - tol_t:
            # last frame: FIM_S polish of IDA's end state
            st = chart.state(y_last, T_end)
            st, o = newton(model, st, s, qs.history, k_out, qs.counters, event="final_fim_s")
            if not o.ok:
                reason = f"Newton polish of the last frame failed ({o.status.value})"
                ok = _fallback(qs, frames, outcomes, ts, k_out, reason, fallbacks,
                               chart.state(y_last, t_last))
                k_out += 1
                break
            frames.append(st)
            outcomes.append(o)
            k_out += 1
            break
        if chart.max_rotation(y_last) > REBASE_ANGLE:
            ref = chart.state(y_last, t_last)
            solver = None
            rebased = 1
    prog.close()
    if fallbacks:
        notes.append(f"{len(fallbacks)} FIM_S fallbacks: " + "; ".join(fallbacks[:3])
                     + (" ..." if len(fallbacks) > 3 else ""))
    nsteps = len(steps["time"])
    notes.append(f"IDA: {nsteps} steps, tol {tol:g}")
    extra = {f"steps/{k}": np.asarray(v, dtype=float if k in ("time", "step_size") else np.int64)
             for k, v in steps.items()}
    st, ar = qs.finish(frames, outcomes, index, "FIM_D", notes, moved, time_indep, extra=extra,
                       measured=measured)
    ar.attrs["ida_steps"] = nsteps
    ar.attrs["fim_s_fallbacks"] = len(fallbacks)
    ar.attrs["dae_tol"] = tol
    return st, ar


def _fallback(qs, frames, outcomes, ts, k_out, reason, fallbacks, last_state):
    """Solve output frame ``k_out`` with FIM_S from ``last_state``; record the reason."""
    model, s = qs.model, qs.settings
    fallbacks.append(reason)
    qs.history.add(k_out, 0, np.nan, np.nan, np.nan, np.nan, reason, "fallback_fim_s")
    hist = list(frames[-2:])
    if last_state.t > hist[-1].t:
        hist.append(last_state)
    min_dt = MIN_SUBSTEP_FRACTION * (ts[k_out] - ts[k_out - 1])
    st, o, _ = fims_step(model, hist, float(ts[k_out]), s, qs.history, qs.counters, k_out, min_dt)
    frames.append(st)
    outcomes.append(o)
    return o.ok
