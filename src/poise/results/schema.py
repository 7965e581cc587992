"""The results file layout as data: every dataset and attribute poise may write, declared once.

Each :class:`Item` names a path (``scope/relative/path`` for a dataset, ``scope@name`` for an
attribute; scopes: ``root``, ``model`` (``/model``), ``analysis`` (each ``/analysis_NNN``),
``timings``, ``counts``), its dtype, its shape in symbols (``("F", "B", 3)``), a unit
expression in the symbols ``length force mass time`` (``"force*length"``, ``"1"`` for
dimensionless numbers, ``"rad"``, ``""`` for text, ``"mixed"`` when components differ) and its
meaning. The writer (:mod:`poise.results.hdf5`) refuses any object not declared here and
writes every dataset's ``units`` attribute from its unit expression and the deck's unit names
(:func:`unit_string`). ``docs/results-format.md`` is generated from these declarations and
the prose of ``results_format.md`` next to this module
(``python -m poise.results.schema --markdown docs/results-format.md``; :func:`markdown`).
The declarations themselves are long tables (:mod:`poise.results.schema_items`).
"""
from __future__ import annotations

import functools
import re
from pathlib import Path

import numpy as np

from poise.results import schema_dims as sd
from poise.results.schema_dims import (  # noqa: F401 (the netCDF view, re-exported)
    component_dim,
    component_meaning,
    component_values,
    coordinates,
    dimension_names,
    dims,
    group_coordinates,
    long_name,
)
from poise.results import schema_sweep
from poise.results.schema_items import Item, declared

SCOPES = ("root", "model", "analysis", "timings", "counts", schema_sweep.SCOPE)
DTYPE_KINDS = {"float": "f", "int": "iu", "bool": "b", "str": "OSUT", "json": "OSUT"}


class UndeclaredError(AssertionError):
    """An internal error: the writer was handed an object the schema does not declare (a new
    capability must declare its datasets in :mod:`poise.results.schema_items`)."""


@functools.cache
def items() -> tuple[Item, ...]:
    out = tuple(declared()) + tuple(schema_sweep.declared())
    seen = set()
    for it in out:
        assert it.scope in SCOPES and it.dtype in DTYPE_KINDS, it
        assert (it.scope, it.kind, it.name) not in seen, f"declared twice: {it.path}"
        seen.add((it.scope, it.kind, it.name))
        if it.kind == "dataset":
            dims(it)                   # every axis has a dimension name
    return out


@functools.cache
def _index() -> tuple[dict, list]:
    exact, patterns = {}, []
    for it in items():
        if it.pattern:
            parts = re.split(r"(<[A-Za-z_]+>)", it.name)
            rx = "".join((r"\d{3}" if p == "<NNN>" else r"[A-Za-z0-9_]+") if p.startswith("<")
                         else re.escape(p) for p in parts)
            patterns.append((it.scope, it.kind, re.compile(rx + r"\Z"), it))
        else:
            exact[(it.scope, it.kind, it.name)] = it
    return exact, patterns


@functools.cache
def element_groups() -> tuple[str, ...]:
    """The element groups: every analysis group declared with ``<group>/id`` and
    ``<group>/label`` (``bodies``, ``joints``, ..., ``requests``), in declaration order."""
    return tuple(it.name.split("/")[0] for it in items() if it.scope == "analysis"
                 and it.kind == "dataset" and it.name.endswith("/label")
                 and it.name.count("/") == 1)


def lookup(scope: str, kind: str, name: str) -> Item | None:
    """The declaration of ``name`` (dataset path or attribute name) in ``scope``, or None."""
    exact, patterns = _index()
    it = exact.get((scope, kind, name))
    if it is None:
        for s, k, rx, p in patterns:
            if s == scope and k == kind and rx.match(name):
                return p
    return it


def declared_item(scope: str, kind: str, name: str, where: str) -> Item:
    it = lookup(scope, kind, name)
    if it is None:
        raise UndeclaredError(
            f"{where}: {kind} {name!r} is not declared in the results schema "
            f"(poise.results.schema_items); declare it (dtype, shape, unit, meaning) before "
            f"writing it")
    return it


