"""Element-by-element deck checks: values against the schema, bodies, markers, specific rules.

Each check reports through a :class:`~poise.core.errors.ProblemCollector` with the element's
location. They are the reference behaviour: :mod:`poise.deck.screen` decides column-wise which
elements need them, and fills :data:`DCM_CHECK` and :data:`EIG` with batch results that
:func:`check_marker` and :func:`check_body` then read instead of recomputing.
"""
from __future__ import annotations

import numbers
from typing import Any

import numpy as np

from poise.deck.matrix import matrix_values
from poise.deck.schema_types import NAMESPACES, Attr, ElementSchema
from poise.deck.spec import Element, Expr
from poise.core.errors import ProblemCollector


ORTHO_TOL = 1e-6
_KIND_TEXT = {"real": "a real number", "int": "an integer", "bool": "TRUE or FALSE",
              "real_or_expr": "a number or an expression", "int_list": "a list of integers",
              "real_list": "a list of real numbers", "expr": "an expression", "str": "text"}
DCM = tuple(f"a{r}{c}" for c in range(3) for r in range(3))
_SCALAR_KINDS = frozenset({"real", "int", "bool", "real_or_expr"})


def ns_text(ns: str) -> str:
    return " or ".join(NAMESPACES[ns])


# --------------------------------------------------------------------------- attribute checks
def _check_value(pc: ProblemCollector, el: Element, a: Attr, v: Any) -> None:
    """Type, enum and bounds check of one typed attribute value."""
    k = a.kind
    if k == "enum":
        if v not in a.choices:
            pc.error(el.loc, f"unknown value for '{a.name}'; expected one of "
                             f"{', '.join(a.choices)}, got '{v}'")
        return
    if k in ("str", "expr"):
        return
    if isinstance(v, str):
        what = "empty value" if not v.strip() else "invalid value"
        if k in ("real", "int"):
            x = _looks_numeric(v)
            what = ("not a number" if x is None else "not a finite number" if not np.isfinite(x)
                    else "not an integer")
        pc.error(el.loc, f"attribute '{a.name}' is {what}; expected {_KIND_TEXT[k]}, got '{v}'")
        return
    if k in _SCALAR_KINDS and not isinstance(v, (numbers.Real, Expr, type(None))):
        # only an in-memory edit gets here (poise.solve(spec) after attrs[...] = [1, 2])
        pc.error(el.loc, f"attribute '{a.name}' is a {type(v).__name__}; expected "
                         f"{_KIND_TEXT[k]}, got {' '.join(repr(v).split())[:80]}")
        return
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        if not np.isfinite(v):
            pc.error(el.loc, f"attribute '{a.name}' is not a finite number; expected "
                             f"{_KIND_TEXT[k]}, got {v}")
            return
        bad = ((a.lo is not None and (v < a.lo or (a.lo_open and v == a.lo)))
               or (a.hi is not None and (v > a.hi or (a.hi_open and v == a.hi))))
        if bad:
            pc.error(el.loc, f"attribute '{a.name}' out of range; expected {a.bounds_text()}, "
                             f"got {v:g}")


def _looks_numeric(v: str) -> float | None:
    """``float()`` of a number-like string (``inf``, ``nan`` and ``1.5D0`` included) or None."""
    try:
        return float(v.strip().replace("d", "e").replace("D", "e"))
    except ValueError:
        return None


_REQUIRED: dict[str, tuple] = {}   # tag -> required attributes (schema order)
_REFS: dict[str, dict] = {}        # tag -> {name: Attr} of id-reference attributes


def required_attrs(sch: ElementSchema) -> tuple:
    r = _REQUIRED.get(sch.tag)
    if r is None:
        r = _REQUIRED[sch.tag] = tuple(a for a in sch.attrs.values() if a.required)
    return r


def ref_attrs(sch: ElementSchema) -> dict:
    r = _REFS.get(sch.tag)
    if r is None:
        r = _REFS[sch.tag] = {n: a for n, a in sch.attrs.items() if a.ref is not None}
    return r


def check_element(pc: ProblemCollector, el: Element, sch: ElementSchema) -> None:
    get = sch.attrs.get
    for name, v in el.attrs.items():
        a = get(name)
        if a is None:
            continue
        # fast paths (no problem possible): finite unbounded float, bool of a bool attribute
        tv = type(v)
        if (tv is float and a.lo is None and a.hi is None and v - v == 0.0
                and a.kind not in ("enum", "str", "expr")):
            continue
        if tv is bool and a.kind == "bool":
            continue
        _check_value(pc, el, a, v)
    if el.is_command:
        if "id" in sch.attrs and "id" not in el.attrs:
            pc.error(el.loc, "missing required attribute 'id'; expected the id of the model "
                             "element to modify, got nothing")
        return
    for a in required_attrs(sch):
        if a.name in el.attrs:
            continue
        if el.tag == "Body_Rigid" and a.name == "cg_id" and el.get("isground") is True:
            continue
        exp = (f"one of {', '.join(a.choices)}" if a.choices else
               f"an id of {ns_text(a.ref)}" if a.ref else _KIND_TEXT.get(a.kind, a.kind))
        pc.error(el.loc, f"missing required attribute '{a.name}'; expected {exp}, got nothing")


