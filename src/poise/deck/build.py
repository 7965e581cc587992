"""Element building: parse records -> typed :class:`~poise.deck.spec.Element` objects, in batches.

Records of one batch are grouped by *shape* (tag and attribute names as written) and each shape
is analysed once (schema, canonical names, duplicate/unknown attribute warnings, defaults), so
the per-element work of a large deck is a few C-level calls. Unknown elements keep their written
name and unknown attributes are dropped with one warning each, so that validation can report
every problem of the deck at once.
"""
from __future__ import annotations

from typing import Any

from lxml import etree

from poise.deck.schema import element_schema
from poise.deck.schema_types import Attr
from poise.deck.spec import Element
from poise.deck.values import coerce, ints, reals
from poise.core.errors import Problem, SourceLoc


def local_name(tag: Any) -> str:
    return etree.QName(tag).localname if isinstance(tag, str) else ""


_LOCAL: dict[str, str] = {}          # element tag as written -> local name


def local_tag(tag: Any) -> str:
    if not isinstance(tag, str):
        return ""
    v = _LOCAL.get(tag)
    if v is None:
        v = _LOCAL[tag] = local_name(tag)
    return v


_LOWER_LOCAL: dict[str, str] = {}   # attribute / tag name as written -> lower-case local name


def _lower_local(name: str) -> str:
    v = _LOWER_LOCAL.get(name)
    if v is None:
        v = _LOWER_LOCAL[name] = local_name(name).lower()
    return v


_ATTR_CACHE: dict[tuple[str, str], Attr | None] = {}   # (tag, lower-case name) -> Attr


def _schema_attr(sch, n: str) -> Attr | None:
    key = (sch.tag, n)
    try:
        return _ATTR_CACHE[key]
    except KeyError:
        a = _ATTR_CACHE[key] = sch.attr(n)
        return a


# --------------------------------------------------------------------------- element building
# Deck elements are typed in batches (Builder.flush): the records of one batch are grouped by
# *shape* (tag as written + attribute names as written, in order) and each shape is analysed
# once (_Shape: schema, canonical names, duplicate/unknown attribute warnings, defaults), so the
# per-element Python work is a few C-level calls; attribute values are typed column by column
# (plain numbers through one float()/int() map per column).
_SHAPES: dict[tuple, "_Shape"] = {}
_SHAPES_MAX = 4096


class _Shape:
    """What every element with one tag and one list of attribute names (as written) becomes."""

    __slots__ = ("tag", "kind", "names", "cols", "id_src", "warns", "defaults")

    def __init__(self, wtag: Any, keys: tuple):
        sch = element_schema(local_tag(wtag))
        self.tag = sch.tag if sch else local_tag(wtag)
        self.kind = sch.kind if sch else "model"
        raw: dict[str, int] = {}                 # lower-case name -> index of its last value
        for i, k in enumerate(keys):
            raw[_lower_local(k)] = i
        self.id_src = raw.get("id")
        out: dict[str, tuple] = {}               # attribute -> (value index, Attr | tag)
        warns: list[str] = []
        if sch is None:
            for n, i in raw.items():
                out[n] = (i, "id" if n == "id" else "raw")
        else:
            written: dict[str, str] = {}
            for n, i in raw.items():
                a = _schema_attr(sch, n)
                if a is None:
                    if sch.open_attrs:
                        out[n] = (i, "guess")
                    else:
                        warns.append(f"unknown attribute '{n}' ignored")
                    continue
                if a.name in written:
                    warns.append(f"attribute '{a.name}' given twice (as '{written[a.name]}' and "
                                 f"'{n}'); '{n}' is used")
                written[a.name] = n
                out[a.name] = (i, a)
        self.names = tuple(out)
        self.cols = tuple(out.values())
        self.warns = tuple(warns)
        present = set(out)
        self.defaults = tuple((n, d) for n, d in _defaults(self.tag) if n not in present)


def _shape(wtag: Any, keys: tuple) -> _Shape:
    k = (wtag, keys)
    s = _SHAPES.get(k)
    if s is None:
        if len(_SHAPES) >= _SHAPES_MAX:
            _SHAPES.clear()
        s = _SHAPES[k] = _Shape(wtag, keys)
    return s


