"""Deck validation: one pass over a :class:`~poise.deck.spec.DeckSpec`, every problem collected.

Messages read ``FILE:LINE: <Tag id=N>: problem; expected ..., got ...``. Problems that belong to
the whole file rather than one element (malformed XML, no ground body) read ``FILE:LINE: problem``.
Warnings (moving body without mass, unknown attributes from the parser, ...) go to
``DeckSpec.warnings``; errors are raised together as one :class:`~poise.core.errors.DeckError`.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np

from poise.deck.schema import NAMESPACES, Attr, ElementSchema, element_schema, namespace_of
from poise.deck.spec import DeckSpec, Element, Expr
from poise.core.errors import Problem, ProblemCollector, SourceLoc, one_line

ORTHO_TOL = 1e-6
_KIND_TEXT = {"real": "a real number", "int": "an integer", "bool": "TRUE or FALSE",
              "real_or_expr": "a number or an expression", "int_list": "a list of integers",
              "real_list": "a list of real numbers", "expr": "an expression", "str": "text"}
_DCM = tuple(f"a{r}{c}" for c in range(3) for r in range(3))


@dataclass(frozen=True)
class FileProblem(Problem):
    """A problem of the whole file: ``FILE:LINE: message`` (no element prefix)."""

    def __str__(self) -> str:
        return one_line(f"{self.loc.file}:{self.loc.line}: {self.message}")


def _ns_text(ns: str) -> str:
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


def _required(sch: ElementSchema) -> tuple:
    r = _REQUIRED.get(sch.tag)
    if r is None:
        r = _REQUIRED[sch.tag] = tuple(a for a in sch.attrs.values() if a.required)
    return r


def _refs(sch: ElementSchema) -> dict:
    r = _REFS.get(sch.tag)
    if r is None:
        r = _REFS[sch.tag] = {n: a for n, a in sch.attrs.items() if a.ref is not None}
    return r


def _check_element(pc: ProblemCollector, el: Element, sch: ElementSchema) -> None:
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
    for a in _required(sch):
        if a.name in el.attrs:
            continue
        if el.tag == "Body_Rigid" and a.name == "cg_id" and el.get("isground") is True:
            continue
        exp = (f"one of {', '.join(a.choices)}" if a.choices else
               f"an id of {_ns_text(a.ref)}" if a.ref else _KIND_TEXT.get(a.kind, a.kind))
        pc.error(el.loc, f"missing required attribute '{a.name}'; expected {exp}, got nothing")


# --------------------------------------------------------------------------- model checks
def _num(el: Element, name: str, default: float = 0.0) -> float:
    v = el.get(name, default)
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else default


def _inertia(el: Element) -> np.ndarray:
    xx, yy, zz = (_num(el, f"inertia_{c}") for c in ("xx", "yy", "zz"))
    xy, yz, xz = (_num(el, f"inertia_{c}") for c in ("xy", "yz", "xz"))
    return np.array([[xx, -xy, -xz], [-xy, yy, -yz], [-xz, -yz, zz]])


def _check_body(pc: ProblemCollector, el: Element, markers: dict[int, Element]) -> None:
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
    pre = _EIG.get(id(el))
    if pre is None:
        tensor = _inertia(el)
        pre = (bool(np.any(tensor)), None)
    if not pre[0]:
        if mass > 0:
            pc.warn(el.loc, "moving body has mass but no inertia; its rotations must be constrained")
        return
    eig = _eigvalsh(tensor[None])[0] if pre[1] is None else pre[1]
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


def _eigvalsh(T: np.ndarray) -> np.ndarray:
    """Eigenvalues of finite symmetric 3x3 tensors ``T[k]``, each scaled by its largest entry
    first (no overflow in LAPACK for entries near the float limit)."""
    if not len(T):
        return np.zeros((0, 3))
    s = np.abs(T).max(axis=(1, 2))
    s = np.where(s > 0, s, 1.0)
    return np.linalg.eigvalsh(T / s[:, None, None]) * s[:, None]


def _check_marker(pc: ProblemCollector, el: Element) -> None:
    given = [n for n in _DCM if n in el.attrs]
    forms = sum(bool(x) for x in (given, [n for n in ("psi", "theta", "phi") if el.has(n)],
                                  [n for n in ("yaw", "pitch", "roll") if el.has(n)],
                                  [n for n in ("e0", "e1", "e2", "e3") if el.has(n)]))
    if forms > 1:
        pc.warn(el.loc, "several orientation forms given; direction cosines win, then Euler "
                        "parameters, then psi/theta/phi, then yaw/pitch/roll")
    if given:
        if len(given) < 9:
            missing = [n for n in _DCM if n not in el.attrs]
            pc.error(el.loc, f"incomplete direction cosines; expected all of a00..a22, got "
                             f"missing {', '.join(missing)}")
            return
        if any(not isinstance(el.attrs[n], float) for n in _DCM):
            return  # already reported as non-numeric
        pre = _DCM_CHECK.get(id(el))
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


_DCM_CHECK: dict[int, tuple[float, float]] = {}   # id(marker) -> (max |A^T A - I|, det A)


def _check_specific(pc: ProblemCollector, el: Element, markers: dict[int, Element]) -> None:
    t = el.tag
    if t == "Constraint_Joint":
        jt = el.get("type")
        if jt == "SCREW" and not el.has("pitch"):
            pc.error(el.loc, "SCREW joint needs 'pitch'; expected a real number, got nothing")
        if jt == "RACK_PINION" and not el.has("pitch_diameter"):
            pc.error(el.loc, "RACK_PINION joint needs 'pitch_diameter'; expected a real number, got nothing")
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
    if t == "Simulate":
        st, en = el.get("start_time", 0.0), el.get("end_time")
        if isinstance(st, float) and isinstance(en, float) and en < st:
            pc.error(el.loc, f"end_time before start_time; expected end_time >= {st:g}, got {en:g}")


# --------------------------------------------------------------------------- driver
def _check_expression_syntax(pc: ProblemCollector, els: list[Element]) -> None:
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


_EIG: dict[int, tuple] = {}   # id(body) -> (tensor non-zero, eigenvalues or None)
_NONE = type(None)
_NO_NUMBER = frozenset({bool, tuple, Expr, _NONE})     # values _check_value never reports
_SPECIFIC = frozenset({"Constraint_Joint", "Constraint_Jprim", "Force_SpringDamper",
                       "Force_Scalar_TwoBody", "Simulate"})
_schema = functools.cache(element_schema)   # per-tag memos (called per element)
_ns = functools.cache(namespace_of)


def _column_ok(a: Attr, col: tuple, types: set) -> bool:
    """True when :func:`_check_value` reports nothing for any value of the column."""
    k = a.kind
    if k == "enum":
        return set(col) <= set(a.choices)
    if k in ("str", "expr"):
        return True
    if types <= _NO_NUMBER:
        return True
    if types <= {float, Expr, _NONE}:
        nums = col if types == {float} else [v for v in col if type(v) is float]
        s = sum(nums)
        if not s - s == 0.0:            # a NaN / inf (or an overflowing sum: checked one by one)
            return False
    elif types <= {int, _NONE}:
        nums = col if types == {int} else [v for v in col if type(v) is int]
    else:
        return False
    if not nums:
        return True
    if a.lo is not None:
        m = min(nums)
        if m < a.lo or (a.lo_open and m == a.lo):
            return False
    if a.hi is not None:
        m = max(nums)
        if m > a.hi or (a.hi_open and m == a.hi):
            return False
    return True


class _Screen:
    """Per-shape screening of all elements: elements with the same tag, section and attribute
    names are checked column by column (C-level passes over the values), and only elements that
    may have a problem go through the element-by-element checks — which then report exactly as
    before, in document order.

    Flags (per element of ``els``): ``values`` (:func:`_check_element` reports nothing),
    ``marker`` (:func:`_check_marker` reports nothing), ``expr`` (holds an expression).
    :meth:`refs` and :meth:`body_type` flag reference and body-type problems once the ids are
    known.
    """

    def __init__(self, els: list[Element]):
        n = len(els)
        self.els = els
        values = np.zeros(n, bool)
        marker = np.zeros(n, bool)
        self.expr = [False] * n
        groups: dict[tuple, list[int]] = {}
        for k, el in enumerate(els):
            key = (el.tag, el.is_command, tuple(el.attrs))
            g = groups.get(key)
            if g is None:
                groups[key] = [k]
            else:
                g.append(k)
        self.groups = []
        _DCM_CHECK.clear()
        _EIG.clear()
        for (tag, cmd, keys), idx in groups.items():
            sch = _schema(tag)
            if sch is None or not sch.supported:
                continue
            g = [els[k] for k in idx]
            cols = list(zip(*[el.attrs.values() for el in g]))
            types = [set(map(type, c)) for c in cols]
            self.groups.append((tag, cmd, keys, idx, cols, types))
            if any(issubclass(t, Expr) for ts in types for t in ts):
                for k, el in zip(idx, g):
                    self.expr[k] = any(isinstance(v, Expr) for v in el.attrs.values())
            get = sch.attrs.get
            ok = all(_column_ok(a, c, t) for name, c, t in zip(keys, cols, types)
                     if (a := get(name)) is not None)
            names = set(keys)
            if cmd:
                ok = ok and not ("id" in sch.attrs and "id" not in names)
            else:
                ok = ok and all(a.name in names for a in _required(sch))
            if ok:
                values[idx] = True
            if tag == "Reference_Marker" and not cmd:
                self._markers(marker, idx, g, keys, cols, types, names)
            elif tag == "Body_Rigid" and not cmd:
                self._inertias(g, keys, cols, types)
        self.values = values.tolist()
        self.marker = marker.tolist()

    def _markers(self, marker, idx, g, keys, cols, types, names):
        pos = {n: i for i, n in enumerate(keys)}
        dcm = [pos.get(n) for n in _DCM]
        full = all(i is not None and types[i] == {float} for i in dcm)
        forms = sum(bool(x) for x in (
            [n for n in _DCM if n in names], [n for n in ("psi", "theta", "phi") if n in names],
            [n for n in ("yaw", "pitch", "roll") if n in names],
            [n for n in ("e0", "e1", "e2", "e3") if n in names]))
        given = any(i is not None for i in dcm)
        quiet = forms <= 1 and not any(f"e{k}" in names for k in range(4)) and (full or not given)
        if full:       # orthonormality and handedness of the whole group in one batch
            rows = range(len(g))
        elif all(i is not None for i in dcm):   # the elements with nine numeric cosines
            rows = [j for j in range(len(g)) if all(type(cols[i][j]) is float for i in dcm)]
        else:
            rows = []
        if rows:
            A = np.array([[cols[i][j] for j in rows] for i in dcm]).T.reshape(-1, 3, 3)  # [c][r]
            A = np.swapaxes(A, 1, 2)                                     # [r][c]
            with np.errstate(invalid="ignore", over="ignore"):          # inf / nan: reported
                err = np.abs(np.matmul(np.swapaxes(A, 1, 2), A) - np.eye(3)).max(axis=(1, 2))
                det = np.linalg.det(A)
                bad = (err > ORTHO_TOL) | (det < 0)
            # the markers _check_marker will see read their batch results
            for r in (np.flatnonzero(bad) if quiet else range(len(rows))):
                _DCM_CHECK[id(g[rows[r]])] = (float(err[r]), float(det[r]))
        if quiet:
            marker[idx] = ~bad if full else True

    def _inertias(self, g, keys, cols, types):
        """Inertia tensors of moving rigid bodies with a mass, eigenvalues in one batch."""
        sel, rows = [], []
        for j, el in enumerate(g):
            if el.get("isground") is True:
                continue
            mass = el.get("mass")
            if not isinstance(mass, (int, float)) or isinstance(mass, bool) or mass == 0:
                continue
            sel.append(el)
            rows.append(j)
        if not sel:
            return
        pos = {n: i for i, n in enumerate(keys)}
        comp = [pos.get(f"inertia_{c}") for c in ("xx", "yy", "zz", "xy", "yz", "xz")]
        if all(i is None or types[i] == {float} for i in comp):    # as _inertia, by columns
            z = np.zeros(len(g))
            xx, yy, zz, xy, yz, xz = (z if i is None else np.array(cols[i]) for i in comp)
            T = np.stack([xx, -xy, -xz, -xy, yy, -yz, -xz, -yz, zz], 1)[rows].reshape(-1, 3, 3)
        else:
            T = np.array([_inertia(el) for el in sel]).reshape(-1, 3, 3)
        nz = np.any(T, axis=(1, 2)) & np.isfinite(T).all(axis=(1, 2))  # non-finite: _check_body
        eig = _eigvalsh(T[nz])
        pd = (eig.min(axis=1) > 1e-12 * np.maximum(1.0, np.abs(eig).max(axis=1))).tolist()
        it = zip(eig, pd)
        for el, z in zip(sel, nz.tolist()):
            _EIG[id(el)] = (True, *next(it)) if z else (False, None)

    def refs(self, ids: dict) -> list[bool]:
        """Per element: every id reference exists (the reference check reports nothing)."""
        ok = [False] * len(self.els)
        for tag, _cmd, keys, idx, cols, _types in self.groups:
            refs = _refs(_schema(tag))
            good = True
            for name, c in zip(keys, cols):
                a = refs.get(name)
                if a is None:
                    continue
                d = ids[a.ref]
                if not all(map(d.__contains__, c)) and not all(
                        not isinstance(v, int) or isinstance(v, bool) or (v == 0 and a.zero_ok)
                        or v in d or (a.lo is not None and v < a.lo) for v in c):
                    good = False
                    break
            if good:
                for k in idx:
                    ok[k] = True
        return ok

    def body_type(self, bodies: dict) -> list[bool]:
        """Per element: a marker whose body_type contradicts its body's kind (warned)."""
        out = [False] * len(self.els)
        for tag, cmd, keys, idx, cols, _types in self.groups:
            if tag != "Reference_Marker" or cmd or "body_type" not in keys or "body_id" not in keys:
                continue
            bt_col = cols[keys.index("body_type")]
            b_col = cols[keys.index("body_id")]
            for k, bt, bid in zip(idx, bt_col, b_col):
                if bt in ("RIGIDBODY", "POINTBODY"):
                    body = bodies.get(bid)
                    if body is not None:
                        out[k] = bt != ("POINTBODY" if body.tag == "Body_Point" else "RIGIDBODY")
        return out


