"""Compile ``Reference_ParamCurve``/``Reference_ParamSurface`` and the higher-pair constraints
``Constraint_PTCV``, ``Constraint_CVCV``, ``Constraint_PTSF``, ``Constraint_CVSF``,
``Constraint_SFSF`` (equations: :mod:`poise.elements.curves`; geometry:
:mod:`poise.elements.curve_data`).

Parameters become scalar unknowns (``CompileContext.add_extra``) named
``<Constraint_PTCV id=3> u`` etc. Seeds: the ``*disp_*0`` guess projected onto the curve/surface
(PTCV: global coordinates; CVCV/CVSF/SFSF ``i_disp``/``j_disp``: I-/J-marker coordinates; PTSF:
J-marker coordinates), else the point of the curve/surface closest to the I-marker origin (point
pairs) or the closest pair of points of the two geometries (sampled, then projected) in the input
configuration. Reaction outputs: group ``curves`` (force/torque on the I body at I); per-frame
contact outputs ``curves/tag``, ``curves/parameters``, ``curves/point`` (frame hook).
"""
from __future__ import annotations

import numpy as np

from poise.deck.matrix import matrix_values
from poise.deck.spec import Expr
from poise.core.errors import EvaluationError, ProblemCollector
from poise.elements import curves as F
from poise.elements import curve_data as CD
from poise.elements.registry import ElementType, OutputGroup, static, workless
from poise.elements.kernel import slot_kinematics

TAGS = ("Constraint_PTCV", "Constraint_CVCV", "Constraint_PTSF", "Constraint_CVSF",
        "Constraint_SFSF")
PARAM_NAMES = {"PTCV": ("u",), "PTSF": ("u", "v"), "CVCV": ("u_i", "u_j"),
               "CVSF": ("u", "s", "t"), "SFSF": ("u_i", "v_i", "u_j", "v_j")}
ROW_NAMES = {"PTCV": ("dx", "dy", "dz"), "PTSF": ("dx", "dy", "dz"),
             "CVCV": ("d.e1", "d.e2", "ti x tj.n"), "CVSF": ("dx", "dy", "dz", "tc.ns"),
             "SFSF": ("dx", "dy", "dz", "ni.tj_u", "ni.tj_v")}


def _f(el, name, default):
    v = el.attrs.get(name)
    return default if v is None else float(v)


def _points(el, pc, per):
    txt = (el.text or "").replace(",", " ").split()
    try:
        vals = np.array([float(t) for t in txt])
    except ValueError:
        pc.error(el.loc, "curve/surface data must be numbers (x y z per point)")
        return None
    if len(vals) == 0 or len(vals) % 3:
        pc.error(el.loc, f"expected x y z triplets in the element text, got {len(vals)} numbers")
        return None
    pts = vals.reshape(-1, 3)
    if per is not None and len(pts) != per:
        pc.error(el.loc, f"expected {per} points in the element text, got {len(pts)}")
        return None
    return pts


def _matrix_points(spec, el, pc, per):
    """Curve points from the ``Reference_Matrix`` of ``matrix_id``: one row per point, three
    columns x y z (Adams ``CURVE/id, MATRIX=id``); None after a located problem."""
    mid = el.attrs["matrix_id"]
    mel = next((m for m in spec.elements("Reference_Matrix") if m.id == mid), None)
    if mel is None:                  # validation reports the missing reference
        return None
    scratch = ProblemCollector()
    M = matrix_values(mel, scratch)
    if M is None:                    # validation reports the matrix's own problem
        return None
    if M.shape[1] != 3:
        pc.error(el.loc, f"Reference_Matrix id={mid} has {M.shape[1]} columns; expected 3 "
                 "(x y z of one curve point per row)", "matrix_id")
        return None
    if per is not None and len(M) != per:
        pc.error(el.loc, f"num_pts={per} but Reference_Matrix id={mid} has {len(M)} rows",
                 "num_pts")
        return None
    return M