class Builder:
    """Builds :class:`Element` objects from parse records, in batches, and collects warnings.

    A record is ``[tag as written, attributes (dict), text, line, section, event]``; ``event``
    orders the warnings as the document does (a nested-element warning at the nested element's
    start, the element's own warnings at its end).
    """

    def __init__(self, path: str):
        self.path = path
        self.items: list[tuple] = []       # (Element, section, _Shape) in document order
        self.warnings: list[tuple] = []    # (event, Problem)

    def flush(self, recs: list) -> None:
        if not recs:
            return
        groups: dict[tuple, list[int]] = {}
        for k, r in enumerate(recs):
            key = (r[0], tuple(r[1]))
            g = groups.get(key)
            if g is None:
                groups[key] = [k]
            else:
                g.append(k)
        built: list = [None] * len(recs)
        for (wtag, keys), idx in groups.items():
            shp = _shape(wtag, keys)
            rs = [recs[k] for k in idx]
            raw = list(zip(*[r[1].values() for r in rs]))    # one tuple per attribute
            if shp.id_src is not None:
                idents = ints(list(raw[shp.id_src]), keep_raw=False)
            else:
                idents = [None] * len(rs)
            path, tag = self.path, shp.tag
            locs = [SourceLoc(path, r[3], tag, ident) for r, ident in zip(rs, idents)]
            cols = [self._column(shp, name, src, conv, list(raw[src]), locs, idents)
                    for name, (src, conv) in zip(shp.names, shp.cols)]
            names = shp.names
            rows = zip(*cols) if cols else ((),) * len(rs)
            texts = [r[2] for r in rs]
            if any(texts):
                texts = [t.strip() if t and t.strip() else None for t in texts]
            else:
                texts = [None] * len(rs)
            els = [Element(tag, dict(zip(names, row)), loc, txt)
                   for row, loc, txt in zip(rows, locs, texts)]
            for k, el, r in zip(idx, els, rs):
                built[k] = (el, r[4], shp)
            if shp.warns:
                for r, loc in zip(rs, locs):
                    for msg in shp.warns:
                        self.warnings.append((r[5], Problem(loc, msg)))
        self.items.extend(built)

    @staticmethod
    def _column(shp: _Shape, name: str, src: int, conv: Any, col: list, locs: list,
                idents: list) -> list:
        if conv == "raw":
            return col
        if conv == "id":                   # unknown element: the id typed when it is one
            return [v if x is None else x for v, x in zip(col, idents)]
        if conv == "guess":
            return reals(col)
        k = conv.kind
        if k == "real":
            return reals(col)
        if k == "int":
            return ints(col)
        if k == "str":
            return col
        if k in ("bool", "enum", "int_list", "real_list"):   # no location: one per value
            memo = {v: coerce(conv, v, None) for v in set(col)}
            return [memo[v] for v in col]
        if k == "real_or_expr":
            x = reals(col)
            if all(type(v) is float for v in x):
                return x
        return [coerce(conv, v, loc) for v, loc in zip(col, locs)]


_DEFAULTS: dict[str, tuple] = {}   # canonical tag -> ((name, default), ...) in schema order


def _defaults(tag: str) -> tuple:
    d = _DEFAULTS.get(tag)
    if d is None:
        sch = element_schema(tag)
        d = _DEFAULTS[tag] = () if sch is None else tuple(
            (a.name, a.default) for a in sch.attrs.values() if a.default is not None)
    return d


def place(spec, items, seen_model: bool = True) -> None:
    """Put built elements into ``spec``: commands (a command-only element, or one from the
    command section) in ``spec.commands``, the others, with their defaults, in ``spec.model``.
    ``items`` are :attr:`Builder.items`; ``seen_model``: the document had a model section
    (elements directly under the root that may be both are then commands)."""
    model, commands = spec.model, spec.commands
    for el, where, shp in items:
        kind = shp.kind
        if kind == "command" or where == "command" or (where == "root" and seen_model
                                                       and kind == "both"):
            el.is_command = True
            commands.append(el)
        else:
            if shp.defaults:
                el.attrs.update(shp.defaults)
            model.append(el)
