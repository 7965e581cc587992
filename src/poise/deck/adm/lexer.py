"""Adams dataset text -> statements (name, id, keyword values), every problem located.

Lines: the first line of a dataset is its title; ``!`` starts a comment (``!MS#`` lines are
MotionSolve's extensions: their text continues the statement before them); a line starting with
``,`` continues the statement above; any other line starts a statement ``NAME/id, KEY=value,
FLAG, ...``. Comment lines before a statement are kept with it (``adams_view_name='x'`` names
it). Keywords are scanned per the statement's vocabulary (:mod:`poise.deck.adm.vocab`): numbers
separated by commas, expressions running to ``\\`` or to the end of the statement across
continuation lines (a continuation line that starts with a keyword ends it), strings to the next
comma. Numbers take Fortran and C notation; a ``D`` suffix means degrees (converted to radians).
"""
from __future__ import annotations

import bisect
import math
import re
from dataclasses import dataclass, field

from poise.deck.adm.vocab import STATEMENTS, StatementDef

CONT = "\x1e"            # a continuation-line boundary inside a statement's joined text
_NUM = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eEdD][+-]?\d+)?(D)?$", re.IGNORECASE)
_WORD = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_VIEW_NAME = re.compile(r"adams_view_name\s*=\s*'([^']*)'", re.IGNORECASE)
_HEAD = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)\s*(/?)")
_SEP_OR_PAREN = re.compile("[,(\x1e]")


@dataclass
class Value:
    """A keyword as written: its canonical name, value(s) and where it starts."""

    name: str
    kind: str
    value: object                    # None (flag), int, float, str, list[int|float]
    line: int
    text: str = ""                   # the value as written (numbers: their spellings)
    degrees: tuple = ()              # per number: written with a D suffix


@dataclass
class Statement:
    """One statement: ``NAME/id, ...`` with its keywords, comments and location."""

    name: str                        # canonical statement name
    id: int | None
    line: int
    file: str
    values: dict = field(default_factory=dict)      # canonical keyword -> Value
    comments: list = field(default_factory=list)    # comment lines before (and on) it
    label: str | None = None         # adams_view_name, or LABEL=
    defn: StatementDef | None = None
    written: str = ""                # the name as written

    @property
    def who(self) -> str:
        """``JOINT/3``; a statement without an id by its first option (``SIMULATE/STATIC``)."""
        if self.id is not None:
            return f"{self.name}/{self.id}"
        flag = next((v.name for v in self.values.values() if v.kind == "flag"), "")
        return f"{self.name}/{flag}"

    def get(self, key, default=None):
        v = self.values.get(key)
        return default if v is None else v.value

    def has(self, key) -> bool:
        return key in self.values


@dataclass
class Chunk:
    """The raw text of one statement: its lines joined with :data:`CONT` between them."""

    head: str
    rest: str
    line: int
    lines: list                      # (offset in ``rest``, line number) of each piece
    comments: list
    label: str | None


def _commented_statement(comment: str) -> bool:
    """``!MOTION/3`` and the like: a statement commented out (Adams View keeps them)."""
    m = _HEAD.match(comment)
    return bool(m and m.group(2) and m.group(1).upper() in STATEMENTS)


