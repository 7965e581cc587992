"""The evaluation engine: one pass over the element families for F >= 1 frames of a model.

:func:`evaluate` computes, by its ``what`` option, the residual ``[Phi_q^T lam - Q; Phi]``
(``"residual"``), with the KKT Jacobian (``"jacobian"``; ``"defer"``: assembled later by
:func:`jacobian`; ``"phi_q"``: its constraint blocks alone), the constraint values only
(``"phi"``: no force element is called) or the potential energy (``"energy"``). One state is
one frame (the Jacobian through the model's fixed-pattern assembler, sparse or dense); a list
of states is ``F`` frames evaluated together (tileable families tiled across frames by
:mod:`poise.model.frame_batch` and called once, dense ``(F, N, N)`` Jacobians scattered with
one ``bincount``). Every family goes through :func:`_family_pass`, the only loop over the
families; what differs per option is how its outputs are reduced; the energy sums what the
element types declare (``Model.energy_terms``, :mod:`poise.elements.registry`). Active rows
come from the caller's solve data (``active``); element loads of the kept slot data:
:mod:`poise.elements.loads`; forces reading constraint reactions: the model's
``reaction_feed`` (:mod:`poise.elements.reaction_feed`), single frames. What an evaluation
keeps between calls (assembly buffer, tiled families, kernels' caches) is in the caller's
:class:`~poise.model.workspace.Workspace`, never on the model.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial

import numpy as np

from poise.core import phases
from poise.core.lean import all_finite, einsum, where
from poise.core.errors import EvaluationError
from poise.elements.chunked import (constraint_values, local_residuals, rows, spans,
                                    tangent_values)
from poise.expr import EvalContext
from poise.elements.kernel import (constraint_jacobian_local, dense_g,
                                   local_pattern, local_residual_tangent, local_tangent,
                                   slot_kinematics, slot_points,
                                   tangent_compact)
from poise.model.assembly import Few, Scatter, Zeros
from poise.model.energy import potential_energy
from poise.model.frame_batch import add_block, stack_ext, tiles
from poise.model.nonfinite import family_nonfinite, nonfinite_message
from poise.model.recent import RecentEvaluations
from poise.model.small_dense import SmallTerms
from poise.model.workspace import Workspace

WHAT = ("residual", "jacobian", "defer", "phi_q", "phi", "energy")


@dataclass
class Evaluation:
    """Residual and Jacobian at a state.

    Attributes
    ----------
    r : (nq,) generalised force imbalance ``Phi_q^T lam - Q`` (force rows then moment rows per body)
    phi : (nc,) constraint values (inactive/redundant rows included, unscaled)
    J : (N, N) KKT Jacobian (dense ndarray or CSR), N = nq + nc, or None
    """

    r: np.ndarray
    phi: np.ndarray
    J: object = None
    _pending: object = field(default=None, repr=False)   # deferred Jacobian (:func:`jacobian`)
    workspace: object = field(default=None, repr=False)  # the solve's (assembly)
    _coupling: list = field(default_factory=list, repr=False)  # reaction feed d r / d lambda
    items: list = field(default=None, repr=False)   # per-family slot data (keep=True)
    inertia: object = field(default=None, repr=False)  # world inertias its Jacobian used
    scaled: tuple = field(default=None, repr=False)  # the residual by tolerance (newton.scaled)


@dataclass
class FrameEvaluation:
    """Residuals and Jacobians of ``F`` frames (all constraint rows active).

    Attributes
    ----------
    r : (F, nq) generalised force imbalance per frame
    phi : (F, nc) constraint values per frame
    J : (F, N, N) dense KKT Jacobians (``None`` for ``what="residual"``)
    items : list of ``(family, kin, rho, phi_y)`` over the stacked instances (frame-major:
        instance ``f * n + i``), the ``family`` a tiled copy whose ``owner`` / ``crow`` are
        shifted per frame (output group size / ``nc``) for :func:`poise.elements.loads.loads_of`
    """

    r: np.ndarray
    phi: np.ndarray
    J: np.ndarray | None
    items: list = field(default_factory=list)


def evaluate(model, states, what: str = "jacobian", *, active=None, keep: bool = False,
             eps_mass: float = 0.0, workspace: Workspace | None = None):
    """Evaluate one frame (``states`` a State) or ``F`` frames (a sequence of States).

    what : ``"residual"``, ``"jacobian"``, ``"defer"`` (residual now, element data kept so that
        :func:`jacobian` assembles the Jacobian later without calling the kernels again:
        line-search trials), ``"phi_q"`` (no stiffness tangent in the coordinate block: for
        readers of ``Phi_q`` alone; its other blocks are ``"jacobian"``'s), ``"phi"``, ``"energy"``.
    active : (nc,) bool or None (all rows). Inactive (redundant) rows read 0 in ``phi``, have
        no constraint Jacobian and 1 on their multiplier diagonal. Frames: all rows active.
    keep : keep per-family slot data (``ev.items``: ``(family, kin, rho, phi_y)``, ``phi_y``
        None for force families) for element loads (always kept for frames).
    eps_mass : multiple of the mass matrix added to the coordinate block of the Jacobian only.
    workspace : the solve's :class:`~poise.model.workspace.Workspace` (a fresh one when None:
        nothing is kept between calls).

    Returns an :class:`Evaluation` (one frame) or :class:`FrameEvaluation` (frames); ``"phi"``:
    ``(nc,)`` or ``(F, nc)``; ``"energy"``: a float (NaN when a force element is not
    conservative) or ``(F,)``.
    """
    if what not in WHAT:
        raise ValueError(f"evaluate: what={what!r}, expected one of {WHAT}")
    single = hasattr(states, "pos")
    ws = Workspace() if workspace is None else workspace
    if what == "energy":             # summed per frame: one frame at a time
        if single:
            return potential_energy(model, _Frames(model, [states], True, ws))
        return np.array([potential_energy(model, _Frames(model, [s], True, ws)) for s in states])
    t_start = phases.now()
    try:
        fr = _Frames(model, [states] if single else list(states), single, ws)
        if what == "phi":
            return _phi(model, fr, active)
        if not single:
            return _many_frames(model, fr, what == "jacobian")
        ev = _one_frame(model, fr, what, active, keep, eps_mass)
    finally:
        phases.add("evaluate", phases.now() - t_start)
    if what in ("jacobian", "phi_q"):
        jacobian(model, ev)          # timed as "assemble"
    return ev


class _Frames:
    """Marker kinematics of the frames and the kernel call of one family over all of them."""

    def __init__(self, model, states, single, workspace):
        self.model, self.states, self.single = model, states, single
        self.ws = workspace
        self.F = F = len(states)
        self.dg = None                    # reaction channels' (F, T), global (reaction feed)
        nb = model.nb
        if single:               # P, A, pos and ctx on first use (:meth:`__getattr__`)
            self.mb = model.marker_body
            self.lam = states[0].lam
            self.kins = None         # a small model's slot kinematics, all at once (first call)
            return
        nm = len(model.marker_id)
        mb = model.marker_body
        posx = np.zeros((F, nb + 1, 3))
        rotx = np.zeros((F, nb + 1, 3, 3))
        posx[:, :nb] = np.stack([s.pos for s in states])
        rotx[:, :nb] = np.stack([s.rot for s in states])
        rotx[:, nb] = np.eye(3)
        P = posx[:, mb] + np.einsum("fnij,nj->fni", rotx[:, mb], model.marker_s0)
        A = np.matmul(rotx[:, mb], model.marker_A0)
        self.Pfr, self.Afr = P, A
        self.P = P.reshape(F * nm, 3)
        self.A = A.reshape(F * nm, 3, 3)
        self.pos = posx.reshape(F * (nb + 1), 3)
        self.mb = (mb[None] + ((nb + 1) * np.arange(F))[:, None]).ravel()
        self.lam2 = np.stack([s.lam for s in states]) if model.nc else np.zeros((F, 0))
        self.lam = self.lam2.ravel()
        ang = np.concatenate([s.angle for s in states]) if len(model.angle_I) else np.zeros(0)
        ext = np.concatenate([s.extra for s in states]) if model.n_extra else None
        # tiled families see every frame at once: one time per frame, stacked marker tables
        self.ctx = EvalContext(t=np.array([s.t for s in states], float), angle=ang, P=self.P,
                               A=self.A, extra=ext, workspace=workspace)
        self.ctxs = None
        self.tiles = tiles(model, F, workspace)

    def __getattr__(self, name):    # one frame's P, A, pos, ctx, made when first read: an
        # evaluation the kept outputs answer (poise.model.recent) never reads them
        if name not in ("P", "A", "pos", "ctx") or not self.__dict__.get("single"):
            raise AttributeError(name)
        s = self.states[0]
        self.P, self.A, self.pos = self.model.marker_kinematics(s)
        self.ctx = EvalContext(t=s.t, angle=s.angle, P=self.P, A=self.A, extra=s.extra,
                               workspace=self.ws)
        return self.__dict__[name]

    def scatter(self, fam) -> Scatter:
        """The family's residual scatter (:class:`~poise.model.assembly.Scatter`), kept in
        the workspace."""
        sc = self.ws.scratch(fam, dict)
        s = sc.get("residual_scatter")
        if s is None:
            s = sc["residual_scatter"] = Scatter(self.model.nq, fam.gcol)
        return s

    def call(self, fi, need_jac):
        """``(t, kin, lam, out)`` of family ``fi``: ``t`` the family (tiled copy for frames),
        ``lam`` its multipliers (constraints), ``out`` the kernel's output tuple."""
        fam = self.model.families[fi]
        kin = None
        if self.single:
            t, exact = fam, True
            small = self.model.small
            if small is not None:
                if self.kins is None:
                    self.kins = small.kinematics(self.P, self.A, self.pos) or {}
                kin = self.kins.get(fi)
            if kin is None:
                index = None if fam.pattern is None else fam.pattern.slots
        else:
            (t, exact), index = self.tiles[fi], None
        if kin is None:
            kin = slot_kinematics(t.markers, fam.slot_ml, t.slot_kind, self.P, self.A, self.mb,
                                  self.pos, index, None if index is not None else slot_points(t))
        lam = self.lam[t.crow] if fam.is_constraint else None
        if exact:
            return t, kin, lam, _kernel(t, kin, lam, self.ctx, need_jac)
        # a family that is not tileable: once per frame with that frame's context
        if self.ctxs is None:
            self.ctxs = [EvalContext(t=s.t, angle=s.angle, P=self.Pfr[f], A=self.Afr[f],
                                     extra=s.extra, workspace=self.ws)
                         for f, s in enumerate(self.states)]
        n = fam.n
        outs = [_kernel(fam, rows(kin, f * n, (f + 1) * n),
                        self.lam2[f][fam.crow] if fam.is_constraint else None, self.ctxs[f],
                        need_jac) for f in range(self.F)]
        k = 3 if fam.is_constraint else 2
        out = [None if outs[0][j] is None else np.concatenate([dense_g(o[j]) for o in outs])
               for j in range(k)]
        ext = stack_ext(outs, k)
        if ext is not None:
            out.append(ext)
        return t, kin, lam, out


