"""The description of every constraint row, stored per deck element (``Model.row_info``).

Filled by the compilers (:meth:`poise.elements.context.CompileContext.add_row`), so the
dictionaries are never all alive at once.

A model with 10⁵ joints has 5·10⁵ constraint rows; one dictionary per row (ten keys, a location
string each) held ≈ 200 MB for the model's lifetime. :class:`RowTable` keeps the per-element
part (tag, id, line, file, label, location) once per element and the per-row part (equation,
kind, output group, owner) as small integer codes; ``table[r]`` builds row ``r``'s dictionary
on demand, with the same keys, in the same order, and the same values as before.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: keys of a row's dictionary, in order
KEYS = ("tag", "id", "equation", "line", "file", "kind", "group", "owner", "label", "where")


def _position(seq, k, what: str) -> int:
    """``k`` as a position in ``seq`` (negative: from the end); IndexError naming ``what``."""
    k = int(k)
    if k < 0:
        k += len(seq)
    if not 0 <= k < len(seq):
        raise IndexError(f"{what} index out of range")
    return k


class Texts(Sequence):
    """A sequence of strings stored as one string and their end offsets: ``t[k]`` is a fresh
    ``str`` equal to the k-th one given. A large model's per-element names (labels, locations)
    are then two objects instead of one small string each: small objects made while the
    parsed deck is alive fill the holes the parse left between its elements, and would keep
    the allocator's pages of the whole deck resident after the deck is dropped."""

    __slots__ = ("_text", "_ends")

    def __init__(self, strings=()):
        strings = list(strings)
        self._text = "".join(strings)
        self._ends = np.fromiter(map(len, strings), np.int64, len(strings)).cumsum()

    def __len__(self) -> int:
        return self._ends.size

    def __getitem__(self, k):
        if isinstance(k, slice):
            return tuple(self[i] for i in range(*k.indices(len(self))))
        k = _position(self, k, "string")
        return self._text[int(self._ends[k - 1]) if k else 0:int(self._ends[k])]

    def __iter__(self):
        ends = self._ends.tolist()
        text = self._text
        return (text[a:b] for a, b in zip([0] + ends[:-1], ends))


class _Column:
    """One column of :class:`RowTable`'s per-element part: an int64 array when every value is
    a Python ``int`` (ids, lines), else the values as a tuple; ``col[k]`` gives the value back
    with its type."""

    __slots__ = ("_v", "_ints")

    def __init__(self, values):
        values = list(values)
        self._ints = all(type(v) is int for v in values)
        try:
            self._v = np.array(values, np.int64) if self._ints else tuple(values)
        except OverflowError:                 # an int beyond 64 bits: kept as it is
            self._ints, self._v = False, tuple(values)

    def __getitem__(self, k):
        return int(self._v[k]) if self._ints else self._v[k]


class _Codes:
    """One column of few distinct values (tags, files): a code per element."""

    __slots__ = ("_values", "_code")

    def __init__(self, values):
        index: dict = {}
        code = [index.setdefault(v, len(index)) for v in values]
        self._values = tuple(index)
        self._code = np.asarray(code, np.int32)

    def __getitem__(self, k):
        return self._values[int(self._code[k])]


def element_where(tag, ident, line, file) -> str:
    """``FILE:LINE: <Tag id=N>``: where a deck element is (messages name it so)."""
    return f"{file}:{line}: <{tag} id={ident}>"


