"""Families driven by Python user routines (``poise.core.user_routines``), one instance each.

* :class:`UserConstraint` (``Constraint_UserConstr``, UCOSUB style): ``phi`` = the function's
  values, ``phi_y`` its derivatives w.r.t. the marker vectors it reads (user-given or central
  differences), ``G = sum lam_r d2 phi_r / dy2`` by central differences of the gradient.
  Markers: the distinct markers read; slots: the vectors read.
* :class:`UserScalarForce` / :class:`UserVectorForce` (``Force_Scalar_TwoBody`` SFOSUB,
  ``Force_Vector_*`` GFOSUB): the expression-force families of ``expr_forces.py`` with the
  expression batches replaced by the user function (same force laws and slot layout
  ``[I, J, R, extra markers...]``), so values and slot gradients chain exactly the same way.
* :class:`UserScalarEquation` (``Reference_Variable`` VARSUB): the variable is a scalar unknown v
  with residual row ``v - f(q, t)``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from poise.core.errors import DeckError, EvaluationError
from poise.core.user_routines import UserRoutine, describe, load
from poise.elements import expr_forces as XF
from poise.elements.base import ConstraintFamily, ForceFamily
from poise.elements.kernel import POINT
from poise.elements.context import GLOBAL
from poise.elements.expr_forces import ExprScalarForce, ExprVectorForce
from poise.elements.forces import FORCES
from poise.elements.registry import ElementType, OutputGroup, not_conservative


def _vectors_from_slots(routine, Y, slot_of):
    """Recorded vectors of instance 0 from the kernel's slot vectors ``Y`` (n, S, 3)."""
    vec = {}
    for key in routine.slots:
        s = slot_of.get(key)
        if s is not None:
            vec[key] = Y[0, s]
    return vec


@dataclass(frozen=True, eq=False, kw_only=True)
class UserConstraint(ConstraintFamily):
    """Rows ``phi`` = the user function's values (see the module doc): ``routine`` the probed
    :class:`~poise.core.user_routines.UserRoutine`, ``slot_of`` (marker_id, kind) -> family
    slot of the moving-marker vectors it reads, ``const_vec`` the constant (ground) ones."""

    routine: UserRoutine
    slot_of: dict
    const_vec: dict

    def _vec(self, kin, ctx):
        vec = _vectors_from_slots(self.routine, kin.Y, self.slot_of)
        for key in self.routine.slots:            # ground / global vectors: constants
            if key not in vec:
                vec[key] = self.const_vec[key]
        return vec

    def constraints(self, kin, lam, ctx):
        r = self.routine
        vec = self._vec(kin, ctx)
        t = float(ctx.t)
        v, D = r.evaluate(t, vec, True)
        S = len(self.slot_ml)
        phy = np.zeros((1, self.m, 3 * S))
        Hf = None
        if np.any(lam):
            Hf = r.hessian(t, vec, lam[0])
        G = np.zeros((1, 3 * S, 3 * S))
        for a, ka in enumerate(r.slots):
            sa = self.slot_of.get(ka)
            if sa is None:
                continue
            phy[0, :, 3 * sa:3 * sa + 3] = D[:, a]
            if Hf is None:
                continue
            for b, kb in enumerate(r.slots):
                sb = self.slot_of.get(kb)
                if sb is None:
                    continue
                G[0, 3 * sa:3 * sa + 3, 3 * sb:3 * sb + 3] = Hf[3 * a:3 * a + 3, 3 * b:3 * b + 3]
        return v[None, :], phy, G