def split_lines(text: str, title: bool) -> tuple[str, list[Chunk], list[tuple[int, str]]]:
    """(title, statement chunks, located problems) of a dataset's text."""
    lines = text.split("\n")
    head_title = ""
    start = 0
    if title and lines:
        head_title = lines[0].strip()
        start = 1
    chunks: list[Chunk] = []
    problems: list[tuple[int, str]] = []
    pending: list[str] = []
    label = None
    named = ""                       # the comment line that gave ``label``
    amp = False                      # the line before ended with '&': this one continues it
    cur: list | None = None          # [head, pieces, line, comments, label]

    def close():
        nonlocal cur
        if cur is not None:
            rest, offs = "", []
            for k, (t, ln) in enumerate(cur[1]):
                if k:
                    rest += CONT
                offs.append((len(rest), ln))
                rest += t
            chunks.append(Chunk(cur[0], rest, cur[2], offs, cur[3], cur[4]))
            cur = None

    for k in range(start, len(lines)):
        ln = k + 1
        body, bang, comment = lines[k].rstrip("\r").partition("!")
        stripped = body.strip()
        if bang and comment[:3].upper() == "MS#":       # MotionSolve extension: continues
            ext = comment[3:].strip()                   # the statement above
            if cur is not None and ext:
                cur[1].append((ext[1:] if ext.startswith(",") else ext, ln))
            continue
        if not stripped:
            if bang:
                m = _VIEW_NAME.search(comment)
                if m:
                    label, named = m.group(1), comment.strip()
                elif comment.strip():
                    if label is not None and _commented_statement(comment):
                        pending.append(named)   # the name was the commented-out statement's
                        label = None
                    pending.append(comment.strip())
            continue
        joined, amp = amp, stripped.endswith("&")
        if amp:                             # Adams command language: '&' ends a line that
            stripped = stripped[:-1].rstrip()       # the next one continues
            if stripped.endswith(","):
                stripped = stripped[:-1].rstrip()
            if not stripped:
                continue
        if stripped.startswith(",") or (joined and cur is not None):
            if cur is None:
                problems.append((ln, "a continuation line (starting with ',') with no "
                                     "statement before it"))
                continue
            cur[1].append((stripped[1:] if stripped.startswith(",") else stripped, ln))
        else:
            close()
            m = _HEAD.match(stripped)
            cur = [stripped[:m.end()] if m else stripped, [(stripped[m.end():] if m else "", ln)],
                   ln, pending, label]
            pending, label = [], None
        if bang and comment.strip():                    # a comment after the statement's text
            m = _VIEW_NAME.search(comment)
            if m:
                cur[4] = m.group(1)
            else:
                cur[3].append(comment.strip())
    close()
    return head_title, chunks, problems


def number(tok: str) -> tuple[float | None, bool]:
    """(value, written in degrees) of a number token, (None, False) when it is not one."""
    t = tok.strip()
    m = _NUM.match(t)
    if not m:
        return None, False
    deg = m.group(1) is not None
    core = t[:-1] if deg else t
    try:
        v = float(core.replace("d", "e").replace("D", "e"))
    except ValueError:
        return None, False
    if deg:
        v = radians(v)
    return v, deg


def radians(deg: float) -> float:
    """Degrees -> radians."""
    return math.radians(deg)