def _eval_problem(pc, el, e: EvaluationError, when: str):
    """A curve/surface expression that fails where the compiler samples it: located deck error
    (the geometry must be defined on its whole parameter range)."""
    pc.error(e.loc or el.loc, f"{e.detail} ({when})", e.attr if e.loc else None)


def _geometry(spec, ctx, tag):
    """id -> curve/surface object for the elements of ``tag`` (errors collected)."""
    pc = ctx.pc
    out = {}
    surf = tag == "Reference_ParamSurface"
    for el in spec.elements(tag):
        a = el.attrs
        if a.get("usrsub_dll_name") or a.get("script_name") or a.get("usrsub_fnc_name"):
            pc.error(el.loc, "user-subroutine curve and surface data are not supported; "
                     "give x_expression/y_expression/z_expression of U (and V), the points "
                     "in the element text or a Reference_Matrix (curves)")
            continue
        if a.get("matrix_id") is not None and surf:
            pc.error(el.loc, "surface data from a Reference_Matrix are not supported; give "
                     "the grid points in the element text or x/y/z_expression of U and V",
                     "matrix_id")
            continue
        ex = [a.get(f"{c}_expression") for c in "xyz"]
        u0, u1 = _f(el, "u_start", 0.0), _f(el, "u_end", 1.0)
        closed = bool(a.get("is_u_closed"))
        rng = [u0, u1] + ([_f(el, "v_start", 0.0), _f(el, "v_end", 1.0)] if surf else [])
        if not (np.all(np.isfinite(rng)) and np.isfinite(u1 - u0)
                and np.isfinite(rng[-1] - rng[-2])):
            pc.error(el.loc, "the parameter range (u_start, u_end" + (", v_start, v_end" if surf
                     else "") + ") must be finite numbers with a finite length")
            continue
        try:
            if any(e is not None for e in ex):
                ex = [0.0 if e is None else (e if isinstance(e, Expr) else float(e)) for e in ex]
                if surf:
                    obj = CD.AnalyticSurface(el, ex, u0, u1, _f(el, "v_start", 0.0),
                                             _f(el, "v_end", 1.0))
                    obj.derivs(np.array([u0]), np.array([obj.v0]), 0)
                else:
                    obj = CD.AnalyticCurve(el, ex, u0, u1, closed)
                    obj.derivs(np.array([u0]), 0)        # compile now: located syntax errors
                if obj.batch.depends_on_time:
                    # geometry is evaluated without a time: TIME would silently read 0
                    pc.error(el.loc, "curve/surface expressions may only use U, V and "
                             "constants; expected no TIME (a moving curve is not supported)",
                             next((f"{c}_expression" for c, e in zip("xyz", ex)
                                   if isinstance(e, Expr) and "TIME" in e.text.upper()), None))
                    continue
            elif surf:
                nu, nv = a.get("num_u"), a.get("num_v")
                if not nu or not nv:
                    pc.error(el.loc, "spline surface needs num_u and num_v (points in the text, "
                             "v index fastest)")
                    continue
                pts = _points(el, pc, int(nu) * int(nv))
                if pts is None:
                    continue
                obj = CD.SplineSurface(pts, int(nu), int(nv), u0, u1, _f(el, "v_start", 0.0),
                                       _f(el, "v_end", 1.0))
            else:
                npts = a.get("num_pts")
                if a.get("is_curve_points") is False:
                    pc.error(el.loc, "is_curve_points=\"FALSE\": the points would be B-spline "
                             "control points, which poise does not support; expected points the "
                             "curve passes through (is_curve_points=\"TRUE\")", "is_curve_points")
                    continue
                if a.get("matrix_id") is not None:
                    pts = _matrix_points(spec, el, pc, int(npts) if npts else None)
                else:
                    pts = _points(el, pc, int(npts) if npts else None)
                if pts is None:
                    continue
                if len(pts) < 4:
                    pc.error(el.loc, "a spline curve needs at least 4 points")
                    continue
                obj = CD.SplineCurve(pts, u0, u1, closed)
            if not _within_range(el, pc, obj, surf):
                continue
        except ValueError as e:
            pc.error(el.loc, str(e))
            continue
        except EvaluationError as e:
            _eval_problem(pc, el, e, "evaluating the geometry at its start")
            continue
        obj.id = el.id
        out[el.id] = obj
    return out


