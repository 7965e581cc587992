"""Deck validation: one pass over a :class:`~poise.deck.spec.DeckSpec`, every problem collected.

Messages read ``FILE:LINE: <Tag id=N>: problem; expected ..., got ...``. Problems that belong to
the whole file rather than one element (malformed XML, no ground body) read ``FILE:LINE: problem``.
Warnings (moving body without mass, unknown attributes from the parser, ...) go to
``DeckSpec.warnings``; errors are raised together as one :class:`~poise.core.errors.DeckError`.
This module holds the driver and the id references; the screen and the checks are
:mod:`poise.deck.screen` and :mod:`poise.deck.checks`.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

from poise.deck.checks import (DCM_CHECK, EIG, check_body, check_element, check_expression_syntax,
                               check_marker, check_specific, ns_text, ref_attrs)
from poise.deck.schema import NO_EFFECT, namespace_of
from poise.deck.schema_types import NAMESPACES
from poise.deck.screen import Screen, schema_of
from poise.deck.spec import DeckSpec, Element, Expr
from poise.core.errors import Problem, ProblemCollector, SourceLoc, one_line


@dataclass(frozen=True)
class FileProblem(Problem):
    """A problem of the whole file: ``FILE:LINE: message`` (no element prefix)."""

    def __str__(self) -> str:
        return one_line(f"{self.loc.file}:{self.loc.line}: {self.message}")


_SPECIFIC = frozenset({"Constraint_Joint", "Constraint_Jprim", "Force_SpringDamper",
                       "Force_Scalar_TwoBody", "Simulate", "Reference_Matrix"})
_ns = functools.cache(namespace_of)


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
    scr = Screen(els)
    good: list[Element] = []
    gidx: list[int] = []
    ignored: dict[str, list[Element]] = {}
    for k, el in enumerate(els):
        sch = schema_of(el.tag)
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
            check_element(pc, el, sch)
        if sch.tag in NO_EFFECT:
            ignored.setdefault(sch.tag, []).append(el)
        good.append(el)
        gidx.append(k)
    _warn_no_effect(pc, ignored)

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
        sch = schema_of(el.tag)
        refs = ref_attrs(sch) if not refs_ok[k] else None
        for name, v in (el.attrs.items() if refs else ()):
            a = refs.get(name)
            if a is None or not isinstance(v, int) or isinstance(v, bool):
                continue
            if v == 0 and a.zero_ok:
                continue
            if v not in ids[a.ref] and not (a.lo is not None and v < a.lo):
                pc.error(el.loc, f"attribute '{name}' refers to a missing {ns_text(a.ref)}; "
                                 f"expected an existing {a.ref} id, got {v}")
        if el.is_command and "id" in sch.attrs and isinstance(el.id, int) and el.tag != "Reference_Array":
            if el.id not in per_tag.get(el.tag, {}):
                pc.error(el.loc, f"command modifies a missing <{el.tag}>; expected the id of a model "
                                 f"<{el.tag}>, got {el.id}")
        if el.tag in _SPECIFIC:
            check_specific(pc, el, markers)
        if el.is_command:
            continue
        if el.tag in ("Body_Rigid", "Body_Point"):
            check_body(pc, el, markers)
        elif el.tag == "Reference_Marker":
            if not scr.marker[k]:
                check_marker(pc, el)
            if bt_bad[k]:
                bt = el.get("body_type")
                body = ids["body"].get(el.get("body_id"))
                want = "POINTBODY" if body.tag == "Body_Point" else "RIGIDBODY"
                pc.warn(el.loc, f"body_type {bt} does not match <{body.tag}> {body.id}; using {want}")

    check_expression_syntax(pc, [el for k, el in zip(gidx, good) if scr.expr[k]])

    DCM_CHECK.clear()
    EIG.clear()
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


def _warn_no_effect(pc: ProblemCollector, ignored: dict) -> None:
    """One warning per kind of element without effect on statics, at its first element, with
    the count and lines."""
    for tag, els in ignored.items():
        n = len(els)
        lines = ", ".join(str(e.loc.line) for e in els[:8]) + (", ..." if n > 8 else "")
        pc.warn(els[0].loc, f"{NO_EFFECT[tag][1]}: no effect on statics; {n} <{tag}> "
                f"element{'s' if n > 1 else ''} ignored (line{'s' if n > 1 else ''} {lines})")


__all__ = ["validate", "FileProblem", "Expr"]