class Scanner:
    """Scans one statement chunk's arguments with the statement's vocabulary."""

    def __init__(self, chunk: Chunk, defn: StatementDef, file: str):
        self.c, self.d, self.file = chunk, defn, file
        self.s = chunk.rest
        self.problems: list[tuple[int, str]] = []

    def line_at(self, pos: int) -> int:
        offs = self.c.lines
        if len(offs) == 1:
            return offs[0][1]
        k = bisect.bisect_right([o for o, _ in offs], pos) - 1
        return offs[max(k, 0)][1]

    def err(self, pos: int, msg: str) -> None:
        self.problems.append((self.line_at(pos), msg))

    # ------------------------------------------------------------------ helpers
    def _skip_ws(self, i: int) -> int:
        s = self.s
        while i < len(s) and s[i] in " \t":
            i += 1
        return i

    def _at_keyword(self, i: int) -> bool:
        """Whether the text at ``i`` starts a keyword of the statement (``WORD=`` or a flag)."""
        i = self._skip_ws(i)
        m = _WORD.match(self.s, i)
        if not m:
            return False
        j = self._skip_ws(m.end())
        valued = j < len(self.s) and self.s[j] == "="
        name, _ = self.d.resolve(m.group(0), valued)
        if name is not None:
            return True
        return valued and (j + 1 >= len(self.s) or self.s[j + 1] != "=")

    def scan(self) -> tuple[int | None, dict, str | None]:
        """(id, keyword values, LABEL) of the chunk."""
        s, i, vals = self.s, 0, {}
        ident = None
        i = self._skip_ws(i)
        # the id: digits right after the slash
        m = re.compile(r"[+-]?\d+").match(s, i)
        if m and (m.end() == len(s) or s[self._skip_ws(m.end())] in "," + CONT):
            ident = int(m.group(0))
            i = self._skip_ws(m.end())
            if i < len(s):
                i += 1
        while True:
            i = self._skip_ws(i)
            if i >= len(s):
                break
            if s[i] in "," + CONT + "\\":     # a backslash ends an expression
                i += 1
                continue
            m = _WORD.match(s, i)
            if not m:
                j = self._next_sep(i)
                self.err(i, f"unexpected {s[i:j].strip()!r}; expected KEYWORD=value or an "
                            "option")
                i = j
                continue
            word = m.group(0)
            j = self._skip_ws(m.end())
            valued = j < len(s) and s[j] == "="
            name, msg = self.d.resolve(word, valued)
            if name is None:
                self.err(i, msg)
                i = self._skip_value(j + 1) if valued else self._next_sep(m.end())
                continue
            if name in vals:
                self.err(i, f"{name} given twice")
            kw = (self.d.keywords if valued else self.d.flags)[name]
            line = self.line_at(i)
            if not valued:
                vals[name] = Value(name, "flag", None, line)
                i = m.end()
                k = self._skip_ws(i)
                if k < len(s) and s[k] not in "," + CONT:
                    self.err(k, f"unexpected {s[k:self._next_sep(k)].strip()!r} after {name}")
                    i = self._next_sep(k)
                continue
            i, v = self._value(kw, j + 1, line)
            if v is not None:
                vals[name] = v
        label = None
        if "LABEL" in vals:
            label = str(vals.pop("LABEL").value)
        return ident, vals, label

    def _next_sep(self, i: int) -> int:
        s = self.s
        m = _SEP_OR_PAREN.search(s, i)
        if m is None:
            return len(s)
        if m.group(0) != "(":
            return m.start()
        depth = 0
        while i < len(s):
            ch = s[i]
            if ch == "(":
                depth += 1
            elif ch == ")":
                depth -= 1
            elif depth <= 0 and ch in "," + CONT:
                return i
            i += 1
        return i

    def _skip_value(self, i: int) -> int:
        """Past a value nobody reads (after an unknown keyword): numbers and words up to the
        next keyword."""
        while True:
            j = self._next_sep(i)
            if j >= len(self.s) or self._at_keyword(j + 1):
                return j
            i = j + 1

    # ------------------------------------------------------------------ values
    def _value(self, kw, i: int, line: int):
        k = kw.kind
        while i < len(self.s) and self.s[i] in " \t" + CONT:   # "KEY =" then the next line
            i += 1
        if k == "expr":
            return self._expr(kw, i, line)
        if k == "str":
            j = self._next_sep(i)
            text = self.s[i:j].strip()
            if not text:
                self.err(i, f"{kw.name}= has no value")
                return j, None
            return j, Value(kw.name, k, text, line, text)
        # numbers: one (int, real) or a comma-separated list (ints, reals)
        toks, j = [], i
        while True:
            e = self._next_sep(j)
            tok = self.s[j:e].strip()
            toks.append((tok, j))
            if k in ("int", "real") or e >= len(self.s):
                j = e
                break
            nxt = e + 1
            while nxt < len(self.s) and self.s[nxt] in " \t" + CONT:   # "1, 2,\n, 3"
                nxt += 1
            peek = self.s[nxt:self._next_sep(nxt)].strip()
            if not peek or self._at_keyword(nxt):
                j = e
                break
            j = nxt
        nums, degs = [], []
        for tok, at in toks:
            if not tok:
                self.err(at, f"{kw.name}= has no value")
                return j, None
            v, deg = number(tok)
            if v is None:
                what = "is neither a number nor a keyword" if _WORD.fullmatch(tok) else \
                    "is not a number"
                self.err(at, f"{kw.name}: {tok!r} {what}")
                return j, None
            if k in ("int", "ints"):
                if deg or not abs(v) < 2.0 ** 62 or v != int(v):
                    self.err(at, f"{kw.name}: {tok!r} is not an integer")
                    return j, None
                v = int(v)
            elif not math.isfinite(v):
                self.err(at, f"{kw.name}: {tok!r} is not a finite number")
                return j, None
            nums.append(v)
            degs.append(deg)
        text = ", ".join(t for t, _ in toks)
        val = nums[0] if k in ("int", "real") else nums
        return j, Value(kw.name, k, val, line, text, tuple(degs))

    def _expr(self, kw, i: int, line: int):
        """An expression: to ``\\`` at depth 0 (another expression keyword follows), a comma at
        depth 0, a continuation line starting with a keyword once the expression is complete,
        or the end of the statement; other continuation boundaries are spaces."""
        s, depth, out, j = self.s, 0, [], i
        while j < len(s):
            ch = s[j]
            if ch == "(":
                depth += 1
            elif ch == ")":
                depth -= 1
            elif depth <= 0 and ch == "\\":
                break
            elif depth <= 0 and ch == ",":
                break
            elif ch == CONT:
                done = "".join(out).rstrip()
                if depth <= 0 and done and done[-1] not in "+-*/(,:^" and self._at_keyword(j + 1):
                    break
                out.append(" ")
                j += 1
                continue
            out.append(ch)
            j += 1
        text = " ".join("".join(out).split())
        if not text:
            self.err(i, f"{kw.name}= has no expression")
            return j, None
        return j, Value(kw.name, "expr", text, line, text)
