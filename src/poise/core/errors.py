"""Error types and source locations.

Every problem found in a deck is reported as ``FILE:LINE: <Tag id=N>: message``. Errors in a deck
are collected (not raised one by one) and raised together as one :class:`DeckError`; the CLI maps
it to exit code 3.
"""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True, slots=True)       # one per deck element: no __dict__
class SourceLoc:
    """Where an object came from in a deck.

    Attributes
    ----------
    file : str
        Deck path as given by the user.
    line : int
        1-based line of the ``<`` that opens the element's start tag (0 if unknown), in any
        encoding (``poise.deck.parser``).
    tag : str
        Canonical element name (e.g. ``"Force_SpringDamper"``).
    id : int or None
        The element's ``id`` attribute when present.
    who : str or None
        How the source names the element when it is not an XML tag (an Adams dataset
        statement: ``"JOINT/3"``); the prefix then reads ``FILE:LINE: JOINT/3:``.
    """

    file: str = "<deck>"
    line: int = 0
    tag: str = ""
    id: int | None = None
    who: str | None = None

    def prefix(self, attr: str | None = None) -> str:
        """``FILE:LINE: <Tag id=N>:`` (plus ``attr`` when given)."""
        if self.who is not None:
            who = self.who
        else:
            who = f"<{self.tag} id={self.id}>" if self.id is not None else f"<{self.tag}>"
        s = f"{self.file}:{self.line}: {who}"
        if attr:
            s += f" {attr}"
        return s + ":"


_CONTROL = {c: f"\\x{c:02x}" for c in [*range(0x20), 0x7f]}
_CONTROL.update({ord("\n"): "\\n", ord("\r"): "\\r", ord("\t"): "\\t"})


def one_line(text: str) -> str:
    """``text`` with newlines and other control characters escaped (``\\n``, ``\\x00``): a
    problem is one line that starts with ``FILE:LINE:``, whatever values it echoes."""
    return str(text).translate(_CONTROL)


@dataclass(frozen=True)
class Problem:
    """One located problem in a deck."""

    loc: SourceLoc
    message: str
    attr: str | None = None

    def __str__(self) -> str:
        return one_line(f"{self.loc.prefix(self.attr)} {self.message}")


class PoiseError(Exception):
    """Base class of all poise errors."""

    exit_code = 4


class DeckError(PoiseError):
    """Invalid deck: one or more located problems (exit code 3)."""

    exit_code = 3

    def __init__(self, problems: list[Problem] | Problem | str):
        if isinstance(problems, (Problem, str)):
            problems = [problems]
        self.problems: list = list(problems)
        super().__init__("\n".join(str(p) for p in self.problems))


class ModelError(DeckError):
    """A deck that parses but describes an ill-posed model (e.g. zero mass in a free direction).

    Exit code 3 like any other invalid deck; the message names the element and its line.
    """


class EvaluationError(PoiseError):
    """An element produced NaN/Inf or an expression failed to evaluate (division by zero, ...).

    Raised inside a solve; the solver driver turns it into a failed status with this message.
    """

    exit_code = 1

    def __init__(self, message: str, loc: SourceLoc | None = None, attr: str | None = None):
        self.loc = loc
        self.attr = attr
        self.detail = message              # without the location prefix
        text = f"{loc.prefix(attr)} {message}" if loc is not None else message
        super().__init__(text)


class UsageError(PoiseError):
    exit_code = 2


class MissingFileError(UsageError, FileNotFoundError):
    """An input file that does not exist: a ``FileNotFoundError`` for library callers, a usage
    error (exit code 2) for the command line."""


def require_file(path, what: str = "file") -> None:
    """Raise :class:`MissingFileError` unless ``path`` exists."""
    import errno
    import os
    if not os.path.exists(path):
        raise MissingFileError(errno.ENOENT, f"no such {what}", os.fspath(path))


class UnknownOptionError(UsageError, TypeError):
    """An unknown keyword / override name given to a public API function (exit code 2).

    Also a ``TypeError``, as Python raises for an unexpected keyword argument; the message
    lists the valid names and suggests the closest one.
    """


@dataclass
class ProblemCollector:
    """Collects problems during a validation pass and raises them together."""

    problems: list = field(default_factory=list)
    warnings: list = field(default_factory=list)

    def error(self, loc: SourceLoc, message: str, attr: str | None = None) -> None:
        self.problems.append(Problem(loc, message, attr))

    def warn(self, loc: SourceLoc, message: str, attr: str | None = None) -> None:
        self.warnings.append(Problem(loc, message, attr))

    def raise_if_any(self, cls: type[DeckError] = DeckError) -> None:
        if self.problems:
            raise cls(self.problems)
