"""VARIABLE, DIFF, SPLINE, ARRAY, MATRIX, CURVE, REQUEST, EQUILIBRIUM and INTEGRATOR -> the
Reference_*, Control_Diff, Post_Request, Param_Static and Param_Transient elements.

A SPLINE's Y values come per Z curve (``Y=y(x1,z1)..y(xn,z1), y(x1,z2)..``) and are written in
the XML surface layout (z values, then one row per x). A CURVE through a MATRIX of points
(CURVE_POINTS) becomes a spline Reference_ParamCurve with the points inline; a MATRIX becomes a
Reference_Matrix. EQUILIBRIUM's ERROR, IMBALANCE, MAXIT and STABILITY are Param_Static's
max_error, max_imbalance, max_num_iter and stability; DYNAMIC (equilibrium by damped dynamics)
becomes MKEAM, and MotionSolve's ``!MS#`` lines choose FIM_S, FIM_D or MKEAM.
"""
from __future__ import annotations

import re

import numpy as np

from poise.deck.adm.records import Ctx, num

_REQ_TYPES = {"DISPLACEMENT": "MARKER_DISPLACEMENT", "VELOCITY": "MARKER_VELOCITY",
              "ACCELERATION": "MARKER_ACCELERATION", "FORCE": "MARKER_FORCE"}


def variable(ctx: Ctx, s) -> None:
    if ctx.user(s) or not ctx.need(s, "FUNCTION"):
        return
    a = {"type": "EXPRESSION", "expr": s.get("FUNCTION")}
    if s.has("IC"):
        a["ic"] = num(s.get("IC"))
    ctx.add(s, "Reference_Variable", a)


def diff(ctx: Ctx, s) -> None:
    if ctx.user(s) or not ctx.need(s, "FUNCTION"):
        return
    ic = ctx.count(s, "IC", (1, 2), ())
    if ic is None:
        return
    a = {"type": "EXPRESSION", "expr": s.get("FUNCTION")}
    if s.has("IMPLICIT"):
        a["is_implicit"] = "TRUE"
    if s.has("STATIC_HOLD"):
        a["is_static_hold"] = "TRUE"
    if ic:
        a["ic"] = num(ic[0])
    if len(ic) > 1:
        a["ic_dot"] = num(ic[1])
    ctx.add(s, "Control_Diff", a)


def spline(ctx: Ctx, s) -> None:
    if s.has("FILE") or s.has("BLOCK"):
        ctx.error(s, "SPLINE data from a FILE is not supported; expected X= and Y= values")
        return
    if not ctx.need(s, "X", "Y"):
        return
    x, y, z = s.get("X"), s.get("Y"), s.get("Z")
    a = {"linear_extrap": "TRUE"} if s.has("LINEAR_EXTRAPOLATE") else {}
    if z is None:
        if len(x) != len(y):
            ctx.error(s, f"{len(x)} X values and {len(y)} Y values; expected as many")
            return
        text = "\n".join(f"{num(p)} {num(q)}" for p, q in zip(x, y))
        ctx.add(s, "Reference_Spline", {"num_xy_pair": num(len(x)), **a}, text)
        return
    if len(y) != len(x) * len(z):
        ctx.error(s, f"{len(y)} Y values; expected one per X value for each Z value "
                     f"({len(x)} x {len(z)} = {len(x) * len(z)})")
        return
    yy = np.asarray(y, float).reshape(len(z), len(x))
    rows = [" ".join(num(v) for v in z)]
    rows += [" ".join([num(x[k])] + [num(v) for v in yy[:, k]]) for k in range(len(x))]
    ctx.add(s, "Reference_Spline", {"num_x": num(len(x)), "num_z": num(len(z)), **a},
            "\n".join(rows))


def array(ctx: Ctx, s) -> None:
    t = ctx.one_of(s, ["IC", "U", "X", "Y"], "array type", default="IC")
    if t is None:
        return
    if t == "U":
        ids = s.get("VARIABLES", [])
        for v in ids:
            if v not in ctx.stmts.get("VARIABLE", {}):
                ctx.error(s, f"VARIABLES: no VARIABLE/{v} in the dataset")
                return
        ctx.add(s, "Reference_Array", {"type": "U", "num_element": num(len(ids))},
                " ".join(num(v) for v in ids))
        return
    if t in ("X", "Y"):
        a = {"type": t}
        if s.has("SIZE"):
            a["num_element"] = num(s.get("SIZE"))
        ctx.add(s, "Reference_Array", a)
        return
    vals = s.get("NUMBERS", [])
    ctx.add(s, "Reference_Array", {"type": "IC", "num_element": num(len(vals))},
            " ".join(num(v) for v in vals))