#: largest coordinate (or first/second derivative) a curve or surface may reach: squared
#: distances and sums of samples stay finite (beyond, LAPACK may never return on them)
EXTENT_MAX = 1e150


def _within_range(el, pc, obj, surf) -> bool:
    """Sample the geometry over its parameter range: its points and first two derivatives
    must be finite and within EXTENT_MAX (else a located deck error, False)."""
    if surf:
        U, V = np.meshgrid(np.linspace(obj.u0, obj.u1, 21), np.linspace(obj.v0, obj.v1, 21),
                           indexing="ij")
        U, V = U.ravel(), V.ravel()
        d = obj.derivs(U, V, 2)
        arr = np.stack([d[k] for k in ((0, 0), (1, 0), (0, 1), (2, 0), (0, 2), (1, 1))])
    else:
        U = np.linspace(obj.u0, obj.u1, 181)
        V = None
        arr = obj.derivs(U, 2)                        # (3 orders, k, 3)
    with np.errstate(invalid="ignore", over="ignore"):
        bad = ~(np.abs(arr) <= EXTENT_MAX)           # NaN counts as bad
    if not bad.any():
        return True
    order, k, c = (int(x[0]) for x in np.nonzero(bad))
    what = ("its coordinates", "their first derivatives", "their second derivatives")[min(order, 2)]
    at = f"U = {U[k]:.6g}" + (f", V = {V[k]:.6g}" if V is not None else "")
    attr = f"{'xyz'[c]}_expression" if el.attrs.get(f"{'xyz'[c]}_expression") is not None \
        else None
    pc.error(el.loc, f"the geometry overflows: {'xyz'[c]} of {what} is {arr[order, k, c]:.6g} "
             f"at {at}; expected finite values within {EXTENT_MAX:.0e}", attr)
    return False


def _plane_basis(curve, loc, pc):
    """Columns e1, e2, n (marker axes) of the plane a curve lies in (CVCV)."""
    _, pts = CD.sample_curve(curve, 181)             # finite: _within_range
    c = pts.mean(0)
    _, sv, Vt = np.linalg.svd(pts - c)
    n = Vt[2]
    scale = max(sv[0], 1e-300)
    if sv[2] > 1e-6 * scale:
        pc.error(loc, "Constraint_CVCV needs planar curves (curves in parallel planes); "
                 "curve J is not planar")
    if abs(n[2]) > 0.5 and n[2] < 0:
        n = -n
    e1 = Vt[0] - n * (Vt[0] @ n)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(n, e1), n], 1)