@dataclass(frozen=True, eq=False, kw_only=True)
class UserForceValues:
    """Replaces the expression batches of an expression-force family by a user function
    (called per frame: user force families are not tileable). ``comp_index``: positions of the
    user's values among the family components; ``user_map``: (user slot index, family slot)
    pairs of moving-marker vectors."""

    routine: UserRoutine
    comp_index: np.ndarray
    user_map: tuple
    n_comp: ClassVar[int] = 1

    def expr_values(self, ctx, need_jac):
        r = self.routine
        vec = {key: (ctx.P[r.mi[key[0]]] if key[1] == 0 else ctx.A[r.mi[key[0]]][:, key[1] - 1])
               for key in r.slots}
        v, D = r.evaluate(float(ctx.t), vec, need_jac)
        S = len(self.slot_ml)
        vals = np.zeros((1, self.n_comp))
        vals[0, self.comp_index] = v
        grads = None
        if need_jac:
            g = np.zeros((1, self.n_comp, S, 3))
            for us, fs in self.user_map:
                g[0, self.comp_index, fs] = D[:, us]
            grads = g.reshape(1, self.n_comp, 3 * S)
        return vals, grads, None, None


@dataclass(frozen=True, eq=False, kw_only=True)
class UserScalarForce(UserForceValues, ExprScalarForce):
    n_comp = 1


@dataclass(frozen=True, eq=False, kw_only=True)
class UserVectorForce(UserForceValues, ExprVectorForce):
    n_comp = 6


@dataclass(frozen=True, eq=False, kw_only=True)
class UserScalarEquation(ForceFamily):
    """Residual ``v - f(q, t)`` of a user-defined variable v (VARSUB); fields as
    :class:`UserConstraint`'s."""

    routine: UserRoutine
    slot_of: dict
    const_vec: dict

    def forces(self, kin, ctx, need_jac=True):
        r = self.routine
        vec = _vectors_from_slots(r, kin.Y, self.slot_of)
        for key in r.slots:
            if key not in vec:
                vec[key] = self.const_vec[key]
        f, D = r.evaluate(float(ctx.t), vec, need_jac)
        S = len(self.slot_ml)
        rho = np.zeros((1, 3 * S))
        v = ctx.extra[self.scols[0, 0]]
        ext = {"rho_s": np.array([[v - f[0]]])}
        if need_jac:
            G_sy = np.zeros((1, 1, 3 * S))
            for a, key in enumerate(r.slots):
                s = self.slot_of.get(key)
                if s is not None:
                    G_sy[0, 0, 3 * s:3 * s + 3] = -D[0, a]
            ext["G_sy"] = G_sy
            ext["G_ss"] = np.ones((1, 1, 1))
        return rho, None, ext


# ----------------------------------- compile
USER_CONSTRAINT_TAGS = ("Constraint_UserConstr", "Constraint_Usrconstr")


def _routine(el, ctx, P, A):
    """The element's probed :class:`UserRoutine`, or None (problem collected, or user code not
    run: ``ctx.user_code`` is ``"refuse"`` or ``"skip"``, see ``poise.core.user_routines.load``)."""
    try:
        got = load(el, ctx.user_code)
    except DeckError as e:
        ctx.pc.problems.extend(e.problems)
        return None
    if got is None:                      # poise check: the reference is valid, nothing ran
        ctx.user_routine(describe(el))
        return None
    fn, path, par, digest = got
    ctx.user_routine(describe(el), path, digest)
    r = UserRoutine(el, fn, path, par, ctx.geometry.marker_index, ctx.L)
    try:
        r.probe(0.0, P, A)
    except EvaluationError as e:
        msg = str(e).replace(el.loc.prefix() + " ", "")
        ctx.pc.error(el.loc, f"first call of the user routine (at the input configuration) "
                     f"failed: {msg}")
        return None
    except KeyError as e:
        ctx.pc.error(el.loc, f"user routine read an unknown marker: {e.args[0]}")
        return None
    return r