def matrix_values(ctx: Ctx, s) -> np.ndarray | None:
    """The (rows, columns) array of a MATRIX statement (None, located, when it is wrong)."""
    cache = ctx.__dict__.setdefault("_matrices", {})
    if s.id in cache:
        return cache[s.id]
    out = None
    if s.has("FILE"):
        ctx.error(s, "MATRIX data from a FILE is not supported; expected VALUES=")
    elif ctx.need(s, "ROWS", "COLUMNS", "VALUES"):
        nr, nc, v = s.get("ROWS"), s.get("COLUMNS"), np.asarray(s.get("VALUES"), float)
        if nr < 1 or nc < 1:
            ctx.error(s, f"ROWS={nr}, COLUMNS={nc}; expected positive sizes")
        elif s.has("SPARSE"):
            i, j = s.get("I", []), s.get("J", [])
            if not (len(i) == len(j) == len(v)):
                ctx.error(s, f"{len(i)} I, {len(j)} J and {len(v)} VALUES; expected as many")
            elif any(not 1 <= r <= nr for r in i) or any(not 1 <= c <= nc for c in j):
                ctx.error(s, f"an I or J index lies outside the {nr} x {nc} matrix")
            else:
                out = np.zeros((nr, nc))
                out[np.asarray(i) - 1, np.asarray(j) - 1] = v
        elif len(v) != nr * nc:
            ctx.error(s, f"{len(v)} VALUES; expected ROWS x COLUMNS = {nr * nc}")
        else:
            order = str(s.get("FULL", "RORDER")).upper()
            if order not in ("RORDER", "CORDER"):
                ctx.error(s, f"FULL={s.get('FULL')}; expected RORDER or CORDER")
            else:
                out = v.reshape(nr, nc) if order == "RORDER" else v.reshape(nc, nr).T
    cache[s.id] = out
    return out


def matrix(ctx: Ctx, s) -> None:
    m = matrix_values(ctx, s)
    if m is None:
        return
    a = {"nrow": num(m.shape[0]), "ncol": num(m.shape[1])}
    if s.has("SPARSE"):
        i, j, v = s.get("I"), s.get("J"), s.get("VALUES")
        a.update(issparse="TRUE", nval=num(len(v)))
        text = "\n".join(f"{num(r)} {num(c)} {num(x)}" for r, c, x in zip(i, j, v))
    else:
        rows = str(s.get("FULL", "RORDER")).upper() == "RORDER"
        a["isroworder"] = "TRUE" if rows else "FALSE"
        text = " ".join(num(x) for x in (m.ravel() if rows else m.T.ravel()))
    ctx.add(s, "Reference_Matrix", a, text)


def curve(ctx: Ctx, s) -> None:
    if ctx.user(s):
        return
    if not ctx.need(s, "MATRIX"):
        return
    if not s.has("CURVE_POINTS"):
        ctx.refuse(s, "CURVE", "a B-spline curve through control points (poise's curves pass "
                               "through their points: CURVE_POINTS)")
        return
    ms = ctx.ref(s, "MATRIX", "MATRIX")
    m = None if ms is None else matrix_values(ctx, ms)
    if m is None:
        return
    if m.shape[1] != 3 or m.shape[0] < 2:
        ctx.error(s, f"MATRIX/{ms.id} is {m.shape[0]} x {m.shape[1]}; expected one x y z row "
                     "per point (3 columns, 2 rows or more)")
        return
    a = {"is_curve_points": "TRUE", "num_pts": num(m.shape[0])}
    if s.has("CLOSED"):
        a["is_u_closed"] = "TRUE"
    if s.has("MINPAR"):
        a["u_start"] = num(s.get("MINPAR"))
    if s.has("MAXPAR"):
        a["u_end"] = num(s.get("MAXPAR"))
    text = "\n".join(" ".join(num(v) for v in row) for row in m)
    ctx.add(s, "Reference_ParamCurve", a, text)


