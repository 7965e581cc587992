"""Sweep cases: ``--set`` parameters checked against the deck schema, the cases of a sweep
and their substitution into the parsed deck (:mod:`poise.app.sweep` runs them).

Parameters (``--set``): ``Tag[id].attr=VALUES`` or ``Tag.attr=VALUES`` (an element that occurs
once, e.g. ``Param_Static``, ``Force_Gravity``). VALUES: an inclusive range ``a:b:step`` or a
list ``v1,v2,…``. Values are checked against the schema (kind, bounds, enum choices); the
substituted deck is validated again in the worker (an invalid combination gives an
``invalid_deck`` row). ``Param_Static.attr`` for a deck without a model ``Param_Static`` becomes
a solver override.

Modes: ``grid`` (Cartesian product, first parameter slowest), ``zip`` (parameters in lock-step,
equal lengths), ``random`` (``n`` cases; ranges of real attributes are sampled uniformly in
[a, b], other parameters uniformly from their values; ``numpy.random.default_rng(seed)``).

Groups and chunks: cases with the same values of the structural (enum, boolean) parameters
form a group; each group is cut into chunks of consecutive cases (:func:`chunks`), the unit a
worker solves and a resumed sweep keeps.
"""
from __future__ import annotations

import hashlib
import itertools
import json
import math
import re
from dataclasses import dataclass, replace

from poise.core.errors import UsageError
from poise.core.version import __version__
from poise.deck.schema import ENUM_ALIASES, element_schema
from poise.deck.values import parse_number

_SPEC = re.compile(r"^\s*([A-Za-z][A-Za-z0-9_]*)\s*(?:\[\s*(-?\d+)\s*\])?\s*\.\s*"
                   r"([A-Za-z][A-Za-z0-9_]*)\s*$")
_SWEEPABLE = ("real", "int", "real_or_expr", "enum", "bool")


@dataclass
class Param:
    """One swept attribute: ``key`` as written canonically (``Force_SpringDamper[3].stiffness``)."""

    key: str
    tag: str
    id: int | None
    attr: str
    kind: str
    values: list
    range: tuple | None = None        # (a, b) of an a:b:step range
    override: bool = False            # Param_Static without a model element: solver override

    @property
    def structural(self) -> bool:
        """An enum or boolean attribute (a method, a joint type, a flag): cases with other
        values may have another structure, so they are solved in separate groups."""
        return self.kind in ("enum", "bool")


# ---------------------------------------------------------------------------- parameters
def _num(text: str, kind: str, where: str):
    v = parse_number(text)
    if v is None or not math.isfinite(v):
        raise UsageError(f"{where}: {text!r} is not a number")
    if kind == "int":
        if v != int(v):
            raise UsageError(f"{where}: {text!r} is not an integer")
        return int(v)
    return v


def _clean(v: float) -> float:
    """Round range points to 12 significant digits (0.1*3 -> 0.3, not 0.30000000000000004)."""
    return float(f"{v:.12g}")


def _check_value(attr, v, where: str):
    if attr.kind == "enum":
        u = " ".join(str(v).upper().split())
        u = ENUM_ALIASES.get(u, u)
        if attr.choices and u not in attr.choices:
            raise UsageError(f"{where}: {v!r} is not one of {', '.join(attr.choices)}")
        return u
    if attr.kind == "bool":
        u = str(v).strip().upper()
        if u in ("TRUE", "YES", "1", "T", "ON"):
            return True
        if u in ("FALSE", "NO", "0", "F", "OFF"):
            return False
        raise UsageError(f"{where}: {v!r} is not a boolean (TRUE/FALSE)")
    x = _num(str(v), "int" if attr.kind == "int" else "real", where) \
        if not isinstance(v, (int, float)) or isinstance(v, bool) else v
    if attr.kind == "int":
        if float(x) != int(x):
            raise UsageError(f"{where}: {v!r} is not an integer")
        x = int(x)
    else:
        x = float(x)
        if not math.isfinite(x):
            raise UsageError(f"{where}: {v!r} is not finite")
    bad = ((attr.lo is not None and (x < attr.lo or (attr.lo_open and x == attr.lo)))
           or (attr.hi is not None and (x > attr.hi or (attr.hi_open and x == attr.hi))))
    if bad:
        raise UsageError(f"{where}: {x!r} out of bounds; {attr.name} must be {attr.bounds_text()}")
    return x


