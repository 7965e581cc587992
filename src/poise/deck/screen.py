"""Column-wise screen of a parsed deck: which elements may have a problem at all.

Elements with the same tag, section and attribute names are checked column by column (C-level
passes over the values, batched orthonormality and inertia eigenvalues), so that on a large
deck only the elements that may have a problem go through :mod:`poise.deck.checks`, which then
report exactly as they would alone.
"""
from __future__ import annotations

import functools

import numpy as np

from poise.deck.checks import (DCM, DCM_CHECK, EIG, ORTHO_TOL, eigvalsh, inertia, ref_attrs,
                               required_attrs)
from poise.deck.schema import element_schema
from poise.deck.schema_types import Attr
from poise.deck.spec import Element, Expr

schema_of = functools.cache(element_schema)   # per-tag memo (called per element)


_NONE = type(None)
_NO_NUMBER = frozenset({bool, tuple, Expr, _NONE})     # values _check_value never reports


def _column_ok(a: Attr, col: tuple, types: set) -> bool:
    """True when :func:`poise.deck.checks._check_value` reports nothing for any value of the column."""
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


class Screen:
    """Per-shape screening of all elements: elements with the same tag, section and attribute
    names are checked column by column (C-level passes over the values), and only elements that
    may have a problem go through the element-by-element checks — which then report exactly as
    before, in document order.

    Flags (per element of ``els``): ``values`` (:func:`check_element` reports nothing),
    ``marker`` (:func:`check_marker` reports nothing), ``expr`` (holds an expression).
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
        DCM_CHECK.clear()
        EIG.clear()
        for (tag, cmd, keys), idx in groups.items():
            sch = schema_of(tag)
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
                ok = ok and all(a.name in names for a in required_attrs(sch))
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
        dcm = [pos.get(n) for n in DCM]
        full = all(i is not None and types[i] == {float} for i in dcm)
        forms = sum(bool(x) for x in (
            [n for n in DCM if n in names], [n for n in ("psi", "theta", "phi") if n in names],
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
            # the markers check_marker will see read their batch results
            for r in (np.flatnonzero(bad) if quiet else range(len(rows))):
                DCM_CHECK[id(g[rows[r]])] = (float(err[r]), float(det[r]))
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
        if all(i is None or types[i] == {float} for i in comp):    # as inertia, by columns
            z = np.zeros(len(g))
            xx, yy, zz, xy, yz, xz = (z if i is None else np.array(cols[i]) for i in comp)
            T = np.stack([xx, -xy, -xz, -xy, yy, -yz, -xz, -yz, zz], 1)[rows].reshape(-1, 3, 3)
        else:
            T = np.array([inertia(el) for el in sel]).reshape(-1, 3, 3)
        nz = np.any(T, axis=(1, 2)) & np.isfinite(T).all(axis=(1, 2))  # non-finite: check_body
        eig = eigvalsh(T[nz])
        pd = (eig.min(axis=1) > 1e-12 * np.maximum(1.0, np.abs(eig).max(axis=1))).tolist()
        it = zip(eig, pd)
        for el, z in zip(sel, nz.tolist()):
            EIG[id(el)] = (True, *next(it)) if z else (False, None)

    def refs(self, ids: dict) -> list[bool]:
        """Per element: every id reference exists (the reference check reports nothing)."""
        ok = [False] * len(self.els)
        for tag, _cmd, keys, idx, cols, _types in self.groups:
            refs = ref_attrs(schema_of(tag))
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