def _slot_layout(r, ctx, first=()):
    """Markers (1, K) (``first`` then the other moving markers read), slot lists and the map
    (marker_id, kind) -> slot for the recorded vectors of moving markers; constant vectors
    (ground / global) are returned separately."""
    mids = list(first)
    for mid, _ in r.slots:
        if mid not in mids and ctx.moving_marker(mid):
            mids.append(mid)
    if not mids:
        mids = [0]
    slot_ml, slot_kind, slot_of = [], [], {}
    for mid, kind in r.slots:
        if not ctx.moving_marker(mid):
            continue
        slot_of[(mid, kind)] = len(slot_ml)
        slot_ml.append(mids.index(mid))
        slot_kind.append(kind)
    markers = np.array([[ctx.geometry.marker_index.get(m, GLOBAL) for m in mids]], int)
    return markers, np.array(slot_ml, int), np.array([slot_kind], int).reshape(1, -1), slot_of


def _const_vectors(r, ctx, P, A):
    return {k: (P[r.mi[k[0]]] if k[1] == POINT else A[r.mi[k[0]]][:, k[1] - 1]).copy()
            if k[0] != 0 else (np.zeros(3) if k[1] == 0 else np.eye(3)[:, k[1] - 1])
            for k in r.slots if not ctx.moving_marker(k[0])}


def compile_user(spec, ctx):
    """Element compiler: user constraints and user forces.

    Compile elements given by Python user routines (see ``poise/user_routines.py``).

    * ``Constraint_UserConstr`` (alias ``Constraint_Usrconstr``): one ``UserConstraint`` family per
      element, m rows (m = number of values at the first call) named ``user1..userm``, output group
      ``userconstrs`` (reaction force/torque on the body of the first marker the function reads, at
      its origin, like joints).
    * ``Force_Scalar_TwoBody`` / ``Force_Vector_OneBody`` / ``Force_Vector_TwoBody`` with a user
      routine: routed here by ``compile_forces`` (``ctx.route("user", ...)``); output group
      ``forces``.
    * ``Reference_Variable type="USERSUB"``: called by ``compile_diff_vars`` with the variable's
      scalar unknown.
    """
    els = [e for t in USER_CONSTRAINT_TAGS for e in spec.elements(t)]
    uf = ctx.routed("user")
    if not els and not uf:
        return
    P, A = ctx.geometry.initial_kinematics()
    ids = []
    for el in els:
        r = _routine(el, ctx, P, A)
        if r is None:
            continue
        if r.m == 0:
            ctx.pc.error(el.loc, "the user routine returned no constraint value")
            continue
        markers, slot_ml, slot_kind, slot_of = _slot_layout(r, ctx)
        ids.append(el.id)
        owner = len(ids) - 1
        rows = [ctx.add_row(el, f"user{k + 1}", "trans", "userconstrs", owner)
                for k in range(r.m)]
        ctx.add_family(UserConstraint(
            name=f"userconstrs:{el.id}", markers=markers, slot_ml=slot_ml, slot_kind=slot_kind,
            owner=np.array([owner]), m=r.m, row_names=tuple(f"user{k + 1}" for k in range(r.m)),
            crow=np.array([rows], int), routine=r, slot_of=slot_of,
            const_vec=_const_vectors(r, ctx, P, A), group="userconstrs",
            element_locs=(el.loc,)))
        ctx.effect(f"{el.tag}:python")
    if ids:
        ctx.output("userconstrs", "Constraint_UserConstr", ids)
    for owner, el in uf:
        _user_force(el, owner, ctx, P, A)