def parse_values(attr, text, where: str) -> tuple[list, tuple | None]:
    """``a:b:step`` (inclusive) or ``v1,v2,…`` (or a Python list) -> checked values, range."""
    if isinstance(text, (list, tuple)):
        vals = [_check_value(attr, v, where) for v in text]
        if not vals:
            raise UsageError(f"{where}: no values")
        return vals, None
    text = str(text).strip()
    if ":" in text and attr.kind in ("real", "int", "real_or_expr"):
        parts = text.split(":")
        if len(parts) != 3:
            raise UsageError(f"{where}: range must be a:b:step, got {text!r}")
        kind = "int" if attr.kind == "int" else "real"
        a, b, step = (_num(p.strip(), kind, where) for p in parts)
        span = (float(b) - float(a)) / float(step) if step != 0 else math.nan
        if step == 0 or span < 0:
            raise UsageError(f"{where}: step {step!r} does not go from {a!r} to {b!r}")
        if not span < 1_000_000:            # also inf/nan: b - a overflows a float
            raise UsageError(f"{where}: range {text!r} has more than 1000000 values "
                             "(or overflows)")
        n = int(math.floor(span + 1e-9)) + 1
        raw = [a + i * step for i in range(n)]
        vals = [_check_value(attr, v if kind == "int" else _clean(v), where) for v in raw]
        return vals, (a, b)
    items = [t.strip() for t in text.split(",")]
    if not text or any(not t for t in items):
        raise UsageError(f"{where}: expected a:b:step or v1,v2,..., got {text!r}")
    return [_check_value(attr, t, where) for t in items], None


def resolve_param(spec, key: str, values) -> Param:
    """Check ``Tag[id].attr`` against the deck and the schema; parse and check its values."""
    where = f"--set {key!r}"
    m = _SPEC.match(key)
    if not m:
        raise UsageError(f"{where}: expected Tag[id].attr or Tag.attr, "
                         f"e.g. Force_SpringDamper[3].stiffness")
    tag, eid, name = m.group(1), m.group(2), m.group(3)
    sch = element_schema(tag)
    if sch is None:
        raise UsageError(f"{where}: unknown element <{tag}>")
    a = sch.attr(name)
    if a is None:
        raise UsageError(f"{where}: <{sch.tag}> has no attribute {name!r}")
    if a.kind not in _SWEEPABLE or a.ref or a.name == "id":
        raise UsageError(f"{where}: attribute {a.name!r} ({a.kind}{', reference' if a.ref else ''})"
                         f" cannot be swept; numeric, enum and boolean attributes can")
    els = [e for e in spec.model if e.tag == sch.tag]
    override = False
    if eid is not None:
        eid = int(eid)
        if not any(e.id == eid for e in els):
            have = sorted(e.id for e in els if e.id is not None)
            raise UsageError(f"{where}: the deck has no <{sch.tag} id={eid}>"
                             + (f"; ids: {', '.join(map(str, have))}" if have else ""))
        canon = f"{sch.tag}[{eid}].{a.name}"
    else:
        if len(els) > 1:
            raise UsageError(f"{where}: the deck has {len(els)} <{sch.tag}> elements; "
                             f"address one as {sch.tag}[id].{a.name}")
        if not els:
            if sch.tag != "Param_Static":
                raise UsageError(f"{where}: the deck has no <{sch.tag}> element")
            override = True
        canon = f"{sch.tag}.{a.name}"
    vals, rng = parse_values(a, values, f"--set {canon}")
    return Param(canon, sch.tag, eid, a.name, a.kind, vals, rng, override)


def parse_set(text: str) -> tuple[str, str]:
    """``'Tag[id].attr=values'`` -> (key, values)."""
    if "=" not in text:
        raise UsageError(f"--set {text!r}: expected Tag[id].attr=VALUES")
    k, v = text.split("=", 1)
    return k.strip(), v.strip()


#: Default cap on the number of cases of one sweep (``--max-cases``).
MAX_CASES = 100_000


def count_cases(params: list[Param], mode: str = "grid", n: int | None = None) -> int:
    """The number of cases :func:`make_cases` would make, without making them."""
    if mode == "grid":
        return math.prod(len(p.values) for p in params)
    if mode == "zip":
        return max((len(p.values) for p in params), default=0)
    if mode == "random":
        return int(n or 0)
    raise UsageError(f"unknown sweep mode {mode!r}; expected grid, zip or random")