class RowTable(Sequence):
    """Constraint rows: ``len(t)``, ``t[r]`` (a fresh dict per call: the model's table cannot
    be changed through it), iteration, slices (tuples of dicts). Built row by row
    (:meth:`append`, then :meth:`freeze`), or made by :meth:`of` from row dictionaries."""

    __slots__ = ("_elements", "_el", "_eq", "_kind", "_group", "_owner", "_codes", "_n",
                 "_build")

    def __init__(self):
        self._elements: tuple = ()        # columns tag, id, line, file, label, where
        self._codes: dict = {"equation": (), "kind": (), "group": ()}
        self._el = self._eq = self._kind = self._group = self._owner = np.zeros(0, np.int32)
        self._n = 0
        self._build = None

    def append(self, el, equation: str, kind: str, group: str, owner: int) -> int:
        """Add a row of deck element ``el`` (before :meth:`freeze`); returns its index."""
        b = self._build
        if b is None:
            b = self._build = dict(elements=[], last=None, codes={w: {} for w in
                                   ("equation", "kind", "group")},
                                   cols={w: [] for w in ("el", "equation", "kind", "group",
                                                         "owner")})
        if el is not b["last"]:
            loc = el.loc
            b["elements"].append((el.tag, el.id, loc.line, loc.file,
                                  str(el.attrs.get("label") or ""), loc.prefix()[:-1]))
            b["last"] = el
        cols, codes = b["cols"], b["codes"]
        cols["el"].append(len(b["elements"]) - 1)
        for w, v in (("equation", equation), ("kind", kind), ("group", group)):
            cols[w].append(codes[w].setdefault(v, len(codes[w])))
        cols["owner"].append(owner)
        self._n += 1
        return self._n - 1

    def freeze(self) -> "RowTable":
        """The rows appended, as int32 codes and tuples (no more :meth:`append`)."""
        b, self._build = self._build, None
        if b is not None:
            self._set(b["elements"], b["codes"], b["cols"])
        return self

    def _set(self, elements, codes, cols):
        tag, ident, line, file, label, where = (zip(*elements) if elements
                                                  else ((),) * 6)
        self._elements = (_Codes(tag), _Column(ident), _Column(line), _Codes(file),
                          Texts(label), Texts(where))
        self._codes = {w: tuple(c) for w, c in codes.items()}
        self._el, self._eq, self._kind, self._group, self._owner = (
            np.asarray(cols[w], np.int64).astype(np.int32)
            for w in ("el", "equation", "kind", "group", "owner"))

    @classmethod
    def of(cls, rows):
        """The table of ``rows`` (dicts with the keys :data:`KEYS`, in order), or ``rows`` as a
        tuple when one does not have exactly those keys."""
        if isinstance(rows, RowTable):
            return rows.freeze()
        rows = tuple(rows)
        if not all(tuple(d) == KEYS for d in rows):
            return rows
        t = cls()
        elements, last = [], None
        codes = {w: {} for w in ("equation", "kind", "group")}
        cols = {w: [] for w in ("el", "equation", "kind", "group", "owner")}
        for d in rows:
            e = (d["tag"], d["id"], d["line"], d["file"], d["label"], d["where"])
            if e != last:
                elements.append(e)
                last = e
            cols["el"].append(len(elements) - 1)
            for w in ("equation", "kind", "group"):
                cols[w].append(codes[w].setdefault(d[w], len(codes[w])))
            cols["owner"].append(d["owner"])
        if any(type(d["owner"]) is not int for d in rows):
            return rows
        t._set(elements, codes, cols)
        t._n = len(rows)
        return t

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, r):
        if isinstance(r, slice):
            return tuple(self[i] for i in range(*r.indices(self._n)))
        r = _position(self, r, "constraint row")
        e = int(self._el[r])
        tag, ident, line, file, label, where = (col[e] for col in self._elements)
        c = self._codes
        return dict(tag=tag, id=ident, equation=c["equation"][int(self._eq[r])], line=line,
                    file=file, kind=c["kind"][int(self._kind[r])],
                    group=c["group"][int(self._group[r])], owner=int(self._owner[r]),
                    label=label, where=where)

    def __iter__(self):
        return (self[r] for r in range(self._n))

    def where_equation(self, r) -> tuple[str, str]:
        """``(row_where(self[r]), equation)`` of row ``r`` without building its dictionary
        (Newton names its worst equation at every iteration)."""
        r = _position(self, r, "constraint row")
        e = int(self._el[r])
        where = self._elements[5][e]
        if not where:
            where = element_where(*(col[e] for col in self._elements[:4]))
        return where, self._codes["equation"][int(self._eq[r])]

    def kind_is(self, kind: str) -> np.ndarray:
        """Boolean array: the rows whose ``kind`` is ``kind`` (no dictionary built)."""
        codes = self._codes["kind"]
        return self._kind == (codes.index(kind) if kind in codes else -1)


class CoordNames(Sequence):
    """The name of every coordinate (``Model.coord_info``): ``FILE:LINE: <Body_Rigid id=2> Fx``
    for the 6 (rigid) or 3 (point) coordinates of each body, then the scalar unknowns' names.
    Stored as one location prefix per body; ``names[k]`` builds the string on access."""

    __slots__ = ("_prefix", "_off", "_nq_bodies", "_extra")
    SUFFIX = (" Fx", " Fy", " Fz", " Tx", " Ty", " Tz")

    def __init__(self, prefixes, offsets, nq_bodies: int, extra=()):
        self._prefix = prefixes if isinstance(prefixes, Texts) else Texts(prefixes)
        self._off = np.asarray(offsets, np.int64)
        self._nq_bodies = int(nq_bodies)
        self._extra = tuple(extra)

    def with_extra(self, extra) -> "CoordNames":
        """The same names followed by ``extra``."""
        return CoordNames(self._prefix, self._off, self._nq_bodies, self._extra + tuple(extra))

    def __len__(self) -> int:
        return self._nq_bodies + len(self._extra)

    def __getitem__(self, k):
        if isinstance(k, slice):
            return tuple(self[i] for i in range(*k.indices(len(self))))
        k = _position(self, k, "coordinate")
        if k >= self._nq_bodies:
            return self._extra[k - self._nq_bodies]
        b = int(self._off.searchsorted(k, side="right")) - 1
        return self._prefix[b] + self.SUFFIX[k - int(self._off[b])]

    def __iter__(self):
        return (self[k] for k in range(len(self)))


def group_owner(row_info, rows) -> tuple[np.ndarray, np.ndarray]:
    """``(group, owner)`` of the constraint rows ``rows`` (object and int arrays), from a
    :class:`RowTable` without building a dictionary per row (or from any sequence of row
    dicts)."""
    rows = np.asarray(rows, np.int64).ravel()
    if isinstance(row_info, RowTable):
        return (np.asarray(row_info._codes["group"] + ("",), object)[row_info._group[rows]],
                row_info._owner[rows].astype(np.int64))
    ris = [row_info[int(r)] for r in rows]
    return (np.array([ri["group"] for ri in ris], object),
            np.array([ri["owner"] for ri in ris], np.int64))
