"""MKEAM relaxation: maximum kinetic energy attrition down to a stable equilibrium.

The model is made conservative and its constrained dynamics integrated from rest by RATTLE
(solvers/rattle.py); at every peak of the kinetic energy the velocities are zeroed and the
integration restarts (one peak = one iteration), so the iterates descend the potential and can
only settle in a stable equilibrium. After ``HANDOVER_ITER`` iterations the descent continues by
the inertia-controlled Newton of solvers/stable.py when that verifiably reaches a stable point.
Budgets end every run with a status. :class:`Relaxation` is the MKEAM method's solve
(solvers/mkeam.py) and the fallback chain's last stage (:meth:`Relaxation.relax`). The method in detail,
step-size control and convergence: docs/mkeam.md.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from poise.core.errors import EvaluationError
from poise.core.wording import plural
from poise.solvers.energy import potential_energy
from poise.solvers.linalg import SingularMatrix
from poise.solvers.newton import initial_multipliers
from poise.solvers.reach import assemble
from poise.solvers.rattle import CONSTRAINT_TOL, Dynamics, RattlePoint, retract_flat
from poise.solvers.record import MkeamRun
from poise.solvers.stability import classify
from poise.solvers.stable import descend, seek_stable
from poise.solvers.status import Status

STEPS_PER_PERIOD = 20.0
MAX_TRANS_STEP = 0.1         # x L per integration step
MAX_ROT_STEP = 0.1           # rad per integration step
ENERGY_TOL = 1e-3            # relative energy error per step
MAX_STEPS_PER_ITER = 1000    # an iteration still accelerating after this many steps restarts
MAX_TOTAL_STEPS = 5000       # integration budget of one MKEAM run (all iterations)
REST_STEPS = 50              # steps with only noise-level energies: the iteration is at rest
NOISE_FACTOR = 10.0          # energy resolution: x work over the constraint tolerance
MAX_TRAVEL = 1e4             # x L: an iterate farther than this from the start is divergence
PEAK_TOL = 1e-3              # bracket of the peak relative to the step
PERTURB = 1e-3               # size of the kick off an unstable MKEAM point (x L / rad)
MAX_PERTURB = 3
HANDOVER_ITER = 1            # KE iterations before the hand-over to the Newton descent
HANDOVER_NQ = 300            # models with more coordinates cut their first iterations ...
HANDOVER_CAP = 20            # ... at this many integrator steps before the hand-over
HANDOVER_STEPS = 2           # its budget: this many x max_num_iter Newton steps
SPARSE_CHECK_NQ = 300        # above: stability sign by sparse inertia, not dense eigenvalues


class Relaxation:
    """MKEAM iterations on ``model`` from a state (the MKEAM method's solve and the last stage
    of the fallback chain). Rows go to ``history``, counts to ``data`` (:class:`SolveData`,
    whose active rows the integration keeps)."""

    def __init__(self, model, settings, history, data, units=None):
        self.model = model
        # units of work (integration and descent steps): the fallback chain's share, else
        # MAX_TOTAL_STEPS; ``used``: spent so far
        self.limited = units is not None
        self.units, self.used = max(1, min(int(units or MAX_TOTAL_STEPS), MAX_TOTAL_STEPS)), 0
        self.settings = settings
        self.history = history
        self.counters = data
        self.extras_free = False  # scalar unknowns MKEAM cannot determine (see _resolve_extras)
        self.iterates = []        # restart points (pos, rot)
        self.handover_tried = False
        self.report = None        # progress(label, done, total) of the iterations, or None
        self.pe_start = np.nan
        self.last_dq = np.nan
        self.dyn = Dynamics(model, data)

    def _step(self, dyn, a: RattlePoint, h):
        """One RATTLE step of size h from ``a``; returns the new RattlePoint or None (no convergence)."""
        m = self.model
        p_half = a.p + 0.5 * h * a.Q
        lam = a.lam.copy() if a.lam is not None else np.zeros(m.nc)
        state1 = None
        if m.nc:
            GT = a.G.T
            for _ in range(30):
                dq = h * (a.Minv @ (p_half - 0.5 * h * (GT @ lam)))
                state1 = retract_flat(m, a.state, dq)
                phi = dyn.phi(state1)
                if np.all(np.abs(phi) <= self.dyn.phi_tol):
                    break
                try:
                    lam = lam + (2.0 / (h * h)) * a.S.solve(phi)
                except SingularMatrix:
                    return None
            else:
                return None
            p_half = p_half - 0.5 * h * (GT @ lam)
        else:
            state1 = retract_flat(m, a.state, h * (a.Minv @ p_half))
        state1.lam = np.where(self.counters.mask(m), a.state.lam, 0.0)
        b = RattlePoint(dyn, state1, p_half, a.t + h)     # forces at q1 (lam for stiffness only)
        p1 = p_half + 0.5 * h * b.Q
        if m.nc:
            try:
                mu = b.S.solve(b.G @ (b.Minv @ p1))
            except SingularMatrix:
                return None
            p1 = p1 - b.G.T @ mu
            # reaction estimate for the geometric stiffness of the next step
            b.state.lam = np.where(self.counters.mask(m), (2.0 / h) * mu, 0.0)
        b.lam = lam
        b.p = p1
        b.v = b.Minv @ p1
        b.ke = 0.5 * float(p1 @ b.v)
        b.power = float(b.v @ b.Q)
        return b

    def _h_limit(self, a: RattlePoint):
        m = self.model
        # Gershgorin bound of the largest eigenvalue of M^-1/2 K M^-1/2 (mass-scaled rows)
        md = m.mass_diagonal(a.state)
        if len(self.dyn.x_idx):
            md[self.dyn.x_idx] = self.dyn.extra_mass(a.state)
        d = np.where(md > 0, 1.0 / np.sqrt(np.where(md > 0, md, 1.0)), 0.0)   # scalars: no mass
        K = a.K
        if sp.issparse(K):
            rs = np.asarray(abs(K) @ d).ravel() * d
        else:
            rs = (np.abs(K) @ d) * d
        w2 = float(np.max(rs)) if m.nq else 0.0
        h = np.inf
        if w2 > 0:
            h = 2 * np.pi / np.sqrt(w2) / STEPS_PER_PERIOD
        acc = a.Minv @ a.Q
        lim = np.where(m.q_kind == 1, MAX_ROT_STEP, MAX_TRANS_STEP * m.L)
        vel = np.abs(a.v)
        with np.errstate(divide="ignore", invalid="ignore"):
            hv = np.where(vel > 0, lim / vel, np.inf)
            ha = np.where(np.abs(acc) > 0, np.sqrt(2 * lim / np.abs(acc)), np.inf)
        return float(min(h, hv.min(initial=np.inf), ha.min(initial=np.inf)))

    def _iteration(self, dyn, state, h0, budget=MAX_STEPS_PER_ITER):
        """Integrate from rest until the first KE peak, or for at most ``budget`` steps (then
        the iteration restarts where it stands, still descending: a mode so soft that its
        peak is out of reach is left to the Newton polish). Returns (point, steps, h, msg);
        ``msg`` non-empty: the integration failed."""
        a = RattlePoint(dyn, state, np.zeros(self.model.nq), 0.0)
        h = min(h0, self._h_limit(a)) if np.isfinite(h0) else self._h_limit(a)
        if not np.isfinite(h):
            return a, 0, h, "no force acts (already at rest in equilibrium)"
        steps = 0
        escale = 0.0
        noise = self._energy_noise(a)
        while steps < budget:
            hl = self._h_limit(a)
            h = min(2.0 * h, hl) if np.isfinite(hl) else 2.0 * h
            while True:
                b = self._step(dyn, a, h)
                steps += 1
                if b is not None:
                    work = 0.5 * h * (a.power + b.power)
                    err = abs(b.ke - a.ke - work)
                    escale = max(escale, a.ke, b.ke, abs(work))
                    noise = max(noise, self._energy_noise(b))
                    if err <= max(ENERGY_TOL * escale, noise) or h < 1e-14 * max(1.0, a.t):
                        break
                h *= 0.5
                if h < 1e-300:
                    return a, steps, h, "integration step became too small"
                if steps >= budget:
                    return a, steps, h, ""
            bad = self._absurd(b)
            if bad:
                return b, steps, h, bad
            if steps >= REST_STEPS and escale <= noise:
                return b, steps, h, ""            # at rest within the integrator's resolution
            if b.power <= 0.0:
                if a.power <= 0.0:                 # never accelerated: at rest already
                    return (a if a.ke >= b.ke else b), steps, h, ""
                peak, n = self._locate_peak(dyn, a, b, h, min(12, budget - steps))
                return peak, steps + n, h, ""
            a = b
        return a, steps, h, ""

    def _energy_noise(self, a):
        """Energy the integrator cannot resolve at ``a``: the work of the applied forces over the
        position-constraint tolerance of a step (``CONSTRAINT_TOL`` x L per translation, x 1 rad
        per rotation), times ``NOISE_FACTOR``. Energy errors below it are accepted (halving the
        step does not reduce them), and an iteration whose energies all stay below it is at
        rest as far as the integration can tell."""
        m = self.model
        ql = np.where(m.q_kind == 0, m.L, 1.0)
        return NOISE_FACTOR * CONSTRAINT_TOL * float(np.sum(np.abs(a.Q) * ql))

    def _absurd(self, b):
        """Why the integrated point ``b`` cannot be a step towards an equilibrium ("" if it can):
        non-finite energy or pose, or a body farther than ``MAX_TRAVEL * L`` from the start."""
        m = self.model
        if not (np.isfinite(b.ke) and np.all(np.isfinite(b.state.pos))
                and np.all(np.isfinite(b.state.rot))):
            return "the integration produced a non-finite state (NaN/Inf)"
        if m.nb and float(np.max(np.abs(b.state.pos - self.iterates[0][0]))) > MAX_TRAVEL * m.L:
            return (f"a body moved more than {MAX_TRAVEL:g} L = {MAX_TRAVEL * m.L:.3g} from the "
                    "input configuration (nothing holds it: no equilibrium within reach)")
        return ""

    def _locate_peak(self, dyn, a, b, h, most=12):
        lo, hi = 0.0, h
        plo, phi_ = a.power, b.power
        best = b
        n = 0
        side = 0
        while hi - lo > PEAK_TOL * h and n < most:
            tau = (lo * phi_ - hi * plo) / (phi_ - plo)
            if not (lo < tau < hi):
                tau = 0.5 * (lo + hi)
            c = self._step(dyn, a, tau)
            n += 1
            if c is None:
                break
            best = c if c.ke >= best.ke or c.power > 0 else best
            if c.power > 0:
                lo, plo = tau, c.power
                if side == 1:
                    phi_ *= 0.5
                side = 1
            else:
                hi, phi_ = tau, c.power
                if side == -1:
                    plo *= 0.5
                side = -1
            if abs(c.power) <= 1e-12 * max(abs(a.power), abs(b.power)):
                best = c
                break
        return best, n

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

    def _dq(self, s0, s1):
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
        holds them during each KE-attrition iteration and re-solves them at each restart by
        Newton on their own equations with the bodies fixed. When those equations do not
        determine them (``d e / d s`` singular, e.g. an integrator state ``y' = target - DX``
        whose equation does not contain y) they stay held and are found by the final Newton
        polish (``self.extras_free``)."""
        m = self.model
        if not m.n_extra:
            return state
        ix = np.setdiff1d(m.extra_idx, self.dyn.x_idx)    # curve parameters move with RATTLE
        if not len(ix):
            return state
        st = state
        for _ in range(20):
            ev = self.counters.evaluate(m, st, "jacobian")
            J = ev.J.toarray() if sp.issparse(ev.J) else np.asarray(ev.J)
            Jss = J[np.ix_(ix, ix)]
            rs = ev.r[ix]
            sv = np.linalg.svd(Jss, compute_uv=False)
            if sv.min() <= 1e-10 * max(sv.max(), 1e-300):
                self.extras_free = True
                return state
            if np.max(np.abs(rs)) <= self.settings.max_imbalance:
                return st
            dq = np.zeros(m.nq)
            dq[ix] = np.linalg.solve(Jss, -rs)
            st = m.retract(st, dq)
        return st

    def iterate(self, state):
        """MKEAM iterations from ``state``. Returns ``(state, status, message, iterations)``:
        the last restart point and ``Status.CONVERGED`` when ``max_ke_tol`` / ``max_dq_tol``
        were met; otherwise why not (``max_num_iter`` or the ``MAX_TOTAL_STEPS`` integration
        budget: ``MAX_ITERATIONS``; a non-finite state: ``NONFINITE``; a body running away:
        ``DIVERGED``)."""
        m, s = self.model, self.settings
        dyn = self.dyn
        state = state.copy()
        state.lam = np.where(self.counters.mask(m), state.lam, 0.0)
        self.iterates = [(state.pos.copy(), state.rot.copy())]
        pe0 = self.potential_energy(state)
        self.pe_start = pe0
        h = np.inf
        perturbs = 0
        self.last_dq = np.nan
        t_total = 0.0
        for it in range(1, s.max_num_iter + 1):
            if self.report is not None:
                self.report("MKEAM", it - 1, s.max_num_iter)
            used = self.used
            if used >= self.units:
                return state, Status.MAX_ITERATIONS, (
                    f"MKEAM used its integration budget ({self.units} steps) in "
                    f"{plural(it - 1, 'iteration')} without meeting max_ke_tol / max_dq_tol"), it - 1
            cap = MAX_STEPS_PER_ITER
            if it <= HANDOVER_ITER and m.nq > HANDOVER_NQ and not m.n_extra:
                cap = HANDOVER_CAP       # a large model: restart early, then hand over
            if it <= HANDOVER_ITER and self.limited and not m.n_extra:
                cap = max(1, min(cap, self.units // 4))   # leave the hand-over most of it
            peak, steps, h, msg = self._iteration(dyn, state, h,
                                                  min(cap, self.units - used))
            self.used += steps
            if msg and "already at rest" not in msg:
                self._row(it, np.nan, np.nan, msg, peak, steps, np.nan, "mkeam")
                status = (Status.NONFINITE if "non-finite" in msg else
                          Status.DIVERGED if "moved more than" in msg else Status.MAX_ITERATIONS)
                return state, status, f"MKEAM iteration {it}: {msg}", it
            new = self._resolve_extras(peak.state.copy())
            dq = self._dq(state, new)
            t_total += peak.t
            pe = self.potential_energy(new)
            ke = peak.ke
            self.last_dq = dq
            self._row(it, ke, dq, "", peak, steps, pe, "mkeam")
            self.iterates.append((new.pos.copy(), new.rot.copy()))
            state = new
            if (it >= HANDOVER_ITER and not (ke <= s.max_ke_tol and dq <= s.max_dq_tol)
                    and not self.handover_tried and not m.n_extra):
                self.handover_tried = True
                fast = self._handover(state, h)
                if fast is not None:
                    return fast, Status.CONVERGED, "", it
            if ke <= s.max_ke_tol and dq <= s.max_dq_tol:
                lam_state = initial_multipliers(m, state, self.counters)
                wmin, vec = self.projected_stiffness_min(lam_state)
                if wmin is not None and vec is not None and wmin < -1e-6 and perturbs < MAX_PERTURB:
                    perturbs += 1
                    vs = vec * m.q_scale
                    kick = PERTURB * m.L / max(float(np.max(np.abs(vs))), 1e-300)
                    state = m.retract(state, kick * vec)
                    st2, _, _ = assemble(m, state, s, self.history, 0, self.counters)
                    state = st2
                    continue
                return state, Status.CONVERGED, "", it
            h = h if np.isfinite(h) else np.inf
        return state, Status.MAX_ITERATIONS, (
            "MKEAM did not converge within max_num_iter iterations (raise max_num_iter or loosen "
            "max_ke_tol / max_dq_tol)"), s.max_num_iter

    def _handover(self, state, h):
        """Newton-speed continuation of the descent from the restart point ``state``: the
        inertia-controlled Newton of :func:`poise.solvers.stable.descend` (potential energy
        non-increasing, steps on a positive-definite reduced stiffness), unstable end points left
        along their negative modes (:func:`~poise.solvers.stable.seek_stable`). The point is
        taken only if it is stable (neutral allowed) by the classification, its potential energy
        is not above ``state``'s, and one KE-attrition iteration from it (event
        ``mkeam-verify``) meets ``max_ke_tol`` and ``max_dq_tol``. Returns it or None (MKEAM
        iterations continue from ``state`` as if nothing happened)."""
        m, s = self.model, self.settings
        s_any = replace(s, allow_neutral=True)
        budget = HANDOVER_STEPS * s.max_num_iter
        if self.limited:   # the descent gets half the units left, its polishes and escapes half
            budget = self._left() // 2
            s_any = replace(s_any, max_num_iter=max(1, self._left() // 8))
            if budget < 1:
                return None
        pe0 = self.potential_energy(state)
        try:
            st = initial_multipliers(m, state, self.counters)
            self.history.add(0, 0, np.nan, np.nan, event="mkeam: handover to the "
                             "inertia-controlled Newton descent")
            st, out, _, steps = descend(m, st, s_any, self.history, 0, self.counters, budget)
            self.used += steps
            if out is None:
                return None
            info = classify(m, st, active=self.counters.active)
            if info.klass == "unstable":
                act = self.counters.active
                rows = len(self.history)
                st, out, info, _ = seek_stable(m, st, s_any, self.history, 0, self.counters,
                                               info, lambda x: classify(m, x, active=act))
                self.used += len(self.history) - rows       # its escape and descent steps
            if not out.ok or info.klass not in ("stable", "neutral"):
                return None
            pe1 = self.potential_energy(st)
            if np.isfinite(pe0) and np.isfinite(pe1) and pe1 > pe0 + 1e-9 * max(abs(pe0), 1.0):
                return None
            if self._left() <= 0:
                return None
            peak, steps, _, msg = self._iteration(self.dyn, st, h, min(MAX_STEPS_PER_ITER,
                                                                       self._left()))
            self.used += steps
            ke, dq = peak.ke, self._dq(st, peak.state)
            self.history.add(0, 0, np.nan, dq, dq, np.nan, msg, "mkeam-verify")
            if msg and "already at rest" not in msg:
                return None
            if not (ke <= s.max_ke_tol and dq <= s.max_dq_tol):
                return None
            return st
        except (EvaluationError, SingularMatrix, ValueError, ArithmeticError):
            return None

    def _left(self) -> int:
        return max(0, self.units - self.used)     # units not spent yet

    def relax(self, state):
        """MKEAM iterations from ``state`` (the fallback chain's ``mkeam`` stage). Returns
        ``(state, ok, message)``; ``ok`` when the MKEAM tolerances were met, else why not;
        :attr:`used`: the units of work spent (integration and descent steps)."""
        if not np.isfinite(self.model.L):
            return state, False, "the model size L is not finite"
        st = initial_multipliers(self.model, state, self.counters)
        st, status, msg, _n = self.iterate(st)
        return st, status.ok, msg

    def _row(self, it, ke, dq, worst, peak, steps, pe, event):
        # MKEAM_COLUMNS: kinetic_energy, peak_time, max_dq, potential_energy, integrator_steps
        self.history.add(0, it, np.nan, dq, dq, np.nan, worst, event,
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