def check_case_count(params: list[Param], mode: str = "grid", n: int | None = None,
                     max_cases: int | None = MAX_CASES) -> int:
    """:func:`count_cases`, refused (``UsageError``) above ``max_cases`` (None: no cap)."""
    total = count_cases(params, mode, n)
    if max_cases is not None and total > max_cases:
        what = "--random N" if mode == "random" else \
            " x ".join(str(len(p.values)) for p in params) + " values"
        raise UsageError(f"the sweep has {total} cases ({what}), more than --max-cases "
                         f"{max_cases}; raise --max-cases to run it")
    return total


def make_cases(params: list[Param], mode: str = "grid", n: int | None = None,
               seed: int | None = 0) -> list[dict]:
    """Case values: list of {param key: value} in case order (check the count first:
    :func:`check_case_count`)."""
    keys = [p.key for p in params]
    if mode == "grid":
        return [dict(zip(keys, combo)) for combo in itertools.product(*[p.values for p in params])]
    if mode == "zip":
        lens = {p.key: len(p.values) for p in params}
        if len(set(lens.values())) > 1:
            raise UsageError("--zip needs the same number of values for every --set; got "
                             + ", ".join(f"{k}: {v}" for k, v in lens.items()))
        return [dict(zip(keys, combo)) for combo in zip(*[p.values for p in params])]
    if mode == "random":
        if not n or n < 1:
            raise UsageError("--random N needs N >= 1")
        import numpy as np
        rng = np.random.default_rng(seed)
        cases = []
        for _ in range(n):
            c = {}
            for p in params:
                if p.range is not None and p.kind in ("real", "real_or_expr"):
                    c[p.key] = _clean(float(rng.uniform(p.range[0], p.range[1])))
                else:
                    c[p.key] = p.values[int(rng.integers(len(p.values)))]
            cases.append(c)
        return cases
    raise UsageError(f"unknown sweep mode {mode!r}; expected grid, zip or random")


def case_hash(deck_sha256: str, values: dict, overrides: dict | None) -> str:
    blob = json.dumps({"deck_sha256": deck_sha256, "values": values,
                       "overrides": overrides or {}, "poise_version": __version__},
                      sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()


def apply_case(spec, params: list[Param], values: dict):
    """A copy of ``spec`` with the case values substituted (model elements copied only where
    changed) and the solver overrides of ``Param_Static`` parameters without an element."""
    changes: dict[int, dict] = {}
    overrides = {}
    for p in params:
        v = values[p.key]
        if p.override:
            overrides[p.attr] = v
            continue
        for k, e in enumerate(spec.model):
            if e.tag == p.tag and (p.id is None or e.id == p.id):
                changes.setdefault(k, {})[p.attr] = v
                break
    model = list(spec.model)
    for k, ch in changes.items():
        model[k] = replace(model[k], attrs={**model[k].attrs, **ch})
    return replace(spec, model=model, warnings=[]), overrides


# ---------------------------------------------------------------------------- chunks
def group_cases(params: list[Param], cases: list[dict], todo) -> dict[str, tuple[dict, list]]:
    """``{group key: (structural values, [case numbers])}`` of the cases ``todo`` (in order),
    grouped by the values of the structural parameters (one group when there are none)."""
    keys = [p.key for p in params if p.structural]
    out: dict[str, tuple[dict, list]] = {}
    for i in todo:
        group = {k: cases[i][k] for k in keys}
        g = json.dumps(group, sort_keys=True, default=str)
        out.setdefault(g, (group, []))[1].append(int(i))
    return out


#: most cases in one chunk (progress and memory per task stay small)
MAX_CHUNK = 1000


def chunk_size(n: int, workers: int, per_case_bytes: int = 0, limit: int = 64 << 20,
               per_worker: int = 8) -> int:
    """Cases per chunk for ``n`` cases on ``workers``: about ``per_worker`` chunks per worker
    (load balance, progress; cases solved together want fewer, larger chunks), at most
    :data:`MAX_CHUNK` and at most ``limit`` bytes of results per chunk (``per_case_bytes``
    each)."""
    size = math.ceil(n / max(1, per_worker * max(1, workers)))
    if per_case_bytes:
        size = min(size, max(1, limit // per_case_bytes))
    return max(1, min(MAX_CHUNK, size))


def chunks(groups: dict, size: int) -> list[tuple[dict, list]]:
    """``[(structural values, [case numbers])]``: each group cut into chunks of ``size``."""
    return [(group, idx[k:k + size]) for group, idx in groups.values()
            for k in range(0, len(idx), size)]