# --------------------------------------------------------------------------- model checks
def _num(el: Element, name: str, default: float = 0.0) -> float:
    v = el.get(name, default)
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else default


def inertia(el: Element) -> np.ndarray:
    xx, yy, zz = (_num(el, f"inertia_{c}") for c in ("xx", "yy", "zz"))
    xy, yz, xz = (_num(el, f"inertia_{c}") for c in ("xy", "yz", "xz"))
    return np.array([[xx, -xy, -xz], [-xy, yy, -yz], [-xz, -yz, zz]])


def check_body(pc: ProblemCollector, el: Element, markers: dict[int, Element]) -> None:
    for attr in ("cg_id", "im_id"):
        mid = el.get(attr)
        m = markers.get(mid) if isinstance(mid, int) else None
        if m is not None and m.get("body_id") != el.id and isinstance(m.get("body_id"), int):
            pc.error(el.loc, f"{attr} marker {mid} belongs to body {m.get('body_id')}; expected a "
                             f"marker on body {el.id}, got marker of line {m.loc.line}")
    if el.get("isground") is True:
        return
    mass = el.get("mass")
    if not isinstance(mass, (int, float)) or isinstance(mass, bool) or mass == 0:
        if not isinstance(mass, str):
            pc.warn(el.loc, "moving body has no mass; it must be fully constrained or fixed to a "
                            "massive body")
        return
    if el.tag != "Body_Rigid":
        return
    if not _finite_attrs(el, ("mass", *_INERTIA)):   # reported once, by the attribute check
        return
    pre = EIG.get(id(el))
    if pre is None:
        tensor = inertia(el)
        pre = (bool(np.any(tensor)), None)
    if not pre[0]:
        if mass > 0:
            pc.warn(el.loc, "moving body has mass but no inertia; its rotations must be constrained")
        return
    eig = eigvalsh(tensor[None])[0] if pre[1] is None else pre[1]
    if len(pre) > 2 and pre[2]:       # positive definite (checked in one batch)
        return
    if eig.min() <= 1e-12 * max(1.0, float(np.abs(eig).max())):
        what = ("not positive definite" if eig.min() <= 0 else
                "numerically singular (smallest/largest eigenvalue < 1e-12)")
        pc.error(el.loc, f"inertia tensor is {what} (products of inertia are "
                         "+integral(xy dm)); expected all eigenvalues > 0, got "
                         f"[{', '.join(f'{x:.6g}' for x in eig)}]")


_INERTIA = tuple(f"inertia_{c}" for c in ("xx", "yy", "zz", "xy", "yz", "xz"))


def _finite_attrs(el: Element, names) -> bool:
    """Every one of ``names`` that is given is a finite number (not a string, inf or nan)."""
    for n in names:
        if n in el.attrs:
            v = el.attrs[n]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v - v == 0.0:
                return False
    return True


def eigvalsh(T: np.ndarray) -> np.ndarray:
    """Eigenvalues of finite symmetric 3x3 tensors ``T[k]``, each scaled by its largest entry
    first (no overflow in LAPACK for entries near the float limit)."""
    if not len(T):
        return np.zeros((0, 3))
    s = np.abs(T).max(axis=(1, 2))
    s = np.where(s > 0, s, 1.0)
    return np.linalg.eigvalsh(T / s[:, None, None]) * s[:, None]


