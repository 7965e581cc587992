"""Compile elements given by Python user routines (see ``poise/user_routines.py``).

* ``Constraint_UserConstr`` (alias ``Constraint_Usrconstr``): one ``UserConstraint`` family per
  element, m rows (m = number of values at the first call) named ``user1..userm``, output group
  ``userconstrs`` (reaction force/torque on the body of the first marker the function reads, at
  its origin, like joints).
* ``Force_Scalar_TwoBody`` / ``Force_Vector_OneBody`` / ``Force_Vector_TwoBody`` with a user
  routine: routed here by ``compile_forces`` (``ctx.user_forces``); output group ``forces``.
* ``Reference_Variable type="USERSUB"``: called by ``compile_diff_vars`` with the variable's
  scalar unknown.
"""
from __future__ import annotations

import numpy as np

from poise.core.errors import DeckError, EvaluationError
from poise.elements.base import POINT
from poise.elements import expr_forces as XF
from poise.elements.context import GLOBAL
from poise.elements.registry import ElementType
from poise.elements.resolver import ground_markers
from poise.elements.user import UserConstraint, UserScalarEquation, UserScalarForce, UserVectorForce
from poise.core.user_routines import UserRoutine, describe, load

USER_CONSTRAINT_TAGS = ("Constraint_UserConstr", "Constraint_Usrconstr")


def _initial_kinematics(ctx):
    """Marker origins and axes at the input configuration (nm, 3), (nm, 3, 3)."""
    b = ctx.b
    nm = len(b.marker_els) + 1
    P = np.zeros((nm, 3))
    A = np.tile(np.eye(3), (nm, 1, 1))
    for k, e in enumerate(b.marker_els):
        p, R = b.marker_glob[e.id]
        P[k + 1] = p
        A[k + 1] = R
    return P, A


def _routine(el, ctx, P, A):
    """The element's probed :class:`UserRoutine`, or None (problem collected, or user code not
    run: ``ctx.b.user_code`` is ``"refuse"`` or ``"skip"``, see ``poise.core.user_routines.load``)."""
    b = ctx.b
    try:
        got = load(el, b.user_code)
    except DeckError as e:
        ctx.pc.problems.extend(e.problems)
        return None
    b.user_routines.append(describe(el))
    if got is None:                      # poise check: the reference is valid, nothing ran
        return None
    fn, path, par, digest = got
    b.input_files[str(path)] = digest
    r = UserRoutine(el, fn, path, par, ctx.b.marker_index, ctx.b.L)
    ctx.reads_time(el.loc.prefix()[:-1])   # opaque code: may read its time argument anywhere
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


def _moving(ctx, mid):
    b = ctx.b
    e = b.element("Reference_Marker", mid)
    return e is not None and e.attrs.get("body_id") in b.body_index


def _slot_layout(r, ctx, first=()):
    """Markers (1, K) (``first`` then the other moving markers read), slot lists and the map
    (marker_id, kind) -> slot for the recorded vectors of moving markers; constant vectors
    (ground / global) are returned separately."""
    mids = list(first)
    for mid, _ in r.slots:
        if mid not in mids and _moving(ctx, mid):
            mids.append(mid)
    if not mids:
        mids = [0]
    slot_ml, slot_kind, slot_of = [], [], {}
    for mid, kind in r.slots:
        if not _moving(ctx, mid):
            continue
        slot_of[(mid, kind)] = len(slot_ml)
        slot_ml.append(mids.index(mid))
        slot_kind.append(kind)
    markers = np.array([[ctx.b.marker_index.get(m, GLOBAL) for m in mids]], int)
    return markers, np.array(slot_ml, int), np.array([slot_kind], int).reshape(1, -1), slot_of


def _const_vectors(r, ctx, P, A):
    return {k: (P[r.mi[k[0]]] if k[1] == POINT else A[r.mi[k[0]]][:, k[1] - 1]).copy()
            if k[0] != 0 else (np.zeros(3) if k[1] == 0 else np.eye(3)[:, k[1] - 1])
            for k in r.slots if not _moving(ctx, k[0])}