def _ids_fast(good: list[Element]):
    """Id tables of the model elements when no id repeats within a tag or a namespace (else
    None: :func:`validate` then walks the elements and reports each clash)."""
    by_tag: dict[str, tuple[list, list]] = {}
    for el in good:
        if el.is_command:
            continue
        i = el.attrs.get("id")
        if not isinstance(i, int):
            continue
        t = by_tag.get(el.tag)
        if t is None:
            by_tag[el.tag] = ([i], [el])
        else:
            t[0].append(i)
            t[1].append(el)
    per_tag: dict[str, dict[int, Element]] = {}
    ids: dict[str, dict[int, Element]] = {ns: {} for ns in NAMESPACES}
    for tag, (il, el_list) in by_tag.items():
        d = per_tag[tag] = dict(zip(il, el_list))
        if len(d) != len(il):
            return None
        ns = _ns(tag)
        if ns is not None:
            before = len(ids[ns])
            ids[ns].update(d)
            if len(ids[ns]) != before + len(d):
                return None
    return ids, per_tag


def validate(spec: DeckSpec) -> None:
    """Validate a parsed deck; raise one :class:`~poise.core.errors.DeckError` listing every problem.

    Parameters
    ----------
    spec : DeckSpec
        Parsed deck. Validation warnings are appended to ``spec.warnings``.

    Raises
    ------
    DeckError
        When at least one problem was found (all problems, sorted by line).
    """
    pc = ProblemCollector()
    els = [*spec.model, *spec.commands]
    scr = _Screen(els)
    good: list[Element] = []
    gidx: list[int] = []
    for k, el in enumerate(els):
        sch = _schema(el.tag)
        if sch is None:
            pc.error(el.loc, f"unknown element <{el.tag}>; expected a MotionSolve element name, "
                             f"got <{el.tag}>")
            continue
        if not sch.supported:
            pc.error(el.loc, f"<{sch.tag}> is not supported yet")
            continue
        if el.is_command and sch.kind == "model":
            pc.error(el.loc, f"<{sch.tag}> is a model element; expected it inside <Model>, got it "
                             f"in the command section")
            continue
        if not scr.values[k]:
            _check_element(pc, el, sch)
        good.append(el)
        gidx.append(k)

    # ids: unique within each element type, and within a shared namespace (bodies)
    fast = _ids_fast(good)
    if fast is not None:
        ids, per_tag = fast
    else:
        ids = {ns: {} for ns in NAMESPACES}
        per_tag = {}
        for el in good:
            if el.is_command or not isinstance(el.id, int):
                continue
            seen = per_tag.setdefault(el.tag, {})
            if el.id in seen:
                pc.error(el.loc, f"duplicate id {el.id}; expected ids unique among <{el.tag}>, "
                                 f"got id {el.id} also at line {seen[el.id].loc.line}")
                continue
            seen[el.id] = el
            ns = _ns(el.tag)
            if ns is not None:
                other = ids[ns].get(el.id)
                if other is not None:
                    pc.error(el.loc, f"{ns} id {el.id} is also used by <{other.tag}> at line "
                                     f"{other.loc.line}; expected unique {ns} ids, got a clash")
                else:
                    ids[ns][el.id] = el
    for el in spec.commands:  # arrays may be defined in the command section
        if el.tag == "Reference_Array" and isinstance(el.id, int):
            ids["array"].setdefault(el.id, el)
    markers = ids["marker"]
    refs_ok = scr.refs(ids)
    bt_bad = scr.body_type(ids["body"])

    for k, el in zip(gidx, good):
        sch = _schema(el.tag)
        refs = _refs(sch) if not refs_ok[k] else None
        for name, v in (el.attrs.items() if refs else ()):
            a = refs.get(name)
            if a is None or not isinstance(v, int) or isinstance(v, bool):
                continue
            if v == 0 and a.zero_ok:
                continue
            if v not in ids[a.ref] and not (a.lo is not None and v < a.lo):
                pc.error(el.loc, f"attribute '{name}' refers to a missing {_ns_text(a.ref)}; "
                                 f"expected an existing {a.ref} id, got {v}")
        if el.is_command and "id" in sch.attrs and isinstance(el.id, int) and el.tag != "Reference_Array":
            if el.id not in per_tag.get(el.tag, {}):
                pc.error(el.loc, f"command modifies a missing <{el.tag}>; expected the id of a model "
                                 f"<{el.tag}>, got {el.id}")
        if el.tag in _SPECIFIC:
            _check_specific(pc, el, markers)
        if el.is_command:
            continue
        if el.tag in ("Body_Rigid", "Body_Point"):
            _check_body(pc, el, markers)
        elif el.tag == "Reference_Marker":
            if not scr.marker[k]:
                _check_marker(pc, el)
            if bt_bad[k]:
                bt = el.get("body_type")
                body = ids["body"].get(el.get("body_id"))
                want = "POINTBODY" if body.tag == "Body_Point" else "RIGIDBODY"
                pc.warn(el.loc, f"body_type {bt} does not match <{body.tag}> {body.id}; using {want}")

    _check_expression_syntax(pc, [el for k, el in zip(gidx, good) if scr.expr[k]])

    _DCM_CHECK.clear()
    _EIG.clear()
    grounds = [e for e in good if e.tag == "Body_Rigid" and not e.is_command and e.get("isground") is True]
    if not grounds:
        first = next((e for e in spec.model if e.tag in NAMESPACES["body"]), None)
        loc = SourceLoc(spec.path, first.loc.line if first else 1, "xml")
        pc.problems.append(FileProblem(loc, "no ground body; expected one <Body_Rigid "
                                            "isground=\"TRUE\">, got none"))
    for g in grounds[1:]:
        pc.error(g.loc, f"more than one ground body; expected exactly one <Body_Rigid "
                        f"isground=\"TRUE\">, got another at line {grounds[0].loc.line}")

    spec.warnings.extend(pc.warnings)
    pc.problems.sort(key=lambda p: p.loc.line)
    pc.raise_if_any()


__all__ = ["validate", "FileProblem", "Expr"]