def _kernel(fam, kin, lam, ctx, need_jac):
    # (a constraint family's multipliers are an array, a force family's None: every caller)
    if lam is not None:
        if need_jac == "phi":                  # constraint values alone
            return fam.values(kin, ctx), None, None
        return fam.constraints(kin, lam, ctx)
    return fam.forces(kin, ctx, need_jac)


def _family_pass(model, fr, need_jac, only=None, done=None, call=None):
    """The one loop over the element families (``Model.eval_order``: reaction readers after
    the others, gravity last).

    Yields ``(fi, t, kin, rho, G, ph, phy, ext)`` per family (``ph``/``phy`` None for
    forces). ``only="phi"``: constraint families only, ``ph`` alone. ``done`` (a dict): the
    reaction feed's record of the families evaluated so far; the channels are computed before
    the first family that reads them. ``call``: used instead of ``fr.call``
    (:mod:`poise.model.recent`)."""
    families, phi_only = model.families, only == "phi"
    call = fr.call if call is None else call
    for fi in model.eval_order:
        fam = families[fi]
        constraint = fam.is_constraint
        if phi_only and not constraint:
            continue
        if done is not None and fr.ctx.reactions is None and fam.reads_reactions:
            # reaction channels from every family evaluated so far (exact at this iterate)
            fr.ctx.reactions, fr.dg = model.reaction_feed.values(model, done.values(), fr.P,
                                                                 fr.A)
        t, kin, lam, out = call(fi, need_jac)
        if constraint:
            ph, phy, G = out[:3]
            if phi_only:
                yield fi, t, kin, None, None, ph, None, None
                continue
            ext = out[3] if len(out) > 3 else None
            # phi_y^T lam (one row per instance: the product itself, as the sum of one term)
            rho = phy[:, 0] * lam if phy.shape[1] == 1 else einsum("nmy,nm->ny", phy, lam)
            if fam.U:
                ext = _constraint_ext(ext, lam, len(lam), fam.m, fam.U)
        else:
            rho, G = out[:2]
            ext = out[2] if len(out) > 2 else None
            ph = phy = None
        if done is not None:
            done[fi] = (fam, kin, rho, phy)
        yield fi, t, kin, rho, G, ph, phy, ext


