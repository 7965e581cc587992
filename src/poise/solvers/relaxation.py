"""MKEAM relaxation: maximum kinetic energy attrition down to a stable equilibrium.

The model is made conservative and its constrained dynamics integrated from rest by RATTLE
(solvers/rattle.py); at every peak of the kinetic energy the velocities are zeroed and the
integration restarts (one peak = one iteration, :class:`~poise.solvers.ke_peak.KeIteration`),
so the iterates descend the potential and can only settle in a stable equilibrium. After
``HANDOVER_ITER`` iterations the descent continues by the inertia-controlled Newton of
solvers/descent.py when that verifiably reaches a stable point. :class:`Relaxation` is the
iterations' :class:`~poise.solvers.iterate.Solver` (budget ``max_num_iter`` iterations, and
``units`` integrator and descent steps), the MKEAM method's solve (solvers/mkeam.py) and the
fallback chain's last stage (:meth:`Relaxation.relax`). The method in detail, step-size
control and convergence: docs/mkeam.md.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from poise.core.errors import EvaluationError
from poise.core.wording import plural
from poise.solvers.energy import potential_energy
from poise.solvers.history import Row
from poise.solvers.iterate import Next, Solver, iterate
from poise.solvers.ke_peak import KeIteration
from poise.solvers.linalg import SingularMatrix
from poise.solvers.newton import initial_multipliers
from poise.solvers.reach import assemble
from poise.solvers.rattle import Dynamics
from poise.solvers.record import MkeamRun
from poise.solvers.stability import classify
from poise.solvers.descent import descend
from poise.solvers.stable import seek_stable
from poise.solvers.status import Status

PERTURB = 1e-3               # size of the kick off an unstable MKEAM point (x L / rad)
HANDOVER_ITER = 1            # KE iterations before the hand-over to the Newton descent
HANDOVER_NQ = 300            # models with more coordinates cut their first iterations ...
SPARSE_CHECK_NQ = 300        # above: stability sign by sparse inertia, not dense eigenvalues


@dataclass(frozen=True)
class Relaxing:
    """Where the MKEAM iterations stand: the last restart point ``state``, iterations done
    ``it``, the integrator step ``h``, kicks off unstable points, units of work spent,
    the restart points (pos, rot), whether the hand-over was tried, whether scalar unknowns
    were left free, the last ``max_dq``; ``end``: ``(state, status, message, iterations)``
    once decided; ``error``: an exception a step raised (its rows are kept)."""

    state: Any
    it: int = 0
    h: float = np.inf
    perturbs: int = 0
    used: int = 0
    iterates: tuple = ()
    handover_tried: bool = False
    extras_free: bool = False
    last_dq: float = np.nan
    end: tuple | None = None
    error: BaseException | None = None


class Relaxation(Solver):
    """MKEAM iterations on ``model`` from a state (the MKEAM method's solve and the last stage
    of the fallback chain). Rows go to ``history`` (through the loop), counts to ``data``
    (:class:`SolveData`, whose active rows the integration keeps). After a run:
    ``iterates``, ``used``, ``extras_free``, ``last_dq``, ``pe_start`` describe it."""

    out_of_budget = Status.MAX_ITERATIONS

    def __init__(self, model, settings, history, data, units=None):
        self.model = model
        # units of work (integration and descent steps): the fallback chain's share, else
        # limits.max_total_steps; ``used``: spent so far
        self.limited = units is not None
        self.limits = settings.limits
        cap = self.limits.max_total_steps
        self.units, self.used = max(1, min(int(units or cap), cap)), 0
        self.settings = settings
        self.history = history
        self.counters = data
        self.extras_free = False  # scalar unknowns MKEAM cannot determine (see HeldExtras)
        self.iterates = []        # restart points (pos, rot)
        self.report = None        # progress(label, done, total) of the iterations, or None
        self.pe_start = np.nan
        self.last_dq = np.nan
        self.dyn = Dynamics(model, data)

    def potential_energy(self, state):
        """Total potential energy, NaN when a force element is not conservative."""
        return potential_energy(self.model, state)

    def projected_stiffness_min(self, state):
        """(smallest eigenvalue, eigenvector in tangent coords) of the tangent stiffness projected
        on the constraint null space, coordinates scaled by ``q_scale`` (None if too large).
        Above ``SPARSE_CHECK_NQ`` coordinates only its sign is computed (sparse inertia of
        :func:`~poise.solvers.stability.classify`): -1 with an unstable mode, 0 otherwise."""
        m = self.model
        if m.nq > SPARSE_CHECK_NQ and not m.n_extra:
            # large models: the sign from the sparse inertia count of the classification
            # (the dense null space and eigenproblem below cost O(nq^3))
            info = classify(m, state, active=self.counters.active)
            if info.klass == "unstable":
                vec = info.vectors[0] if info.vectors else None
                return -1.0, vec
            if info.klass in ("stable", "neutral"):
                return 0.0, None
        if m.nq > 3000:
            return None, None
        ev = m.evaluate(state, need_jac=True, active=self.counters.active)
        J = ev.J.toarray() if sp.issparse(ev.J) else np.asarray(ev.J)
        D = np.diag(1.0 / m.q_scale)             # dq = D dz, dz in length units
        K = D @ J[:m.nq, :m.nq] @ D
        G = J[m.nq:, :m.nq][self.counters.mask(m)] @ D
        keep = np.arange(m.nq)
        if m.n_extra:
            # massless scalar unknowns (see Dynamics.solve_algebraic) are eliminated: reduced
            # stiffness K_cc - K_ca K_aa^-1 K_ac when K_aa is regular, else they are held
            a = np.setdiff1d(m.extra_idx, getattr(getattr(self, "dyn", None), "x_idx", []))
            keep = np.setdiff1d(keep, a)
            if len(a):
                Kaa = K[np.ix_(a, a)]
                sv = np.linalg.svd(Kaa, compute_uv=False)
                Kc = K[np.ix_(keep, keep)]
                Gc = G[:, keep]
                if sv.min() > 1e-10 * max(sv.max(), 1e-300):
                    X = np.linalg.solve(Kaa, K[np.ix_(a, keep)])
                    Kc = Kc - K[np.ix_(keep, a)] @ X
                    Gc = Gc - G[:, a] @ X
                K, G = Kc, Gc
            D = D[np.ix_(keep, keep)]
        N = sla.null_space(G) if G.shape[0] else np.eye(K.shape[0])
        if N.shape[1] == 0:
            return np.inf, None
        Kr = N.T @ (0.5 * (K + K.T)) @ N
        w, V = np.linalg.eigh(Kr)
        k = int(np.argmin(w))
        scale = max(float(np.max(np.abs(w))), 1e-300)
        vec = np.zeros(m.nq)
        vec[keep] = D @ (N @ V[:, k])
        return w[k] / scale, vec

    def max_dq(self, s0, s1):
        """Largest change from ``s0`` to ``s1``: translations / L, rotations and angles in rad,
        scalar unknowns relative."""
        m = self.model
        dt = float(np.max(np.linalg.norm(s1.pos - s0.pos, axis=1))) / m.L if m.nb else 0.0
        dr = 0.0
        if len(m.rot_body):
            Rr = np.matmul(s1.rot[m.rot_body], np.swapaxes(s0.rot[m.rot_body], 1, 2))
            # angle = atan2(sin, cos): accurate near zero, where arccos(cos) has a floor of
            # ~sqrt(eps) = 1.5e-8 rad (it kept tight max_dq_tol from ever being met)
            c = (np.einsum("nii->n", Rr) - 1.0) / 2.0
            sn = 0.5 * np.linalg.norm(np.stack([Rr[:, 2, 1] - Rr[:, 1, 2], Rr[:, 0, 2] - Rr[:, 2, 0],
                                                Rr[:, 1, 0] - Rr[:, 0, 1]], axis=1), axis=1)
            dr = float(np.max(np.arctan2(sn, c)))
        da = float(np.max(np.abs(s1.angle - s0.angle))) if len(s1.angle) else 0.0
        de = 0.0
        if m.n_extra:
            de = float(np.max(np.abs(s1.extra - s0.extra) / np.maximum(1.0, np.abs(s0.extra))))
        return max(dt, dr, da, de)

    def _resolve_extras(self, state):
        """Scalar unknowns (Control_Diff states, implicit variables, ...) have no mass: MKEAM
        holds them during each KE-attrition iteration and re-solves them at each restart
        (:class:`HeldExtras`). Returns ``(state, free)``; ``free``: their equations do not
        determine them, they stay held and are found by the final Newton polish."""
        m = self.model
        if not m.n_extra:
            return state, False
        ix = np.setdiff1d(m.extra_idx, self.dyn.x_idx)    # curve parameters move with RATTLE
        if not len(ix):
            return state, False
        return iterate(HeldExtras(m, self.settings, self.counters, ix), self.limits.extras_max_iter,
                       (), state)

    def _integrate(self, state, h, budget, origin):
        """One KE iteration from ``state`` within ``budget`` integrator steps
        (:class:`~poise.solvers.ke_peak.KeIteration`)."""
        return iterate(KeIteration(self.dyn, origin), budget, (), state, h)

    def run(self, state):
        """MKEAM iterations from ``state``. Returns ``(state, status, message, iterations)``:
        the last restart point and ``Status.CONVERGED`` when ``max_ke_tol`` / ``max_dq_tol``
        were met; otherwise why not (``max_num_iter`` or the integration budget:
        ``MAX_ITERATIONS``; a non-finite state: ``NONFINITE``; a body running away:
        ``DIVERGED``)."""
        return iterate(self, self.settings.max_num_iter, self.history, state)

    def init(self, state):
        state = state.copy()
        state.lam = np.where(self.counters.mask(self.model), state.lam, 0.0)
        self.iterates = [(state.pos.copy(), state.rot.copy())]
        self.pe_start = self.potential_energy(state)
        return Relaxing(state, iterates=tuple(self.iterates))

    def terminate(self, s):
        if s.error is not None:
            return True, Status.NONFINITE
        return s.end is not None, None if s.end is None else s.end[1]

    def step(self, s, left):
        rows, at = [], [s]
        try:
            return self._iteration(s, rows, at)
        except Exception as e:      # noqa: BLE001 - re-raised by postprocess, after its rows
            return Next(replace(at[0], error=e), 0, tuple(rows))

    def _iteration(self, s, rows, at):
        """One MKEAM iteration (``rows``: where its rows are collected; ``at[0]``: the state
        as far as it got, should a step raise)."""
        m, st = self.model, self.settings
        it = s.it + 1
        if self.report is not None:
            self.report("MKEAM", it - 1, st.max_num_iter)
        if s.used >= self.units:
            return Next(replace(s, end=(s.state, Status.MAX_ITERATIONS, (
                f"MKEAM used its integration budget ({self.units} steps) in "
                f"{plural(it - 1, 'iteration')} without meeting max_ke_tol / max_dq_tol"),
                it - 1)), 0)
        cap = self.limits.max_steps_per_iter
        if it <= HANDOVER_ITER and m.nq > HANDOVER_NQ and not m.n_extra:
            cap = self.limits.handover_cap     # a large model: restart early, then hand over
        if it <= HANDOVER_ITER and self.limited and not m.n_extra:
            cap = max(1, min(cap, self.units // 4))   # leave the hand-over most of it
        origin = s.iterates[0][0]
        land = self._integrate(s.state, s.h, min(cap, self.units - s.used), origin)
        peak, h = land.point, land.h
        s = at[0] = replace(s, it=it, h=h, used=s.used + land.steps)
        if land.failed:
            rows.append(self._row(it, np.nan, np.nan, land.message, peak, land.steps, np.nan))
            status = Status.MAX_ITERATIONS if land.status is Status.STEP_TOO_SMALL \
                else land.status
            return Next(replace(s, end=(s.state, status, f"MKEAM iteration {it}: "
                                        f"{land.message}", it)), 1, tuple(rows))
        new, free = self._resolve_extras(peak.state.copy())
        dq = self.max_dq(s.state, new)
        pe = self.potential_energy(new)
        ke = peak.ke
        rows.append(self._row(it, ke, dq, "", peak, land.steps, pe))
        s = at[0] = replace(s, state=new, last_dq=dq, extras_free=s.extras_free or free,
                            iterates=s.iterates + ((new.pos.copy(), new.rot.copy()),))
        met = ke <= st.max_ke_tol and dq <= st.max_dq_tol
        if it >= HANDOVER_ITER and not met and not s.handover_tried and not m.n_extra:
            fast, used = self._handover(new, h, s.used, rows, origin)
            s = at[0] = replace(s, handover_tried=True, used=used)
            if fast is not None:
                return Next(replace(s, end=(fast, Status.CONVERGED, "", it)), 1, tuple(rows))
        if not met:
            return Next(s, 1, tuple(rows))
        lam_state = initial_multipliers(m, new, self.counters)
        wmin, vec = self.projected_stiffness_min(lam_state)
        if wmin is not None and vec is not None and wmin < -1e-6 \
                and s.perturbs < self.limits.max_perturb:
            vs = vec * m.q_scale
            kick = PERTURB * m.L / max(float(np.max(np.abs(vs))), 1e-300)
            kicked = m.retract(new, kick * vec)
            kicked, _, _ = assemble(m, kicked, st, rows, 0, self.counters)
            return Next(replace(s, state=kicked, perturbs=s.perturbs + 1), 1, tuple(rows))
        return Next(replace(s, end=(new, Status.CONVERGED, "", it)), 1, tuple(rows))

    def postprocess(self, s, status, used):
        self.iterates = list(s.iterates)
        self.used, self.extras_free, self.last_dq = s.used, s.extras_free, s.last_dq
        if s.error is not None:
            raise s.error
        if s.end is not None:
            return s.end
        return s.state, status, (
            "MKEAM did not converge within max_num_iter iterations (raise max_num_iter or "
            "loosen max_ke_tol / max_dq_tol)"), self.settings.max_num_iter

    def _handover(self, state, h, used, rows, origin):
        """Newton-speed continuation of the descent from the restart point ``state`` (``used``
        units spent so far, rows collected in ``rows``, ``origin``: the run's start
        positions): the inertia-controlled Newton of
        :func:`poise.solvers.descent.descend` (potential energy non-increasing, steps on a
        positive-definite reduced stiffness), unstable end points left along their negative
        modes (:func:`~poise.solvers.stable.seek_stable`). The point is taken only if it is
        stable (neutral allowed) by the classification, its potential energy is not above
        ``state``'s, and one KE-attrition iteration from it (event ``mkeam-verify``) meets
        ``max_ke_tol`` and ``max_dq_tol``. Returns ``(point or None, units used)`` (None:
        MKEAM iterations continue from ``state`` as if nothing happened)."""
        m, s = self.model, self.settings
        s_any = replace(s, allow_neutral=True)
        budget = self.limits.handover_steps * s.max_num_iter
        if self.limited:   # the descent gets half the units left, its polishes and escapes half
            left = max(0, self.units - used)
            budget = left // 2
            s_any = replace(s_any, max_num_iter=max(1, left // 8))
            if budget < 1:
                return None, used
        pe0 = self.potential_energy(state)
        try:
            st = initial_multipliers(m, state, self.counters)
            rows.append(Row(0, 0, event="mkeam: handover to the inertia-controlled Newton "
                            "descent"))
            st, out, _, steps = descend(m, st, s_any, rows, 0, self.counters, budget)
            used += steps
            if out is None:
                return None, used
            info = classify(m, st, active=self.counters.active)
            if info.klass == "unstable":
                act = self.counters.active
                n = len(rows)
                st, out, info, _ = seek_stable(m, st, s_any, rows, 0, self.counters,
                                               info, lambda x: classify(m, x, active=act))
                used += len(rows) - n       # its escape and descent steps
            if not out.ok or info.klass not in ("stable", "neutral"):
                return None, used
            pe1 = self.potential_energy(st)
            if np.isfinite(pe0) and np.isfinite(pe1) and pe1 > pe0 + 1e-9 * max(abs(pe0), 1.0):
                return None, used
            left = max(0, self.units - used)
            if left <= 0:
                return None, used
            land = self._integrate(st, h, min(self.limits.max_steps_per_iter, left),
                                   origin)
            used += land.steps
            ke, dq = land.point.ke, self.max_dq(st, land.point.state)
            rows.append(Row(0, 0, np.nan, dq, dq, np.nan, land.message, "mkeam-verify"))
            if land.failed:
                return None, used
            if not (ke <= s.max_ke_tol and dq <= s.max_dq_tol):
                return None, used
            return st, used
        except (EvaluationError, SingularMatrix, ValueError, ArithmeticError):
            return None, used

    def relax(self, state):
        """MKEAM iterations from ``state`` (the fallback chain's ``mkeam`` stage). Returns
        ``(state, ok, message)``; ``ok`` when the MKEAM tolerances were met, else why not;
        :attr:`used`: the units of work spent (integration and descent steps)."""
        if not np.isfinite(self.model.L):
            return state, False, "the model size L is not finite"
        st = initial_multipliers(self.model, state, self.counters)
        st, status, msg, _n = self.run(st)
        return st, status.ok, msg

    def _row(self, it, ke, dq, worst, peak, steps, pe):
        # MKEAM_COLUMNS: kinetic_energy, peak_time, max_dq, potential_energy, integrator_steps
        return Row(0, it, np.nan, dq, dq, np.nan, worst, "mkeam",
                   mkeam=(ke, peak.t, dq, pe, steps))

    def record(self, mk_state) -> MkeamRun:
        """The run as a record: its restart points and the MKEAM point ``mk_state`` (its
        iterations are history rows)."""
        return mkeam_run(self.iterates, mk_state, self.pe_start)


def mkeam_run(iterates, mk_state, pe_start) -> MkeamRun:
    """:class:`~poise.solvers.record.MkeamRun` of an MKEAM run ending at ``mk_state``."""
    return MkeamRun(iterates=tuple(iterates),
                    position=mk_state.pos[None].copy(), orientation=mk_state.rot[None].copy(),
                    initial_potential_energy=pe_start)


@dataclass(frozen=True)
class Holding:
    """Where :class:`HeldExtras` stands: the point, and once it ended the point it gives
    and whether the unknowns were left free."""

    point: Any
    end: Any = None
    free: bool = False


class HeldExtras(Solver):
    """Newton on the massless scalar unknowns ``ix`` of a restart point with the bodies held,
    until their residual meets ``max_imbalance``; when ``d e / d s`` is singular (e.g. an
    integrator state ``y' = target - DX`` whose equation does not contain y) the point is
    returned unchanged and the unknowns reported free. Result: ``(point, free)``."""

    def __init__(self, model, settings, data, ix):
        self.model, self.settings, self.data, self.ix = model, settings, data, ix

    def init(self, state):
        self.start = state
        return Holding(state)

    def terminate(self, s):
        return s.end is not None, None if s.end is None else Status.CONVERGED

    def step(self, s, left):
        m, ix = self.model, self.ix
        ev = self.data.evaluate(m, s.point, "jacobian")
        J = ev.J.toarray() if sp.issparse(ev.J) else np.asarray(ev.J)
        Jss = J[np.ix_(ix, ix)]
        rs = ev.r[ix]
        sv = np.linalg.svd(Jss, compute_uv=False)
        if sv.min() <= 1e-10 * max(sv.max(), 1e-300):
            return Next(replace(s, end=self.start, free=True))
        if np.max(np.abs(rs)) <= self.settings.max_imbalance:
            return Next(replace(s, end=s.point))
        dq = np.zeros(m.nq)
        dq[ix] = np.linalg.solve(Jss, -rs)
        return Next(replace(s, point=m.retract(s.point, dq)))

    def postprocess(self, s, status, used):
        return (s.point if s.end is None else s.end), s.free