def check_marker(pc: ProblemCollector, el: Element) -> None:
    given = [n for n in DCM if n in el.attrs]
    forms = sum(bool(x) for x in (given, [n for n in ("psi", "theta", "phi") if el.has(n)],
                                  [n for n in ("yaw", "pitch", "roll") if el.has(n)],
                                  [n for n in ("e0", "e1", "e2", "e3") if el.has(n)]))
    if forms > 1:
        pc.warn(el.loc, "several orientation forms given; direction cosines win, then Euler "
                        "parameters, then psi/theta/phi, then yaw/pitch/roll")
    if given:
        if len(given) < 9:
            missing = [n for n in DCM if n not in el.attrs]
            pc.error(el.loc, f"incomplete direction cosines; expected all of a00..a22, got "
                             f"missing {', '.join(missing)}")
            return
        if any(not isinstance(el.attrs[n], float) for n in DCM):
            return  # already reported as non-numeric
        pre = DCM_CHECK.get(id(el))
        if pre is not None:
            err, det = pre
        else:
            A = np.array([[el.attrs[f"a{r}{c}"] for c in range(3)] for r in range(3)])
            err, det = float(np.abs(A.T @ A - np.eye(3)).max()), None
        if err > ORTHO_TOL:
            pc.error(el.loc, f"direction cosines are not orthonormal; expected unit, mutually "
                             f"orthogonal columns (tolerance {ORTHO_TOL:g}), got max |A^T A - I| = {err:.3g}")
        elif (np.linalg.det(A) if det is None else det) < 0:
            pc.error(el.loc, "direction cosines form a left-handed frame; expected det = +1, got -1")
    quat = [el.get(f"e{k}") for k in range(4)]
    if any(q is not None for q in quat) and all(isinstance(q, float) for q in quat):
        n = float(np.sqrt(sum(q * q for q in quat)))
        if abs(n - 1.0) > ORTHO_TOL:
            pc.warn(el.loc, f"Euler parameters are not normalised (norm {n:.6g}); they will be normalised")


DCM_CHECK: dict[int, tuple[float, float]] = {}   # id(marker) -> (max |A^T A - I|, det A)


def check_specific(pc: ProblemCollector, el: Element, markers: dict[int, Element]) -> None:
    t = el.tag
    if t == "Constraint_Joint":
        jt = el.get("type")
        if jt == "SCREW" and not el.has("pitch"):
            pc.error(el.loc, "SCREW joint needs 'pitch'; expected a real number, got nothing")
        if jt == "RACK_PINION" and not el.has("pitch_diameter"):
            pc.error(el.loc, "RACK_PINION joint needs 'pitch_diameter'; expected a real number, got nothing")
        elif jt == "RACK_PINION" and el.get("pitch_diameter") == 0.0:
            pc.error(el.loc, "RACK_PINION joint with pitch_diameter 0; expected a non-zero pitch "
                             "diameter (the rack would not move with the pinion)", "pitch_diameter")
    if t in ("Constraint_Joint", "Constraint_Jprim") and not el.is_command:
        mi, mj = markers.get(el.get("i_marker_id")), markers.get(el.get("j_marker_id"))
        if mi is not None and mj is not None and mi.get("body_id") == mj.get("body_id"):
            pc.error(el.loc, f"I and J markers are on the same body; expected markers on two "
                             f"different bodies, got both on body {mi.get('body_id')}")
    if t == "Force_SpringDamper" and el.get("type") == "TRANSLATIONAL":
        ln = el.get("length")
        if isinstance(ln, float) and ln < 0:
            pc.error(el.loc, f"attribute 'length' out of range; expected >= 0 for a translational "
                             f"spring, got {ln:g}")
    if t == "Force_Scalar_TwoBody" and not el.is_command and not any(
            el.has(n) for n in ("val", "val_expression", "usrsub_param_string", "script_name")):
        pc.error(el.loc, "no magnitude; expected 'val' or 'val_expression', got neither")
    if t == "Reference_Matrix":
        matrix_values(el, pc)             # every matrix checked, used or not
    if t == "Simulate":
        st, en = el.get("start_time", 0.0), el.get("end_time")
        if isinstance(st, float) and isinstance(en, float) and en < st:
            pc.error(el.loc, f"end_time before start_time; expected end_time >= {st:g}, got {en:g}")


def check_expression_syntax(pc: ProblemCollector, els: list[Element]) -> None:
    """Syntax of every expression attribute (``attr col C: message``); names and ids are
    resolved later by the model compiler. Template parses are cached by ``poise.expr``."""
    if not any(isinstance(v, Expr) for el in els for v in el.attrs.values()):
        return  # no expression: do not import poise.expr (it pulls in scipy.interpolate)
    # lazy: the poise.expr package imports scipy.interpolate (decks without expressions skip it)
    from poise.expr.parser import parse
    from poise.expr.tokens import ExprSyntaxError, make_template
    for el in els:
        for name, v in el.attrs.items():
            if not isinstance(v, Expr) or v.text.strip().upper() == "NULL":
                continue
            try:
                tmpl, _ = make_template(v.text)
                if "#" in v.text:
                    raise ExprSyntaxError("template", 0)
                parse(tmpl, True)
            except ExprSyntaxError:
                try:
                    parse(v.text)
                except ExprSyntaxError as e:
                    pc.error(el.loc, e.message, f"{name} col {e.col}")


EIG: dict[int, tuple] = {}   # id(body) -> (tensor non-zero, eigenvalues or None)