def compile_curves(spec, ctx):
    els = [(t, el) for t in TAGS for el in spec.elements(t)]
    if not els:
        return
    pc = ctx.pc
    curves = _geometry(spec, ctx, "Reference_ParamCurve")
    surfs = _geometry(spec, ctx, "Reference_ParamSurface")
    P0, A0 = {}, {}
    index = ctx.geometry.marker_index
    for mid, (p, R) in ctx.geometry.poses.items():
        P0[index[mid]], A0[index[mid]] = p, R
    P0[0], A0[0] = np.zeros(3), np.eye(3)

    def geo_ref(el, attr, table, what):
        gid = el.attrs.get(attr)
        if gid not in table:
            if not any(g.id == gid for g in spec.elements(what)):   # else: reported itself
                pc.error(el.loc, f"{attr} {gid} is not a {what}", attr)
            return None
        return table[gid]

    acc = {k: [] for k in F.FAMILIES}
    ids, tags = [], []
    for tag, el in els:
        kind = tag.split("_")[1]
        I, J = ctx.marker(el, "i_marker_id"), ctx.marker(el, "j_marker_id")
        if kind == "PTCV":
            geo = (geo_ref(el, "curve_id", curves, "Reference_ParamCurve"),)
        elif kind == "PTSF":
            geo = (geo_ref(el, "surface_id", surfs, "Reference_ParamSurface"),)
        elif kind == "CVCV":
            geo = (geo_ref(el, "i_curve_id", curves, "Reference_ParamCurve"),
                   geo_ref(el, "j_curve_id", curves, "Reference_ParamCurve"))
        elif kind == "CVSF":
            geo = (geo_ref(el, "curve_id", curves, "Reference_ParamCurve"),
                   geo_ref(el, "surface_id", surfs, "Reference_ParamSurface"))
        else:
            geo = (geo_ref(el, "i_surface_id", surfs, "Reference_ParamSurface"),
                   geo_ref(el, "j_surface_id", surfs, "Reference_ParamSurface"))
        if any(g is None for g in geo):
            continue
        if kind == "CVCV" and el.attrs.get("is_no_slip"):
            pc.warn(el.loc, "is_no_slip is not modelled (statics: the rolling constraint is a "
                    "velocity constraint); the contact is treated as sliding")
        try:
            seeds = _seed(kind, el, geo, P0[I], A0[I], P0[J], A0[J])
        except EvaluationError as e:
            _eval_problem(pc, el, e, f"sampling the geometry to seed <{tag} id={el.id}>; it must "
                          "be defined on its whole parameter range")
            continue
        owner = len(ids)
        ids.append(el.id)
        tags.append(tag)
        scols = [ctx.add_extra(f"{el.loc.prefix()[:-1]} {nm}", float(s0))
                 for nm, s0 in zip(PARAM_NAMES[kind], seeds)]
        crow = [ctx.add_row(el, nm, "trans", "curves", owner) for nm in ROW_NAMES[kind]]
        acc[kind].append((I, J, owner, crow, scols, geo, el))
        ctx.effect(tag)
    pc.raise_if_any()
    ctx.output("curves", np.array(tags, dtype=str), ids)
    for kind, lst in acc.items():
        if not lst:
            continue
        cls, (sml, skind), m, U = F.FAMILIES[kind]
        n = len(lst)
        plane = None
        if kind == "CVCV":
            try:
                plane = np.array([_plane_basis(x[5][1], x[6].loc, pc) for x in lst])
            except EvaluationError as e:
                _eval_problem(pc, lst[0][6], e, "sampling curve J of a Constraint_CVCV")
                continue
        geo = tuple(x[5] for x in lst)
        ctx.add_family(cls(
            name=f"curves:{kind.lower()}", markers=np.array([[x[0], x[1]] for x in lst], int),
            slot_ml=sml, slot_kind=np.tile(skind, (n, 1)), owner=np.array([x[2] for x in lst]),
            m=m, crow=np.array([x[3] for x in lst], int),
            scols=np.array([x[4] for x in lst], int), geo=geo, geo_groups=F.geometry_groups(geo),
            plane=plane, group="curves", element_locs=tuple(x[6].loc for x in lst)))
    pc.raise_if_any()
    ctx.add_frame_hook(curves_frame_hook)