def _phi(model, fr, active):
    """Constraint values of the frames (no force element is called; one frame's are those of
    a kept evaluation at its state when there is one, :mod:`poise.model.recent`)."""
    phi = (_recent(model, fr.ws).phi(fr.states[0])
           if fr.single and model.reaction_feed is None else None)
    if phi is None:
        phi = np.zeros(fr.F * model.nc)
        for _, t, _, _, _, ph, _, _ in _family_pass(model, fr, "phi", only="phi"):
            phi[t.crow.ravel()] = ph.ravel()
        if not np.all(np.isfinite(phi)):
            raise EvaluationError(nonfinite_message(model, np.zeros(0), phi[:model.nc]) if
                                  fr.single else "a constraint equation is not finite (NaN/Inf)")
        if not fr.single:
            return phi.reshape(fr.F, model.nc)
    return phi if active is None else np.where(np.asarray(active, bool), phi, 0.0)


def _one_frame(model, fr, what, active, keep, eps_mass):
    """Residual (and Jacobian, now or deferred) of one frame (the Jacobian through the model's
    fixed-pattern assembler); kept outputs are reused (:mod:`poise.model.recent`)."""
    need_jac = what != "residual"
    feed = model.reaction_feed
    state, done = fr.states[0], ({} if feed is not None else None)
    if feed is None:
        small = model.small
        if small is None:
            def compute(call):
                return _family_outputs(model, fr, need_jac, None, call)
        else:      # one dense pass (poise.model.small_dense); the generic one names a NaN
            def compute(call):
                return (small.outputs(_family_pass(model, fr, need_jac, call=call), need_jac)
                        or _family_outputs(model, fr, need_jac, None, call))
        r, phi, pend, last = _recent(model, fr.ws).outputs(fr, need_jac, _kernel, compute)
    else:
        r, phi, pend, last = _family_outputs(model, fr, need_jac, done)
    mask = np.ones(model.nc, bool) if active is None else np.asarray(active, bool)
    if active is not None:
        phi = where(mask, phi, 0.0)
    if not (all_finite(r) and all_finite(phi)):
        raise EvaluationError(nonfinite_message(model, r, phi))
    ev = Evaluation(r=r, phi=phi, J=None, items=list(last) if keep else None, workspace=fr.ws)
    if need_jac:
        if feed is not None:       # d r_reader / d (lambda, q) through the channels
            ev._coupling = feed.coupling(model, done, fr.P, fr.A, mask, pend, fr.dg)
        if not isinstance(pend, SmallTerms):
            pend = [p for p in pend if p is not None]     # assembly order: model.families
        ev._pending = (state, pend, eps_mass, mask.copy(), what != "phi_q")
    return ev