def request(ctx: Ctx, s) -> None:
    if s.has("FUNCTION") or s.has("ROUTINE"):
        ctx.warn(s, "a request computed by a user subroutine (output only) is skipped")
        return
    t = ctx.one_of(s, list(_REQ_TYPES), "request type", default="")
    if t is None:
        return
    fs = [f"F{k}" for k in range(1, 9) if s.has(f"F{k}")]
    if t and fs:
        ctx.error(s, f"{t} and {', '.join(fs)} both given; expected a marker request or "
                     "F1..F8 expressions")
        return
    a = {}
    if t:
        if ctx.marker(s, "I") is None:
            return
        a = {"type": _REQ_TYPES[t], "i_marker_id": num(s.get("I"))}
        for key, name in (("J", "j_marker_id"), ("RM", "ref_marker_id")):
            if s.has(key):
                if ctx.marker(s, key) is None:
                    return
                a[name] = num(s.get(key))
    elif fs:
        fs = _computable(ctx, s, fs)
        if not fs:
            return
        a = {"type": "EXPRESSION", **{f"expr{f[1]}": s.get(f) for f in fs}}
    else:
        ctx.warn(s, "a request with no marker type and no F1..F8 expressions (e.g. VARIABLES=) "
                    "is skipped")
        return
    if s.has("COMMENT"):
        a["comment"] = s.get("COMMENT")
    ctx.add(s, "Post_Request", a)


_CALL = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)\s*\(")


def _computable(ctx: Ctx, s, fs: list) -> list:
    """The request channels whose functions poise computes; the others (e.g. ``ORIENT``) are
    left out with one warning: a request is output only."""
    from poise.expr.lower import known_function  # lazy: the expression language imports scipy
    keep, unknown = [], {}
    for f in fs:
        names = sorted({n.upper() for n in _CALL.findall(s.get(f)) if not known_function(n)})
        if names:
            unknown[f] = names
        else:
            keep.append(f)
    if unknown:
        fns = sorted({n for v in unknown.values() for n in v})
        ctx.warn(s, f"{', '.join(unknown)} left out: poise does not compute {', '.join(fns)} "
                    "(a request is output only)" + ("" if keep else "; the request is skipped"))
    return keep


def equilibrium(ctx: Ctx, s, section: str = "model") -> None:
    a = {}
    for key, name in (("ERROR", "max_error"), ("IMBALANCE", "max_imbalance"),
                      ("MAXIT", "max_num_iter"), ("STABILITY", "stability"),
                      ("COMPDELTA", "compliance_delta"), ("KINETIC_ENERGY_ERROR", "max_ke_tol"),
                      ("MAX_KE_TOL", "max_ke_tol"), ("MAX_DQ_TOL", "max_dq_tol")):
        if s.has(key):
            a[name] = num(s.get(key))
    m = ctx.one_of(s, ["FIM_S", "FIM_D", "MKEAM", "DYNAMIC"], "method", default="")
    if m is None:
        return
    if m:
        a["method"] = "MKEAM" if m == "DYNAMIC" else m
    ctx.add(s, "Param_Static", a, section=section)


_MS_INTEGRATORS = ("GSTIFF", "DSTIFF", "CSTIFF", "VSTIFF", "MSTIFF", "ABAM")


def integrator(ctx: Ctx, s, section: str = "model") -> None:
    a = {}
    kinds = [k for k, kw in s.defn.flags.items() if s.has(k) and not kw.ignored]
    if len(kinds) > 1:
        ctx.error(s, f"{' and '.join(kinds)} both given; expected one integrator")
        return
    if kinds:
        if kinds[0] in _MS_INTEGRATORS:
            a["integrator_type"] = kinds[0]
        else:
            ctx.warn(s, f"{kinds[0]} has no MotionSolve counterpart; FIM_D integrates with its "
                        "own BDF (IDA) either way")
    for key, name in (("ERROR", "integr_tol"), ("HMAX", "h_max"), ("HMIN", "h_min"),
                      ("HINIT", "h0_max"), ("KMAX", "max_order"), ("MAXIT", "dae_corrector_maxit"),
                      ("MINIT", "dae_corrector_minit"), ("CONSTR_TOL", "dae_constr_tol")):
        if s.has(key):
            a[name] = num(s.get(key))
    if s.has("VEL_CTRL"):
        a["dae_vel_ctrl"] = "TRUE" if s.get("VEL_CTRL") else "FALSE"
    if s.has("JACINIT"):
        a["dae_jacob_init"] = s.get("JACINIT")
    ctx.add(s, "Param_Transient", a, section=section)


TRANSLATORS = {"VARIABLE": variable, "DIFF": diff, "SPLINE": spline, "ARRAY": array,
               "MATRIX": matrix, "CURVE": curve, "REQUEST": request,
               "EQUILIBRIUM": equilibrium, "INTEGRATOR": integrator}
