"""The vocabulary of the deck schema: :class:`Attr`, :class:`ElementSchema`, the value kinds and
reference namespaces, and the short constructors (``R``, ``B``, ``E``, ``M``, ``xyz``, ...) the
table in :mod:`poise.deck.schema` is written with. Kept apart so that the table module reads as
data.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


KINDS = ("real", "int", "bool", "enum", "str", "real_or_expr", "expr", "int_list", "real_list")

#: reference namespace -> element tags whose ids it contains
NAMESPACES: dict[str, tuple[str, ...]] = {
    "marker": ("Reference_Marker",),
    "body": ("Body_Rigid", "Body_Point", "Body_Flexible"),
    "joint": ("Constraint_Joint",),
    "array": ("Reference_Array",),
    "variable": ("Reference_Variable",),
    "spline": ("Reference_Spline",),
    "graphic": ("Post_Graphic",),
    "curve": ("Reference_ParamCurve",),
    "surface": ("Reference_ParamSurface",),
    "matrix": ("Reference_Matrix",),
}


@dataclass(frozen=True)
class Attr:
    """One attribute of an element.

    Attributes
    ----------
    name : str
        Lower-case canonical name.
    kind : str
        One of :data:`KINDS`.
    doc : str
        One line of documentation.
    required : bool
        Must be present on a model element (command elements only need ``id``).
    default : Any
        Value filled in for model elements when absent (None: no default).
    choices : tuple of str
        Allowed upper-case values of an ``enum``.
    lo, hi : float or None
        Inclusive bounds; ``lo_open``/``hi_open`` make them exclusive.
    ref : str or None
        Reference namespace (key of :data:`NAMESPACES`) for id references.
    zero_ok : bool
        Id ``0`` (global frame) is a valid reference.
    aliases : tuple of str
        Other spellings of the attribute name (stored under ``name``).
    """

    name: str
    kind: str
    doc: str = ""
    required: bool = False
    default: Any = None
    choices: tuple = ()
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    ref: str | None = None
    zero_ok: bool = False
    aliases: tuple = ()

    def bounds_text(self) -> str:
        """Human-readable bounds, e.g. ``'>= 0'`` or ``'> 0'`` (empty when unbounded)."""
        parts = []
        if self.lo is not None:
            parts.append(f"{'>' if self.lo_open else '>='} {self.lo:g}")
        if self.hi is not None:
            parts.append(f"{'<' if self.hi_open else '<='} {self.hi:g}")
        return " and ".join(parts)


@dataclass(frozen=True)
class ElementSchema:
    """One element type.

    Attributes
    ----------
    tag : str
        Canonical spelling.
    kind : str
        ``model``, ``command`` or ``both``.
    supported : bool
        False: known, parsed, but rejected with "is not supported yet".
    attrs : dict[str, Attr]
        Attributes by canonical lower-case name.
    doc : str
    open_attrs : bool
        Unknown attributes are kept as data (number -> float, else str) without warning.
    aliases : tuple of str
        Other spellings of the tag.
    """

    tag: str
    kind: str
    supported: bool
    attrs: dict
    doc: str = ""
    open_attrs: bool = False
    aliases: tuple = ()
    alias_map: dict = field(default_factory=dict, compare=False, repr=False)

    def attr(self, name: str) -> Attr | None:
        """Attribute by (case-insensitive) name or alias."""
        n = name.lower()
        return self.attrs.get(n) or self.attrs.get(self.alias_map.get(n, ""))

    def defaults(self) -> dict[str, Any]:
        """Non-None defaults of all attributes."""
        return {a.name: a.default for a in self.attrs.values() if a.default is not None}


# --------------------------------------------------------------------------- table helpers
def A(name, kind, doc="", **kw) -> Attr:
    return Attr(name, kind, doc, **kw)


def R(name, doc="", default=None, **kw) -> Attr:
    return Attr(name, "real", doc, default=default, **kw)


def B(name, doc="", default=False, **kw) -> Attr:
    return Attr(name, "bool", doc, default=default, **kw)


def E(name, choices, doc="", **kw) -> Attr:
    return Attr(name, "enum", doc, choices=tuple(choices.split()), **kw)


def M(name, doc="", **kw) -> Attr:
    kw.setdefault("lo", 0)
    return Attr(name, "int", doc, ref="marker", **kw)


def ID() -> Attr:
    return Attr("id", "int", "identifier, unique within the element type", required=True, lo=1)


def LABEL() -> Attr:
    return Attr("label", "str", "free-text name")


def USR() -> list[Attr]:
    # Python user routines (poise/user_routines.py) serve Constraint_UserConstr,
    # Force_Scalar_TwoBody, Force_Vector_* and Reference_Variable; elsewhere they are rejected
    return [A("usrsub_dll_name", "str", "user-subroutine library (DLLs are not supported)"),
            A("usrsub_fnc_name", "str", "user function name (Python routines; see DESIGN section 12)"),
            A("usrsub_param_string", "str", "user-routine parameters, USER(p1, p2, ...)"),
            A("script_name", "str", "Python user script, relative to the deck's directory"),
            A("interpreter", "str", "script interpreter; only PYTHON is supported")]


def xyz(prefix, suffix, doc, kind="real", **kw) -> list[Attr]:
    return [Attr(f"{prefix}{c}{suffix}", kind, f"{doc} ({c})", **kw) for c in ("x", "y", "z")]


def SIX(fmt, doc, kind="real", **kw) -> list[Attr]:
    return [Attr(fmt.format(c), kind, f"{doc} ({c})", **kw) for c in ("x", "y", "z", "tx", "ty", "tz")]