def _recent(model, ws) -> RecentEvaluations:
    """Workspace ``ws``'s memo of ``model``'s last evaluations."""
    return ws.scratch(RecentEvaluations, RecentEvaluations).of(model)


def _family_outputs(model, fr, need_jac, done, call=None):
    """``(r, phi, pend, items)`` of one frame: residual, all-row constraint values, the
    families' outputs the Jacobian is assembled from (``need_jac``) and their slot data."""
    r = np.zeros(model.nq)
    phi = np.zeros(model.nc)
    pend = [None] * len(model.families)
    last = []
    for fi, fam, kin, rho, G, ph, phy, ext in _family_pass(model, fr, need_jac, done=done,
                                                            call=call):
        if ph is not None:
            phi[fam.crow.ravel()] = ph.ravel()
        last.append((fam, kin, rho, phy))
        quiet = _no_reaction(fam, kin, rho)
        if need_jac:
            pend[fi] = (fam, kin, rho, G, phy, ext, quiet)
        if quiet:
            continue
        parts = None if fam.U else spans(kin)
        if parts is not None:      # big family: chunk by chunk (no full-size temporaries)
            fr.scatter(fam).add_parts(r, local_residuals(kin, rho, fam.K, parts,
                                                         partial(family_nonfinite, fam)))
            continue
        rl, _ = local_residual_tangent(kin, rho, G, fam.slot_ml, fam.K, False, ext, fam.U)
        if not all_finite(rl):
            raise EvaluationError(family_nonfinite(fam, rl))
        fr.scatter(fam).add(r, rl)
    return r, phi, pend, last