def _user_force(el, owner, ctx, P, A):
    r = _routine(el, ctx, P, A)
    if r is None:
        return
    mk = ctx.marker
    index = ctx.geometry.marker_index
    ground = ctx.geometry.marker_on_ground
    if el.tag == "Force_Scalar_TwoBody":
        I, J, R = mk(el, "i_marker_id"), mk(el, "j_marker_id"), GLOBAL
        ao = bool(el.attrs.get("is_action_only", False))
        t = str(el.attrs.get("type", "FORCE")).upper()
        cls, comp = UserScalarForce, [0]
        if r.m != 1:
            ctx.pc.error(el.loc, f"the user routine returned {r.m} values; expected 1 (SFOSUB)")
            return
    else:
        one = el.tag.endswith("OneBody")
        I = mk(el, "marker_id" if one else "i_marker_id")
        J = GLOBAL if one else mk(el, "j_floating_marker_id")
        R = mk(el, "ref_marker_id", required=False)
        ao = one
        t = str(el.attrs.get("type", "FORCEANDTORQUE")).upper()
        cls = UserVectorForce
        if r.m == 6:
            comp = list(range(6))
        elif r.m == 3 and t in ("FORCEONLY", "TORQUEONLY"):
            comp = [0, 1, 2] if t == "FORCEONLY" else [3, 4, 5]
        else:
            ctx.pc.error(el.loc, f"the user routine returned {r.m} values; expected 6 "
                         "(fx fy fz tx ty tz), or 3 for FORCEONLY / TORQUEONLY (GFOSUB)")
            return

    class _Slots:                                    # slot list in expr_forces' batch format
        slot_marker = np.array([[index[m] if m else -1 for m, _ in r.slots]], int)
        slot_kind = np.array([[k for _, k in r.slots]], int)
    markers, slot_ml, slot_kind, maps = XF.slot_layout([_Slots()], [I], [J], [R], ground)
    _, bs, fs = maps[0]
    extra = {}
    if cls is UserScalarForce:
        extra["stype"] = np.array([XF.ST_TORQUE if t == "TORQUE" else
                                   (XF.ST_AXIS if ao else XF.ST_LINE)], int)
    ctx.add_family(cls(
        name=f"forces:{cls.__name__}:{el.id}", markers=markers, slot_ml=slot_ml,
        slot_kind=slot_kind, owner=np.array([owner], int), action_only=np.array([ao], bool),
        batches=(), slot_maps=(), element_locs=(el.loc,), group="forces", routine=r,
        comp_index=np.array(comp, int), user_map=tuple(zip(bs.tolist(), fs.tolist())),
        **extra))


def compile_user_variables(spec, ctx, items):
    """``Reference_Variable type="USERSUB"``: residual ``v - varsub(...)`` per variable."""
    P, A = ctx.geometry.initial_kinematics()
    for el, k in items:
        r = _routine(el, ctx, P, A)
        if r is None:
            continue
        if r.m != 1:
            ctx.pc.error(el.loc, f"the user routine returned {r.m} values; expected 1 (VARSUB)")
            continue
        markers, slot_ml, slot_kind, slot_of = _slot_layout(r, ctx)
        ctx.add_family(UserScalarEquation(
            name=f"control:UserVariable:{el.id}", markers=markers, slot_ml=slot_ml,
            slot_kind=slot_kind, owner=np.array([0]), scols=np.array([[k]], int), routine=r,
            slot_of=slot_of, const_vec=_const_vectors(r, ctx, P, A), element_locs=(el.loc,)))


def opaque_code(fam) -> list:
    """``time_dependent`` of user routines: opaque code may read its time argument anywhere
    (the probe at two times cannot prove it does not), so every user element counts."""
    return [loc.prefix()[:-1] for loc in fam.element_locs]


ELEMENTS = (ElementType(
    "user", USER_CONSTRAINT_TAGS, compile_user,
    rank=130, needs=("forces",),      # compiles the user forces compile_forces routed here
    kernels=lambda: (UserConstraint, UserScalarForce, UserVectorForce, UserScalarEquation),
    potential_energy=not_conservative,   # user forces and VARSUB rows (constraints: none)
    time_dependent=opaque_code,
    outputs=(OutputGroup("userconstrs", "U", "userconstr", "user constraint",
                         "`Constraint_UserConstr` (Python UCOSUB)",
                         USER_CONSTRAINT_TAGS,
                         load="reaction on the body of the first marker the user routine "
                         "reads, at its origin, global axes"), FORCES),
    fd_tests="tests/kernels/test_diffs_variables_user_routines.py"),)
