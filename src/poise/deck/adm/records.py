"""What a translated Adams dataset is made of: XML element records and the translation context.

A :class:`Rec` is one MotionSolve XML element as text attributes (exactly what ``poise convert``
writes and what the XML builder types), with the statement it came from. The :class:`Ctx`
collects records, located problems and warnings, the frames of parts and markers, the
statements by name and id, and what was skipped or ignored.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from poise.core.errors import Problem, SourceLoc
from poise.deck.schema import element_schema

_USER = re.compile(r"\s*USER\s*\(", re.IGNORECASE)


def takes_label(tag: str) -> bool:
    """Whether the XML element has a ``label`` attribute (Force_Gravity, Param_* have none)."""
    hit = _LABELLED.get(tag)
    if hit is None:
        sch = element_schema(tag)
        hit = _LABELLED[tag] = sch is not None and "label" in sch.attrs
    return hit


_LABELLED: dict[str, bool] = {}


def num(x) -> str:
    """A number as attribute text: the shortest spelling that reads back to the same float."""
    if isinstance(x, (int, np.integer)) and not isinstance(x, bool):
        return str(int(x))
    return repr(float(x))


@dataclass
class Rec:
    """One XML element made from a statement (or command)."""

    tag: str
    attrs: dict
    file: str
    line: int
    who: str
    section: str = "model"           # model | command
    text: str | None = None
    comments: list = field(default_factory=list)
    removed: bool = False            # deactivated by the command file before any analysis


@dataclass
class Frame:
    """A part's (or point mass's) reference frame and what it is."""

    id: int
    origin: np.ndarray
    axes: np.ndarray
    ground: bool = False
    point: bool = False
    who: str = ""


@dataclass
class MarkerInfo:
    id: int
    part: int
    origin: np.ndarray
    axes: np.ndarray
    floating: bool
    who: str


class Ctx:
    """Translation state of one dataset (and its command file)."""

    def __init__(self, file: str, ignore=()):
        self.file = file
        self.ignore = {k.upper() for k in ignore}
        self.recs: list[Rec] = []
        self.problems: list[Problem] = []
        self.warnings: list[Problem] = []
        self.parts: dict[int, Frame] = {}
        self.markers: dict[int, MarkerInfo] = {}
        self.stmts: dict[str, dict] = {}          # name -> {id: Statement}
        self.skipped: dict[str, list] = {}        # name -> statements skipped
        self.ignored_kw: dict[tuple, list] = {}   # (statement, keyword) -> statements
        self.ignored: list[dict] = []             # elements left out by --ignore
        self.refused: dict[tuple, Problem] = {}   # (statement, id) -> its problem
        self.by_stmt: dict[int, list] = {}        # id(Statement) -> its records
        self.next_marker = 0
        self.title = ""
        self.trailing: list[str] = []             # comments after the last element
        self.statements: list = []

    # ------------------------------------------------------------------ locations
    @staticmethod
    def loc(stmt, tag: str = "") -> SourceLoc:
        return SourceLoc(stmt.file, stmt.line, tag, stmt.id, stmt.who)

    def error(self, stmt, msg: str, line: int | None = None) -> None:
        loc = self.loc(stmt)
        if line is not None:
            loc = SourceLoc(loc.file, line, loc.tag, loc.id, loc.who)
        self.problems.append(Problem(loc, msg))

    def warn(self, stmt, msg: str) -> None:
        self.warnings.append(Problem(self.loc(stmt), msg))

    # ------------------------------------------------------------------ records
    def add(self, stmt, tag: str, attrs: dict, text: str | None = None,
            section: str = "model", first: bool = True) -> Rec:
        a = {"id": num(stmt.id)} if stmt.id is not None and "id" not in attrs else {}
        comments = list(stmt.comments) if first else []
        if stmt.label is not None and "label" not in attrs:
            if takes_label(tag):
                a["label"] = stmt.label
            elif first:                 # kept where the XML has room for it: a comment
                comments.append(f"label '{stmt.label}'")
        a.update({k: (v if isinstance(v, str) else num(v)) for k, v in attrs.items()
                  if v is not None})
        r = Rec(tag, a, stmt.file, stmt.line, stmt.who, section, text, comments)
        self.recs.append(r)
        self.by_stmt.setdefault(id(stmt), []).append(r)
        return r

    # ------------------------------------------------------------------ references
    def marker(self, stmt, key: str, required: bool = True, floating_ok: bool = False):
        """The MarkerInfo a keyword names (None, with a located problem when it is wrong)."""
        mid = stmt.get(key)
        if mid is None:
            if required:
                self.error(stmt, f"{key}= is missing; expected the id of a MARKER")
            return None
        m = self.markers.get(mid)
        if m is None:
            self.error(stmt, f"{key}={mid}: no MARKER/{mid} in the dataset", stmt.values[key].line)
            return None
        if m.floating and not floating_ok:
            self.error(stmt, f"{key}={mid}: MARKER/{mid} is FLOATING; expected a fixed marker",
                       stmt.values[key].line)
            return None
        return m

    def ref(self, stmt, key: str, name: str, required: bool = True):
        """The Statement ``name/<value of key>`` (None, located, when missing)."""
        i = stmt.get(key)
        if i is None:
            if required:
                self.error(stmt, f"{key}= is missing; expected the id of a {name}")
            return None
        s = self.stmts.get(name, {}).get(i)
        if s is None:
            self.error(stmt, f"{key}={i}: no {name}/{i} in the dataset", stmt.values[key].line)
        return s

    def need(self, stmt, *keys) -> bool:
        missing = [k for k in keys if not stmt.has(k)]
        if missing:
            self.error(stmt, ", ".join(f"{k}=" for k in missing) + " missing")
        return not missing

    def count(self, stmt, key: str, n, default=None):
        """A list keyword with ``n`` values (an int or a tuple of allowed counts)."""
        v = stmt.get(key)
        if v is None:
            return default
        ok = (n,) if isinstance(n, int) else n
        if len(v) not in ok:
            want = " or ".join(str(k) for k in ok)
            self.error(stmt, f"{key} has {len(v)} values; expected {want}", stmt.values[key].line)
            return None
        return v

    def one_of(self, stmt, names, what: str, default=None):
        """The one flag of ``names`` the statement gives (its default when none)."""
        given = [n for n in names if stmt.has(n)]
        if len(given) > 1:
            self.error(stmt, f"{' and '.join(given)} both given; expected one {what}")
            return None
        if not given:
            if default is None:
                self.error(stmt, f"no {what} given; expected one of " + ", ".join(names))
            return default
        return given[0]

    def user(self, stmt, key: str = "FUNCTION") -> bool:
        """Whether the statement is given by a user subroutine (FUNCTION=USER(...) or ROUTINE=);
        a located problem (or, with --ignore USER, a recorded omission)."""
        f = stmt.get(key)
        if not ((isinstance(f, str) and _USER.match(f)) or stmt.has("ROUTINE")):
            return False
        self.refuse(stmt, "USER", "a Fortran/C user subroutine "
                    f"({key}=USER(...){', ROUTINE=' if stmt.has('ROUTINE') else ''})")
        return True

    def refuse(self, stmt, kind: str, what: str) -> None:
        """Physics poise does not have: a located problem, or recorded when ``--ignore KIND``."""
        if kind in self.ignore:
            self.ignored.append({"kind": kind, "statement": stmt.who, "file": stmt.file,
                                 "line": stmt.line})
            self.warn(stmt, f"left out (--ignore {kind}): {what}")
            return
        self.refused[(stmt.name, stmt.id)] = Problem(
            self.loc(stmt), f"poise does not support {what}; `--ignore {kind}` solves "
                            "without it (recorded in the results)")

    def all_problems(self) -> list[Problem]:
        """Every located problem, in file and line order."""
        out = [*self.problems, *self.refused.values()]
        return sorted(out, key=lambda p: (p.loc.file != self.file, p.loc.line))

    def new_marker_id(self) -> int:
        self.next_marker += 1
        return self.next_marker