def check_array(it: Item, arr: np.ndarray, where: str) -> None:
    """dtype kind and rank of ``arr`` against the declaration (cheap: no per-element work)."""
    if arr.dtype.kind not in DTYPE_KINDS[it.dtype] and not (it.dtype == "float" and arr.size == 0):
        raise UndeclaredError(f"{where}: dtype {arr.dtype} does not match the declared "
                              f"{it.dtype} (results schema)")
    if arr.ndim != len(it.shape):
        raise UndeclaredError(f"{where}: shape {arr.shape} does not match the declared "
                              f"{shape_text(it.shape)} (results schema)")
    for n, s in zip(arr.shape, it.shape):
        if isinstance(s, int) and n != s:
            raise UndeclaredError(f"{where}: shape {arr.shape} does not match the declared "
                                  f"{shape_text(it.shape)} (results schema)")


def shape_text(shape) -> str:
    if not shape:
        return "()"
    return "(" + ", ".join(str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"


# ------------------------------------------------------------------------------------ units
_ABBREV = {
    # length
    "MILLIMETER": "mm", "CENTIMETER": "cm", "METER": "m", "KILOMETER": "km", "NANOMETER": "nm",
    "MICROMETER": "µm", "INCH": "in", "FOOT": "ft", "MILE": "mi", "YARD": "yd", "ANGSTROM": "Å",
    "MILLIINCH": "mil", "MILS": "mil", "MICROINCH": "µin",
    # force
    "NEWTON": "N", "KNEWTON": "kN", "KILONEWTON": "kN", "MEGANEWTON": "MN", "CENTINEWTON": "cN",
    "MILLINEWTON": "mN", "MICRONEWTON": "µN", "NANONEWTON": "nN", "POUND_FORCE": "lbf",
    "KPOUND_FORCE": "kip", "OUNCE_FORCE": "ozf", "DYNE": "dyn", "KILOGRAM_FORCE": "kgf",
    "POUNDAL": "pdl",
    # mass
    "KILOGRAM": "kg", "GRAM": "g", "MILLIGRAM": "mg", "MEGAGRAM": "Mg", "TONNE": "t",
    "MICROGRAM": "µg", "NANOGRAM": "ng", "POUND_MASS": "lbm", "SLUG": "slug", "OUNCE_MASS": "oz",
    "KPOUND_MASS": "klbm", "US_TON": "ton", "SLINCH": "slinch",
    # time
    "SECOND": "s", "MILLISECOND": "ms", "MICROSECOND": "µs", "NANOSECOND": "ns", "MINUTE": "min",
    "HOUR": "h", "DAY": "d",
}
_BASE = ("length", "force", "mass", "time")


def unit_symbols(units: str) -> dict:
    """``{"length", "force", "mass", "time", "torque", "energy", "angle"}`` unit names of the
    deck's unit system (the results file's ``units`` attribute, ``force=NEWTON ...``)."""
    return dict(_symbols(str(units or "")))


@functools.lru_cache(maxsize=64)
def _symbols(units: str) -> dict:
    u = dict(p.split("=", 1) for p in str(units or "").split() if "=" in p)
    out = {k: _ABBREV.get(str(u.get(k, "")).upper(), str(u.get(k, "")).lower() or f"{k} unit")
           for k in _BASE}
    out["torque"] = out["energy"] = f"{out['force']}*{out['length']}"
    out["angle"] = "rad"
    return out


@functools.lru_cache(maxsize=1024)
def unit_string(expr: str, units: str) -> str:
    """The unit expression ``expr`` (``"force*length"``, ``"length/force"``, ``"1"``, ...) in
    the deck's unit names: ``"N*mm"``, ``"mm/N"``, ``"1"``."""
    sym = _symbols(str(units or ""))
    return re.sub(r"\b(length|force|mass|time|angle)\b", lambda m: sym[m.group(1)], expr)


#: request type -> (channel names, channel unit expressions), channels 1..8
REQUEST_CHANNELS = {
    "EXPRESSION": (tuple(f"expr{k}" for k in range(1, 9)), ("",) * 8),
    "MARKER_DISPLACEMENT": (("DM", "DX", "DY", "DZ", "", "YAW", "PITCH", "ROLL"),
                            ("length",) * 4 + ("",) + ("rad",) * 3),
    "MARKER_FORCE": (("FM", "FX", "FY", "FZ", "TM", "TX", "TY", "TZ"),
                     ("force",) * 4 + ("force*length",) * 4),
    "ELEMENTAL_FORCE": (("FM", "FX", "FY", "FZ", "TM", "TX", "TY", "TZ"),
                        ("force",) * 4 + ("force*length",) * 4),
    "MARKER_VELOCITY": (("VM", "VX", "VY", "VZ", "WM", "WX", "WY", "WZ"),
                        ("length/time",) * 4 + ("rad/time",) * 4),
    "MARKER_ACCELERATION": (("ACCM", "ACCX", "ACCY", "ACCZ", "WDTM", "WDTX", "WDTY", "WDTZ"),
                            ("length/time^2",) * 4 + ("rad/time^2",) * 4),
}


# -------------------------------------------------------------------------- sweep outputs
@functools.cache
def element_outputs() -> dict[str, tuple[str, ...]]:
    """``{group: (dataset, ...)}``: the numeric per-element datasets of an analysis (shape
    ``(F, n_group, ...)``) a ``poise sweep --output group[id].dataset`` can read."""
    out: dict[str, list[str]] = {}
    for it in items():
        if it.scope != "analysis" or it.kind != "dataset" or it.dtype not in ("float", "int"):
            continue
        g, _, ds = it.name.partition("/")
        if g in element_groups() and len(it.shape) >= 2 and it.shape[0] == "F" and "/" not in ds:
            out.setdefault(g, []).append(ds)
    return {g: tuple(v) for g, v in out.items()}


# ---------------------------------------------------------------------------- conformance
def _scope_of(top: str) -> str | None:
    if top == "model":
        return "model"
    if re.fullmatch(r"analysis_\d{3}", top):
        return "analysis"
    return None


def _text(v) -> str | None:
    return v.decode() if isinstance(v, bytes) else None if v is None else str(v)


def conformance(path) -> list[str]:
    """Problems of the results file ``path`` against the schema (empty: it conforms): every
    object declared, dtype and rank as declared, each shape symbol one size within its group
    (``F`` = frames of the analysis, ``B`` = bodies, ...), every dataset's ``units`` attribute
    the declared unit in the file's units, its ``long_name`` and dimension scales the declared
    ones (netCDF-4), every non-optional object present."""
    import h5py
    problems: list[str] = []
    sizes: dict[tuple, int] = {}
    seen: set[tuple] = set()
    insts: dict[str, str] = {}         # "/analysis_000" -> "analysis", ...

    def attrs(obj, scope, inst):
        insts[inst] = scope
        for k in obj.attrs:
            it = lookup(scope, "attr", k)
            if it is None:
                problems.append(f"{inst or '/'}@{k}: undeclared attribute")
            else:
                seen.add((inst, it))

    def dataset(ds, scope, inst, rel, units):
        where = "/" + ds.name.lstrip("/")
        it = lookup(scope, "dataset", rel)
        if it is None:
            problems.append(f"{where}: undeclared dataset")
            return
        seen.add((inst, it))
        kind = "O" if h5py.check_string_dtype(ds.dtype) is not None else ds.dtype.kind
        if kind not in DTYPE_KINDS[it.dtype]:
            problems.append(f"{where}: dtype {ds.dtype}, declared {it.dtype}")
        if len(ds.shape) != len(it.shape):
            problems.append(f"{where}: shape {ds.shape}, declared {shape_text(it.shape)}")
        for n, s in zip(ds.shape, it.shape):
            m = re.fullmatch(r"(\d*)([A-Za-z]\w*)", str(s))
            if isinstance(s, int) or not m:
                if n != s:
                    problems.append(f"{where}: shape {ds.shape}, declared {shape_text(it.shape)}")
                continue
            k = int(m.group(1) or 1)
            key = (inst, m.group(2))
            if n % k or sizes.setdefault(key, n // k) != n // k:
                problems.append(f"{where}: axis {s} is {n}, elsewhere in {inst or '/'} "
                                f"{m.group(2)} = {sizes[key]}")
        extra = set(ds.attrs) - {"units", "long_name", "coordinates", "DIMENSION_LIST"}
        if extra:
            problems.append(f"{where}: undeclared attributes {sorted(extra)}")
        if _text(ds.attrs.get("long_name")) != long_name(it):
            problems.append(f"{where}: long_name {_text(ds.attrs.get('long_name'))!r}, "
                            f"declared {long_name(it)!r}")
        got = tuple(d[0].name.rsplit("/", 1)[-1] if len(d) else None for d in ds.dims)
        if got != dims(it)[:len(got)]:
            problems.append(f"{where}: dimensions {got}, declared {dims(it)}")
        if "coordinates" in ds.attrs:
            missing = [c for c in _text(ds.attrs["coordinates"]).split() if c not in ds.parent]
            if missing:
                problems.append(f"{where}: coordinates {missing} not in its group")
        if "units" not in ds.attrs:
            problems.append(f"{where}: no units attribute")
        else:
            u = ds.attrs["units"]
            u = u.decode() if isinstance(u, bytes) else str(u)
            if u != unit_string(it.unit, units):
                problems.append(f"{where}: units {u!r}, declared {unit_string(it.unit, units)!r}")

    def dimension(ds, name, where):
        """A netCDF dimension scale: a declared dimension, a scale, sized as its users."""
        if name not in dimension_names() or _text(ds.attrs.get("CLASS")) != "DIMENSION_SCALE":
            problems.append(f"{where}/{name}: undeclared dataset")
            return
        if component_dim(name):
            if where:
                problems.append(f"{where}/{name}: fixed-size dimension outside the root")
            values = component_values(name)
            n = values if isinstance(values, int) else len(values)
            if ds.shape != (n,):
                problems.append(f"/{name}: shape {ds.shape}, declared ({n},)")

    with h5py.File(path, "r") as f:
        units = f.attrs.get("units", "")
        units = units.decode() if isinstance(units, bytes) else str(units)
        attrs(f, "root", "")
        for top in f:
            obj = f[top]
            scope = _scope_of(top)
            if isinstance(obj, h5py.Dataset):
                if top in dimension_names():
                    dimension(obj, top, "")
                else:
                    dataset(obj, "root", "", top, units)
                continue
            if top in ("timings", "counts"):
                attrs(obj, top, "/" + top)
                continue
            if scope is None:
                problems.append(f"/{top}: undeclared group")
                continue
            insts["/" + top] = scope
            if scope == "analysis":
                attrs(obj, "analysis", "/" + top)
            elif len(obj.attrs):
                problems.append(f"/{top}: undeclared attributes {sorted(obj.attrs)}")

            def visit(name, o, top=top, scope=scope):
                if isinstance(o, h5py.Dataset) and "/" not in name and name in dimension_names():
                    dimension(o, name, "/" + top)
                elif isinstance(o, h5py.Dataset):
                    dataset(o, scope, "/" + top, name, units)
                elif set(o.attrs) - {"coordinates"}:
                    problems.append(f"/{top}/{name}: undeclared attributes {sorted(o.attrs)}")
                elif "coordinates" in o.attrs and any(
                        c not in o for c in _text(o.attrs["coordinates"]).split()):
                    problems.append(f"/{top}/{name}: coordinates not in the group")
            obj.visititems(visit)
        for inst, scope in insts.items():
            for it in items():
                if it.scope == scope and not it.optional and not it.pattern \
                        and (inst, it) not in seen:
                    problems.append(f"{inst or '/'}: missing {it.kind} {it.name!r}")
    return problems


# ------------------------------------------------------------------- the format document
# docs/results-format.md: the prose of results_format.md (next to this module) with each
# ``{{datasets:SECTION}}`` / ``{{attrs:SECTION}}`` line replaced by the table of that section's
# declarations; a test compares the committed document with :func:`markdown`.
TEMPLATE = Path(__file__).with_name("results_format.md")
_MARK = re.compile(r"^\{\{(datasets|attrs):([a-z-]+)\}\}$", re.M)
_UNIT_TEXT = {"": "–", "1": "1"}


def _unit(it: Item) -> str:
    if it.dtype in ("str", "json") and not it.unit:
        return "–"
    return _UNIT_TEXT.get(it.unit, it.unit.replace("*", "·"))


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _name(it: Item) -> str:
    return f"`{it.name}`"


def table(kind: str, section: str) -> str:
    rows = [it for it in items() if it.section == section
            and it.kind == ("dataset" if kind == "datasets" else "attr")]
    if not rows:
        raise ValueError(f"{TEMPLATE.name}: no {kind} declared in section {section!r}")
    if kind == "datasets":
        out = ["| dataset | shape (dimensions) | dtype | units | meaning |",
               "|---|---|---|---|---|"]
        for it in rows:
            opt = "*(optional)* " if it.optional else ""
            dn = f" ({', '.join(dims(it))})" if it.shape else ""
            out.append(f"| {_name(it)} | {shape_text(it.shape)}{dn} | {it.dtype} | "
                       f"{_unit(it)} | {opt}{_cell(it.meaning)} |")
    else:
        out = ["| attribute | type | units | meaning |", "|---|---|---|---|"]
        for it in rows:
            opt = "*(optional)* " if it.optional else ""
            out.append(f"| {_name(it)} | {it.dtype} | {_unit(it)} | {opt}{_cell(it.meaning)} |")
    return "\n".join(out)


def dimension_table() -> str:
    """The netCDF dimensions: name, where it is defined, its size and coordinate values."""
    out = ["| dimension | defined in | size | coordinate values / meaning |", "|---|---|---|---|"]
    for sym, name in sd.symbol_dimensions().items():
        where = sorted({it.scope for it in items() if it.kind == "dataset"
                        and name in dims(it)})
        place = ", ".join("`/`" if w == "root" else "`/model`" if w == "model"
                          else "sweep file" if w == schema_sweep.SCOPE
                          else "`/analysis_NNN`" for w in where)
        e = next((it.name[:-3] for it in items() if it.kind == "dataset"
                  and it.name.endswith("/id") and dims(it) == (name,)), None)
        meaning = sd.DIM_MEANINGS.get(name) or (f"one per `{e}/id` row" if e else "")
        out.append(f"| `{name}` | {place} | `{sym}` | {_cell(meaning)} |")
    for name, (sym, k, meaning) in sd.DERIVED.items():
        out.append(f"| `{name}` | `/analysis_NNN` | {k}·`{sym}` | {_cell(meaning)} |")
    for name, (values, meaning) in sd.COMPONENTS.items():
        size, vals = (values, "") if isinstance(values, int) else \
            (len(values), ", ".join(f"`{v}`" for v in values) + ": ")
        out.append(f"| `{name}` | `/` | {size} | {vals}{_cell(meaning)} |")
    return "\n".join(out)


def markdown() -> str:
    """The whole document: the template with every table filled in."""
    text = TEMPLATE.read_text(encoding="utf-8").replace("{{dimensions}}", dimension_table())
    used = set()

    def fill(m):
        used.add((m.group(1), m.group(2)))
        return table(m.group(1), m.group(2))
    out = _MARK.sub(fill, text)
    missing = {(("datasets" if it.kind == "dataset" else "attrs"), it.section)
               for it in items()} - used
    if missing:
        raise ValueError(f"{TEMPLATE.name}: sections without a table: {sorted(missing)}")
    return out


def main(argv=None) -> int:
    """``python -m poise.results.schema --markdown FILE``: (re)write the format document."""
    import argparse
    ap = argparse.ArgumentParser(prog="python -m poise.results.schema",
                                 description="write docs/results-format.md from the schema")
    ap.add_argument("--markdown", metavar="FILE", help="write the document here ('-': stdout)")
    ns = ap.parse_args(argv)
    text = markdown()
    if not ns.markdown or ns.markdown == "-":
        print(text, end="")
    else:
        with open(ns.markdown, "w", encoding="utf-8") as f:
            f.write(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