def jacobian(model, ev: Evaluation):
    """The KKT Jacobian of a one-frame evaluation (assembled now if it was deferred);
    sets ``ev.J``."""
    if ev.J is not None:
        return ev.J
    t_start = phases.now()
    state, pend, eps_mass, row_active, stiffness = ev._pending
    if isinstance(pend, SmallTerms):        # a small model: the dense slot pass
        Jg = model.world_inertia(state)
        ev.J = pend.jacobian(Jg, eps_mass, row_active, stiffness)
    else:      # only the mass shift reads the inertias: none at eps 0 (prologue, written state)
        Jg = model.world_inertia(state) if eps_mass else None
        ev.J = _assembled(model, ev, pend, Jg, eps_mass, row_active, stiffness)
    ev.inertia = Jg        # Newton's step filter multiplies by the same mass matrix (or None)
    ev._pending = None
    # a "phi_q" evaluation (the static prologue's start) keeps its outputs: Newton's first
    # iterate is the same pose with new multipliers (poise.model.recent)
    if model.reaction_feed is None and ev.workspace is not None and stiffness:
        _recent(model, ev.workspace).release()
    phases.add("assemble", phases.now() - t_start)
    return ev.J


def _assembled(model, ev, pend, Jg, eps_mass, row_active, stiffness):
    """The KKT matrix through the model's fixed-pattern assembler: every family's tangent and
    constraint values in registration order, then the mass shift, the unit diagonal of the
    removed rows and the reaction coupling."""
    vals = []
    for fam, kin, rho, G, phy, ext, quiet in pend:
        pat = local_pattern(fam)
        U = fam.U
        parts = None if U else spans(kin)
        # "phi_q": the tangent entries read zero (nothing else shares them); a family with no
        # reaction and no G (a constraint family whose multipliers are all zero: the
        # out-of-plane rows of a planar model) has a zero tangent: not formed, nothing added
        if not stiffness or _no_tangent(G, quiet):
            Kl = Zeros(fam.n * ((6 * fam.K + U) ** 2 if pat.order is None else pat.order.size))
        elif pat.compact:  # straight into the registered (entry-major block) order
            Kl = (tangent_compact(kin, rho, G, fam.K, pat) if parts is None else
                  tangent_values(kin, rho, G, fam.K, pat, parts))
        else:
            Kl = local_tangent(kin, rho, G, fam.slot_ml, fam.K, ext, U, pat)
            Kl = _gather(Kl, pat.order)
        if fam.is_constraint and not U:      # (n, P); big family: chunk by chunk
            Pq = constraint_values(kin, phy, fam.K, row_active[fam.crow], pat.pidx, parts)
            vals += [Kl, Pq, Pq]
        elif fam.is_constraint:          # with scalar columns: instance-major (n, P)
            Pq = np.concatenate([constraint_jacobian_local(kin, phy, fam.K), ext["phi_s"]],
                                axis=2)                                 # (n, m, 6K + U)
            act = row_active[fam.crow]
            if not np.logical_and.reduce(act, axis=None):   # x * 1.0 is x: only with removed rows
                Pq = Pq * act[:, :, None]
            Pq = Pq.reshape(fam.n, -1)
            if pat.pidx is not None:
                Pq = Pq.take(pat.pidx, axis=1)      # C order: no copy when it is scattered
            vals += [Kl, Pq, Pq]   # second block is indexed (col, row): the transpose
        else:
            vals.append(Kl)
    nr = len(model.rot_body)
    removed = np.flatnonzero(~row_active)           # their unit diagonal, nothing elsewhere
    vals += [eps_mass * model.body_mass.repeat(3), eps_mass * Jg] if eps_mass else [
        Zeros(3 * len(model.body_mass)), Zeros(9 * nr)]
    vals.append(Few(row_active.size, removed, np.ones(removed.size)))
    vals += ev._coupling
    return model.assembler.assemble(vals, ev.workspace)