def _seed(kind, el, geo, PI, AI, PJ, AJ):
    a = el.attrs

    def disp(prefix):
        v = [a.get(f"{prefix}{c}0") for c in "xyz"]
        return None if any(x is None for x in v) else np.array(v, float)

    if kind == "PTCV":
        d = disp("disp_")
        p = PI if d is None else d                       # global
        return [CD.project_curve(geo[0], AJ.T @ (p - PJ))]
    if kind == "PTSF":
        d = disp("disp_")                                # J-marker coordinates
        p = AJ.T @ (PI - PJ) if d is None else d
        return list(CD.project_surface(geo[0], p))
    di, dj = disp("i_disp_"), disp("j_disp_")
    # geometry i in J coordinates and vice versa
    to_j = lambda x: AJ.T @ (PI + AI @ x - PJ)            # noqa: E731
    to_i = lambda x: AI.T @ (PJ + AJ @ x - PI)            # noqa: E731
    if kind in ("CVCV", "CVSF"):
        if di is None:
            us, ci = CD.sample_curve(geo[0])
            cj = (CD.sample_curve(geo[1])[1] if kind == "CVCV" else CD.sample_surface(geo[1])[2])
            cij = np.einsum("ij,nj->ni", AJ.T @ AI, ci) + AJ.T @ (PI - PJ)
            D = ((cij[:, None, :] - cj[None, :, :]) ** 2).sum(-1)
            di = ci[np.unravel_index(np.argmin(D), D.shape)[0]]
        ui = CD.project_curve(geo[0], di)
        pj = dj if dj is not None else to_j(geo[0].derivs([ui], 0)[0][0])
        if kind == "CVCV":
            return [ui, CD.project_curve(geo[1], pj)]
        return [ui, *CD.project_surface(geo[1], pj)]
    # SFSF
    if di is None:
        ui_, vi_, si = CD.sample_surface(geo[0], 31)
        _, _, sj = CD.sample_surface(geo[1], 31)
        sij = np.einsum("ij,nj->ni", AJ.T @ AI, si) + AJ.T @ (PI - PJ)
        D = (sij ** 2).sum(1)[:, None] + (sj ** 2).sum(1)[None, :] - 2 * sij @ sj.T
        di = si[np.unravel_index(np.argmin(D), D.shape)[0]]
    uvi = CD.project_surface(geo[0], di)
    pj = dj if dj is not None else to_j(geo[0].derivs([uvi[0]], [uvi[1]], 0)[(0, 0)][0])
    _ = to_i
    return [*uvi, *CD.project_surface(geo[1], pj)]


def curves_frame_hook(model, state):
    """Per-frame contact outputs, one row per higher-pair constraint (deck order of groups)."""
    o = model.outputs["curves"]
    n = len(o["ids"])
    par = np.full((n, 4), np.nan)
    pt = np.zeros((n, 3))
    P, A, pos = model.marker_kinematics(state)
    for fam in model.families:
        if not isinstance(fam, F.CurveFamily):
            continue
        kin = slot_kinematics(fam.markers, fam.slot_ml, fam.slot_kind, P, A, model.marker_body,
                              pos)
        par[fam.owner, :fam.U] = state.extra[fam.scols]
        pt[fam.owner] = fam.contact(kin, state.extra)
    return {"curves/id": np.asarray(o["ids"]), "curves/tag": np.asarray(o["tag"]),
            "curves/parameters": par, "curves/point": pt}


ELEMENTS = (ElementType(
    "curves", TAGS, compile_curves,
    rank=140,                   # curve rows and parameters after the user constraints
    kernels=lambda: (F.PointOnCurve, F.PointOnSurface, F.CurveOnCurve, F.CurveOnSurface,
                     F.SurfaceOnSurface), potential_energy=workless,
    time_dependent=static,      # TIME in curve geometry is a located error (compile_curves)
    outputs=(OutputGroup("curves", "Cv", "curve", "curve constraint",
                         "`Constraint_PTCV/CVCV/PTSF/CVSF/SFSF`", TAGS,
                         ("id", "tag", "label", "parameters", "point", "force", "torque")),),
    reactions={"PTCV": ("curves", ("Constraint_PTCV",)), "CVCV": ("curves", ("Constraint_CVCV",))},
    reaction_aliases={"CONSTRAINT_PTCV": "PTCV", "CONSTRAINT_CVCV": "CVCV"},
    fd_tests="tests/reference/test_curves.py"),)
