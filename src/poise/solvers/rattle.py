"""RATTLE pieces of MKEAM's integration: forces, mass and constraints at a state.

:class:`Dynamics` evaluates ``(Q, G, K, M^-1)`` and the constraint values (the active rows of the
solve's data), :func:`retract_flat` moves a state on R^3 x SO(3) (the update for which RATTLE
is symplectic), :class:`RattlePoint` is one integrator state and :func:`rattle_step` one step
(its position half a :class:`ConstraintSolve`). The method: docs/mkeam.md.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import scipy.sparse as sp

from poise.elements.rotation import expm_so3, wrap_angle
from poise.solvers.iterate import Next, Solver, iterate
from poise.solvers.linalg import SingularMatrix
from poise.solvers.limits import LIMITS
from poise.solvers.status import Status

CONSTRAINT_TOL = 1e-11       # relative position-constraint tolerance in the RATTLE solve


class Dynamics:
    """Mass matrix, forces and constraint Jacobian of a model at a state."""

    def __init__(self, model, cnt):
        self.m = model
        self.cnt = cnt
        if np.any(model.body_mass <= 0):
            i = int(np.argmin(model.body_mass))
            raise ValueError(f"MKEAM needs a positive mass for every moving body; body id "
                             f"{model.body_id[i]} has mass {model.deck_mass()[i]:g}")
        self.phi_tol = np.where(model.row_kind == 1, 1.0, model.L) * CONSTRAINT_TOL
        rb = model.body_off[model.rot_body][:, None] + 3 + np.arange(3)       # (nr, 3)
        self._mi_r = np.concatenate([model.trans_idx,
                                     np.repeat(rb[:, :, None], 3, 2).ravel()]).astype(int)
        self._mi_c = np.concatenate([model.trans_idx,
                                     np.repeat(rb[:, None, :], 3, 1).ravel()]).astype(int)
        # curve/surface parameters (families with ``inertial_extras``) move with a fictitious
        # mass so RATTLE carries them with the bodies (see extra_mass); other scalar unknowns
        # stay massless (held per iteration, relaxation.HeldExtras)
        xi = [model.extra_off + fam.scols[fam.scols >= 0] for fam in model.families
              if getattr(fam, "inertial_extras", False)]
        self.x_idx = np.unique(np.concatenate(xi)).astype(int) if xi else np.zeros(0, int)
        self.x_mass = None

    def minv(self, state):
        """Inverse mass as a (nq, nq) dense or sparse block-diagonal matrix."""
        m = self.m
        _, Jg = m.mass_blocks(state)
        vals = [np.repeat(1.0 / m.body_mass, 3)]
        if len(m.rot_body):
            vals.append(np.linalg.inv(Jg).ravel())
        r, c = self._mi_r, self._mi_c
        if len(self.x_idx):
            vals.append(1.0 / self.extra_mass(state))
            r = np.concatenate([r, self.x_idx])
            c = np.concatenate([c, self.x_idx])
        v = np.concatenate(vals)
        if m.dense:
            Mi = np.zeros((m.nq, m.nq))
            Mi[r, c] = v
            return Mi
        return sp.csr_matrix((v, (r, c)), shape=(m.nq, m.nq))

    def extra_mass(self, state):
        """Fictitious masses of the curve/surface parameters, fixed at the first call:
        ``m_min * |d Phi / d s|^2`` (the smallest body mass times the squared length of the
        parameter's constraint-Jacobian column: the mass of the lightest body sliding along the
        curve at the start), floored at ``m_min * (1e-3 L)^2``. Any positive value leaves the
        equilibria (and the potential) unchanged; it only shapes the relaxation path."""
        if self.x_mass is None:
            m = self.m
            ev = m.evaluate(state, need_jac=True, active=self.cnt.active)
            G = ev.J[m.nq:, :m.nq]
            G = G.toarray() if sp.issparse(G) else np.asarray(G)
            col = np.sum(G[:, self.x_idx] ** 2, axis=0)
            mmin = float(np.min(m.body_mass))
            self.x_mass = mmin * np.maximum(col, (1e-3 * m.L) ** 2)
        return self.x_mass

    extras_free = False

    def solve_algebraic(self, state, ev):
        """Massless scalar unknowns (Control_Diff states, implicit / user variables) are
        algebraic unknowns of the integration: at every force evaluation they are solved from
        their own equations at the current body configuration (:class:`AlgebraicSolve`,
        ``state.extra`` updated), so the bodies move under the forces of the reduced system.
        Where ``d e / d s`` is singular (an integrator state whose equation does not contain
        it) they are held and left to the final Newton polish (``extras_free``)."""
        ix = np.setdiff1d(self.m.extra_idx, self.x_idx)
        if not len(ix):
            return ev
        extra, ev, status = iterate(AlgebraicSolve(self, state, ix), LIMITS.extras_max_iter,
                                    (), ev)
        if status is Status.SINGULAR_JACOBIAN:
            self.extras_free = True
        state.extra = extra
        return ev

    def at(self, state):
        """(Q, G, K, Minv) at ``state`` (uses ``state.lam`` for the geometric stiffness)."""
        m = self.m
        ev = self.cnt.evaluate(m, state, "jacobian")
        if m.n_extra:
            ev = self.solve_algebraic(state, ev)
        J = ev.J
        G = J[m.nq:, :m.nq]
        K = J[:m.nq, :m.nq]
        Q = G.T @ state.lam - ev.r
        return np.asarray(Q).ravel(), G, K, self.minv(state)

    def schur(self, G, Minv):
        m = self.m
        S = G @ Minv @ G.T
        inact = (~self.cnt.mask(m)).astype(float)
        if sp.issparse(S):
            S = (S + sp.diags(inact)).tocsr()
        else:
            S = np.asarray(S) + np.diag(inact)
        return self.cnt.factor(S, equilibrate=True)   # masses 1e-12 next to 1: rows decades apart

    def phi(self, state):
        """Constraint values only (no force element is evaluated; inactive rows read 0)."""
        return self.cnt.evaluate(self.m, state, "phi")


def retract_flat(model, state, dq):
    """``state (+) dq`` on R^3 x SO(3): each CG moves on a straight line, each body rotates about
    its CG (``R <- expm(skew(dtheta)) R``); continuous angles are unwrapped (steps are small).

    This, not the screw motion of :meth:`Model.retract`, is the configuration update for which
    RATTLE is symplectic: with the screw update a hinged body's momentum is not turned by the
    constraint impulse and the velocity projection bleeds kinetic energy at first order in h.
    """
    new = state.copy()
    dq = np.asarray(dq, float)
    new.pos = state.pos + dq[model.trans_idx].reshape(-1, 3)
    rb = model.rot_body
    if len(rb):
        E = expm_so3(dq[model.rot_idx].reshape(-1, 3))
        new.rot[rb] = np.matmul(E, state.rot[rb])
        model.track_rotation(new, state, dq[model.rot_idx].reshape(-1, 3))
    if len(model.angle_I):
        p = model._principal_angles(new)
        new.angle = state.angle + wrap_angle(p - state.angle)
    if model.n_extra:
        new.extra = state.extra + dq[model.extra_idx]
    return new


class RattlePoint:
    """Integrator state: configuration, momenta and cached quantities at the configuration."""

    __slots__ = ("state", "p", "Q", "G", "K", "Minv", "S", "v", "ke", "power", "t", "lam")

    def __init__(self, dyn, state, p, t):
        self.state = state
        self.p = p
        self.t = t
        self.Q, self.G, self.K, self.Minv = dyn.at(state)
        self.S = dyn.schur(self.G, self.Minv) if dyn.m.nc else None
        self.v = self.Minv @ p
        self.ke = 0.5 * float(p @ self.v)
        self.power = float(self.v @ self.Q)
        self.lam = None


@dataclass(frozen=True)
class _Algebraic:
    """Where :class:`AlgebraicSolve` stands: the scalar unknowns, the evaluation there."""

    extra: np.ndarray
    ev: Any
    done: Status | None = None


class AlgebraicSolve(Solver):
    """Newton on the massless scalar unknowns ``ix`` of ``state`` (bodies held) from the
    evaluation ``ev`` there: ends converged when the update is negligible, with
    ``singular_jacobian`` when ``d e / d s`` is singular (they are then held), else out of
    budget (the last iterate kept). Result: ``(extra, evaluation, status)``."""

    def __init__(self, dyn, state, ix):
        self.dyn, self.state, self.ix = dyn, state, ix

    def init(self, ev):
        return _Algebraic(self.state.extra, ev)

    def terminate(self, s):
        return s.done is not None, s.done

    def step(self, s, left):
        m, ix = self.dyn.m, self.ix
        J = s.ev.J.toarray() if sp.issparse(s.ev.J) else np.asarray(s.ev.J)
        Jss = J[np.ix_(ix, ix)]
        sv = np.linalg.svd(Jss, compute_uv=False)
        if sv.min() <= 1e-10 * max(sv.max(), 1e-300):
            return Next(replace(s, done=Status.SINGULAR_JACOBIAN))
        ds = np.linalg.solve(Jss, -s.ev.r[ix])
        extra = s.extra.copy()
        extra[ix - m.extra_off] += ds
        at = self.state.copy()
        at.extra = extra
        ev = self.dyn.cnt.evaluate(m, at, "jacobian")
        small = np.all(np.abs(ds) <= 1e-12 * (1.0 + np.abs(extra[ix - m.extra_off])))
        return Next(replace(s, extra=extra, ev=ev, done=Status.CONVERGED if small else None))

    def postprocess(self, s, status, used):
        return s.extra, s.ev, status


@dataclass(frozen=True)
class _Impulse:
    """Where :class:`ConstraintSolve` stands: the multipliers and the point they give."""

    lam: np.ndarray
    point: Any = None
    done: Status | None = None


class ConstraintSolve(Solver):
    """The position half of a RATTLE step of size ``h`` from ``a`` (half-step momenta
    ``p_half``): multipliers ``lam`` such that ``retract(q, h M^-1 (p_half - h/2 G^T lam))``
    meets the constraints to ``Dynamics.phi_tol``, by Newton on ``lam`` with the start
    point's Schur complement. Ends converged, ``singular_jacobian`` (that complement), or
    out of budget. Result: ``(lam, point, status)``."""

    def __init__(self, dyn, a, h, p_half):
        self.dyn, self.a, self.h, self.p_half = dyn, a, h, p_half
        self.GT = a.G.T

    def init(self, lam):
        return _Impulse(lam)

    def terminate(self, s):
        return s.done is not None, s.done

    def step(self, s, left):
        a, h, dyn = self.a, self.h, self.dyn
        dq = h * (a.Minv @ (self.p_half - 0.5 * h * (self.GT @ s.lam)))
        point = retract_flat(dyn.m, a.state, dq)
        phi = dyn.phi(point)
        if np.all(np.abs(phi) <= dyn.phi_tol):
            return Next(replace(s, point=point, done=Status.CONVERGED))
        try:
            lam = s.lam + (2.0 / (h * h)) * a.S.solve(phi)
        except SingularMatrix:
            return Next(replace(s, point=point, done=Status.SINGULAR_JACOBIAN))
        return Next(replace(s, lam=lam, point=point))

    def postprocess(self, s, status, used):
        return s.lam, s.point, status


def rattle_step(dyn, a: RattlePoint, h):
    """One RATTLE step of size ``h`` from ``a``: the new :class:`RattlePoint`, or None when
    its constraint solve does not converge."""
    m = dyn.m
    p_half = a.p + 0.5 * h * a.Q
    lam = a.lam.copy() if a.lam is not None else np.zeros(m.nc)
    if m.nc:
        lam, state1, status = iterate(ConstraintSolve(dyn, a, h, p_half),
                                      LIMITS.rattle_max_iter, (), lam)
        if not status.ok:
            return None
        p_half = p_half - 0.5 * h * (a.G.T @ lam)
    else:
        state1 = retract_flat(m, a.state, h * (a.Minv @ p_half))
    state1.lam = np.where(dyn.cnt.mask(m), a.state.lam, 0.0)
    b = RattlePoint(dyn, state1, p_half, a.t + h)     # forces at q1 (lam for stiffness only)
    p1 = p_half + 0.5 * h * b.Q
    if m.nc:
        try:
            mu = b.S.solve(b.G @ (b.Minv @ p1))
        except SingularMatrix:
            return None
        p1 = p1 - b.G.T @ mu
        # reaction estimate for the geometric stiffness of the next step
        b.state.lam = np.where(dyn.cnt.mask(m), (2.0 / h) * mu, 0.0)
    b.lam = lam
    b.p = p1
    b.v = b.Minv @ p1
    b.ke = 0.5 * float(p1 @ b.v)
    b.power = float(b.v @ b.Q)
    return b