def _many_frames(model, fr, need_jac):
    """Residuals (and dense Jacobians) of ``F`` frames, all rows active: each quantity
    scattered once over every family and frame (``bincount``)."""
    F, nq, nc, N = fr.F, model.nq, model.nc, model.N
    fo = np.arange(F)
    phi = np.zeros(F * nc)
    items = []
    ridx, rval, jidx, jval = [], [], [], []
    for fi, t, kin, rho, G, ph, phy, ext in _family_pass(model, fr, need_jac):
        fam = model.families[fi]
        n = fam.n
        if ph is not None:
            phi[t.crow.ravel()] = ph.ravel()
        items.append((t, kin, rho, phy))
        pat = local_pattern(fam)
        rl, Kl = local_residual_tangent(kin, rho, G, fam.slot_ml, fam.K, need_jac, ext, fam.U,
                                        pat)
        if not np.isfinite(rl).all():
            raise EvaluationError(f"element family {fam.name} produced a non-finite value")
        g = fam.gcol                                                  # (n, L)
        gv = g >= 0
        ridx.append(((g + nq * fo[:, None, None]) * gv - (~gv)).reshape(F * n, -1))
        rval.append(rl)
        if need_jac:
            L = g.shape[1]
            li, lj = np.nonzero(pat.kmask)
            add_block(jidx, jval, g[:, li], g[:, lj], Kl.reshape(F * n, L * L)[:, li * L + lj],
                       F, N)
            if fam.is_constraint:
                Pq = constraint_jacobian_local(kin, phy, fam.K)
                if fam.U:
                    Pq = np.concatenate([Pq, ext["phi_s"]], axis=2)
                pr, pc = np.nonzero(pat.pmask)
                rows = nq + fam.crow
                vals = Pq[:, pr, pc]
                add_block(jidx, jval, rows[:, pr], g[:, pc], vals, F, N)
                add_block(jidx, jval, g[:, pc], rows[:, pr], vals, F, N)
    r = np.zeros(F * nq)
    if ridx:
        idx = np.concatenate([i.ravel() for i in ridx])
        val = np.concatenate([v.ravel() for v in rval])
        ok = idx >= 0
        r = np.bincount(idx[ok], weights=val[ok], minlength=F * nq)
    r = r.reshape(F, nq)
    phi = phi.reshape(F, nc)
    if not (np.isfinite(r).all() and np.isfinite(phi).all()):
        raise EvaluationError("non-finite residual in a batched frame evaluation")
    J = None
    if need_jac:
        idx = np.concatenate(jidx) if jidx else np.zeros(0, np.int64)
        val = np.concatenate(jval) if jval else np.zeros(0)
        J = np.bincount(idx, weights=val, minlength=F * N * N).reshape(F, N, N)
    return FrameEvaluation(r=r, phi=phi, J=J, items=items)


# ---------------------------------------------------------------------------- helpers
def _no_reaction(fam, kin, rho) -> bool:
    """Whether a family's residual rows ``B^T rho`` are zero: no scalar columns, no reaction on
    any slot (a constraint family whose multipliers are all zero: the out-of-plane rows of a
    planar model) and finite levers (else its values are formed, and reported non-finite).
    Zeros leave the residual's sums (started from +0.0) as they are: not formed, not added."""
    return not fam.U and not rho.any() and all_finite(kin.V)


def _no_tangent(G, quiet: bool) -> bool:
    """Whether a family's tangent ``B^T G B + C(rho)`` is zero (every value +-0: adding it
    leaves the Jacobian's sums, started from +0.0, as they are): no reaction (``quiet``, its
    :func:`_no_reaction` of the residual pass) and ``G`` None or zero (an array or a
    :class:`~poise.elements.kernel.PairBlocks`)."""
    return quiet and (G is None or not G.any())


def _gather(Kl, idx):
    """Flattened local tangent restricted to the family's structural entries."""
    Kl = Kl.reshape(Kl.shape[0], -1)
    return Kl if idx is None else Kl[:, idx]


def _constraint_ext(ext, lam, n, m, U):
    """Scalar-column pieces of a constraint family: ``rho_s = phi_s^T lam`` etc."""
    ext = dict(ext or {})
    phi_s = ext.get("phi_s")
    if phi_s is None:
        phi_s = np.zeros((n, m, U))
    ext["phi_s"] = phi_s
    ext["rho_s"] = np.einsum("nmu,nm->nu", phi_s, lam)
    if ext.get("G_ys") is not None and ext.get("G_sy") is None:
        ext["G_sy"] = np.swapaxes(ext["G_ys"], 1, 2)
    return ext