def compile_user(spec, ctx):
    """Element compiler: user constraints and user forces."""
    els = [e for t in USER_CONSTRAINT_TAGS for e in spec.elements(t)]
    uf = list(getattr(ctx, "user_forces", []))
    if not els and not uf:
        return
    P, A = _initial_kinematics(ctx)
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
        fam = UserConstraint(name=f"userconstrs:{el.id}", markers=markers, slot_ml=slot_ml,
                             slot_kind=slot_kind, owner=np.array([owner]), m=r.m,
                             row_names=tuple(f"user{k + 1}" for k in range(r.m)))
        fam.crow = np.array([rows], int)
        fam.routine = r
        fam.slot_of = slot_of
        fam.const_vec = _const_vectors(r, ctx, P, A)
        fam.group = "userconstrs"
        fam.element_locs = [el.loc]
        ctx.families.append(fam)
        ctx.effect(f"{el.tag}:python")
    if ids:
        ctx.outputs["userconstrs"] = dict(tag="Constraint_UserConstr", ids=np.array(ids, int))
    for owner, el in uf:
        _user_force(el, owner, ctx, P, A)


def _user_force(el, owner, ctx, P, A):
    r = _routine(el, ctx, P, A)
    if r is None:
        return
    b = ctx.b
    ground = ground_markers(b)
    if el.tag == "Force_Scalar_TwoBody":
        I, J, R = b.mk(el, "i_marker_id"), b.mk(el, "j_marker_id"), GLOBAL
        ao = bool(el.attrs.get("is_action_only", False))
        t = str(el.attrs.get("type", "FORCE")).upper()
        cls, comp = UserScalarForce, [0]
        if r.m != 1:
            ctx.pc.error(el.loc, f"the user routine returned {r.m} values; expected 1 (SFOSUB)")
            return
    else:
        one = el.tag.endswith("OneBody")
        I = b.mk(el, "marker_id" if one else "i_marker_id")
        J = GLOBAL if one else b.mk(el, "j_floating_marker_id")
        R = b.mk(el, "ref_marker_id", required=False)
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

    class _Shim:                                     # slot list in expr_forces' batch format
        slot_marker = np.array([[b.marker_index[m] if m else -1 for m, _ in r.slots]], int)
        slot_kind = np.array([[k for _, k in r.slots]], int)
    fam = XF._build(cls, f"forces:{cls.__name__}:{el.id}", [I], [J], [R], [owner], [ao],
                    [_Shim()], ground, [el.loc])
    fam.batches = []
    _, bs, fs = fam.slot_maps[0]
    fam.user_map = list(zip(bs.tolist(), fs.tolist()))
    fam.slot_maps = []
    fam.routine = r
    fam.comp_index = np.array(comp, int)
    if cls is UserScalarForce:
        fam.stype = np.array([XF.ST_TORQUE if t == "TORQUE" else
                              (XF.ST_AXIS if ao else XF.ST_LINE)], int)
    ctx.families.append(fam)


def compile_user_variables(spec, ctx, items):
    """``Reference_Variable type="USERSUB"``: residual ``v - varsub(...)`` per variable."""
    P, A = _initial_kinematics(ctx)
    for el, k in items:
        r = _routine(el, ctx, P, A)
        if r is None:
            continue
        if r.m != 1:
            ctx.pc.error(el.loc, f"the user routine returned {r.m} values; expected 1 (VARSUB)")
            continue
        markers, slot_ml, slot_kind, slot_of = _slot_layout(r, ctx)
        fam = UserScalarEquation(name=f"control:UserVariable:{el.id}", markers=markers,
                                 slot_ml=slot_ml, slot_kind=slot_kind, owner=np.array([0]))
        fam.scols = np.array([[k]], int)
        fam.routine = r
        fam.slot_of = slot_of
        fam.const_vec = _const_vectors(r, ctx, P, A)
        fam.element_locs = [el.loc]
        ctx.families.append(fam)


ELEMENTS = (ElementType(
    "user", USER_CONSTRAINT_TAGS, compile_user,
    after=("forces", "diff_vars"),    # compiles the user forces compile_forces routed here
    kernels=lambda: (UserConstraint, UserScalarForce, UserVectorForce, UserScalarEquation),
    time_dependent=True, outputs={"userconstrs": USER_CONSTRAINT_TAGS, "forces": None},
    datasets=("id", "force", "torque"), fd_tests="tests/test_elements_8b.py"),)
