"""An Adams command file (``.acf``) -> the XML command section of its model.

The model is the dataset named by the file's first line (Adams' layout: dataset name, then the
output name) or by ``FILE/MODEL=``, relative to the command file (``.adm`` added when the name
has no suffix). Commands: ``SIMULATE/STATIC`` (with END/DURATION a quasi-static analysis);
``SIMULATE/DYNAMIC|KINEMATIC|TRANSIENT`` become quasi-static analyses over the same output times
(one warning: poise computes equilibria, not motion); ``EQUILIBRIUM/`` and ``INTEGRATOR/`` set
Param_Static / Param_Transient; a model statement written again (``SFORCE/3, FUNCTION=...``)
changes what it changes, as an XML command version (the statement is translated with the new
values and compared with the model's element); ``DEACTIVATE``/``ACTIVATE`` of a force sets it
to zero / back; constraints can be deactivated only before the first analysis (they are then
left out of the model); ``STOP`` ends the commands.
"""
from __future__ import annotations

import hashlib
import os
import re

from poise.core.errors import DeckError, Problem, SourceLoc
from poise.deck.adm.lexer import Statement
from poise.deck.adm.data import equilibrium, integrator
from poise.deck.adm.reader import TRANSLATORS, build, decode, model_spec, statements
from poise.deck.adm.records import Ctx, Rec, num
from poise.deck.adm.vocab import ACF, REDEFINABLE, STATEMENTS, lookup
from poise.deck.validate import FileProblem

_TABLE = {**ACF, **{n: STATEMENTS[n] for n in REDEFINABLE if n not in ACF}}
_DYNAMIC = ("DYNAMIC", "KINEMATIC", "TRANSIENT")
#: deactivating a force sets these to zero (the element stays: the model's structure does not
#: change between analyses)
_ZERO = {"Force_Scalar_TwoBody": ("val_expression",),
         "Force_SpringDamper": ("stiffness", "damping", "preload"),
         "Force_Bushing": tuple(f"{p}{c}" for p in ("k", "c") for c in
                                ("x", "y", "z", "tx", "ty", "tz"))
         + tuple(f"preload_{c}" for c in ("x", "y", "z", "tx", "ty", "tz")),
         "Force_Vector_TwoBody": tuple(f"{c}_expression" for c in ("fx", "fy", "fz", "tx", "ty", "tz")),
         "Force_Vector_OneBody": tuple(f"{c}_expression" for c in ("fx", "fy", "fz", "tx", "ty", "tz"))}
_HEADER = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)\s*/")
#: keywords that place frames (fixed before any analysis): changing them between analyses would
#: move markers, which command versions cannot do
_PLACED = {"MARKER": None, "PART": ("QG", "REULER", "XG", "ZG", "CM", "IM", "GROUND"),
           "POINT_MASS": ("QG", "REULER", "XG", "ZG", "CM")}


def _header(text: str) -> tuple[str, list[tuple[int, str]]]:
    """The text with Adams' two header lines (model name, output name) blanked, and those
    lines; none when the file starts with a command."""
    lines = text.split("\n")
    found = []
    for k, raw in enumerate(lines):
        body = raw.split("!", 1)[0].strip()
        if not body:
            continue
        if not found:
            m = _HEADER.match(body)
            if m and lookup(m.group(1), _TABLE)[0] is not None:
                return text, []
            if lookup(body, _TABLE)[0] is not None and body.upper() in ("STOP", "END"):
                return text, []
        found.append((k + 1, body))
        lines[k] = ""
        if len(found) == 2:
            break
    return "\n".join(lines), found


def read_acf(path: str, data: bytes, *, check: bool = True, ignore=()):
    """The DeckSpec of a command file: its model's elements and its commands."""
    text = decode(data, path)
    text, head = _header(text)
    probs: list = []
    _, cmds = statements(text, path, _TABLE, False, probs, stop_at_end=False)
    model_name, model_line = (head[0][1], head[0][0]) if head else (None, 0)
    for c in cmds:
        if c.name == "FILE":
            if c.has("COMMAND"):
                probs.append(Problem(Ctx.loc(c), "FILE/COMMAND= (reading commands from another "
                                                 "file) is not supported; expected the commands "
                                                 "in this file"))
            if c.has("MODEL"):
                if model_name is not None:
                    probs.append(Problem(Ctx.loc(c), "a second model; a command file runs one "
                                                     "dataset"))
                model_name, model_line = c.get("MODEL"), c.line
    if model_name is None:
        probs.append(FileProblem(SourceLoc(path, 1, "acf"), "no model: expected the dataset "
                                 "name on the first line or FILE/MODEL=NAME"))
        raise DeckError(probs)
    mpath = _model_path(path, model_name)
    try:
        with open(mpath, "rb") as f:
            mdata = f.read()
    except OSError as e:
        probs.append(FileProblem(SourceLoc(path, model_line, "acf"),
                                 f"cannot read the model {mpath!r}: {e.strerror or e}"))
        raise DeckError(probs) from None
    spec, ctx, _ = model_spec(mpath, mdata, ignore)
    spec.path = path
    spec.sha256 = hashlib.sha256(data).hexdigest()
    spec.input_files = {mpath: hashlib.sha256(mdata).hexdigest()}
    ctx.problems.extend(probs)
    commands(ctx, cmds)
    summarize_commands(ctx)
    return build(ctx, spec, check), ctx


def _model_path(acf: str, name: str) -> str:
    name = name.strip().strip("'\"")
    base = os.path.dirname(acf)
    p = os.path.join(base, name)
    if not os.path.splitext(name)[1] and not os.path.exists(p):
        p += ".adm"
    return p


class _State:
    """What the commands did so far: analyses run, elements switched off."""

    def __init__(self):
        self.simulated = False
        self.off: dict[tuple, Statement] = {}       # (name, id) -> the DEACTIVATE command
        self.current: dict[tuple, dict] = {}        # (tag, id) -> attributes now in force
        self.dynamic_warned = False
        self.skipped: dict[str, list] = {}
        self.ignored_kw: dict[tuple, list] = {}    # (command, keyword) -> commands


def commands(ctx: Ctx, cmds: list[Statement]) -> None:
    st = _State()
    ctx.acf_skipped = st.skipped
    ctx.acf_ignored_kw = st.ignored_kw
    for c in cmds:
        name = c.name
        if name == "FILE":
            continue
        for v in c.values.values():
            kw = (c.defn.keywords if v.kind != "flag" else c.defn.flags).get(v.name)
            if kw is not None and kw.ignored:
                st.ignored_kw.setdefault((name, v.name), []).append(c)
        if name == "STOP":
            ctx.recs.append(Rec("Stop", {}, c.file, c.line, "STOP", "command", None, c.comments))
            return
        status = c.defn.status
        if status == "skip":
            st.skipped.setdefault(name, []).append(c)
        elif status == "refuse" and name in ACF:
            ctx.refuse(c, c.defn.kind, c.defn.why)
        elif name == "SIMULATE":
            _simulate(ctx, c, st)
        elif name in ("ACTIVATE", "DEACTIVATE"):
            _switch(ctx, c, st)
        elif name == "EQUILIBRIUM":
            equilibrium(ctx, c, section="command")
        elif name == "INTEGRATOR":
            integrator(ctx, c, section="command")
        else:
            _redefine(ctx, c, st)
    ctx.recs.append(Rec("Stop", {}, cmds[-1].file if cmds else ctx.file,
                        cmds[-1].line if cmds else 1, "STOP", "command"))


def summarize_commands(ctx: Ctx) -> None:
    for name, sts in getattr(ctx, "acf_skipped", {}).items():
        n = len(sts)
        ctx.warnings.append(Problem(Ctx.loc(sts[0]), f"{n} {name} command{'s' * (n > 1)} "
                                    f"skipped ({ACF[name].why}: no effect on statics)"))
    for (name, key), sts in getattr(ctx, "acf_ignored_kw", {}).items():
        n = len(sts)
        ctx.warnings.append(Problem(Ctx.loc(sts[0]), f"{key} ignored in {n} {name} "
                                    f"command{'s' * (n > 1)} (no effect on statics)"))


def _simulate(ctx: Ctx, c: Statement, st: _State) -> None:
    kind = ctx.one_of(c, ["STATIC", *_DYNAMIC, "INITIAL_CONDITIONS"], "analysis")
    if kind is None:
        return
    if kind == "INITIAL_CONDITIONS":
        ctx.warn(c, "an initial-conditions analysis is skipped (poise's analyses assemble the "
                    "model themselves)")
        return
    a = {"analysis_type": "STATIC"}
    if c.has("END") and c.has("DURATION"):
        ctx.error(c, "END and DURATION both given; expected one")
        return
    if c.has("STEPS") and c.has("DTOUT"):
        ctx.error(c, "STEPS and DTOUT both given; expected one")
        return
    if c.has("END"):
        a["end_time"] = num(c.get("END"))
    if c.has("DURATION"):
        a["duration"] = num(c.get("DURATION"))
    if c.has("STEPS"):
        a["num_steps"] = num(c.get("STEPS"))
    if c.has("DTOUT"):
        a["print_interval"] = num(c.get("DTOUT"))
    if kind in _DYNAMIC:
        if not (c.has("END") or c.has("DURATION")):
            ctx.error(c, f"SIMULATE/{kind} needs END= or DURATION=")
            return
        if not st.dynamic_warned:
            ctx.warn(c, f"SIMULATE/{kind} is solved as a quasi-static analysis over the same "
                        "output times (poise computes equilibria, not motion)")
            st.dynamic_warned = True
    ctx.recs.append(Rec("Simulate", a, c.file, c.line, f"SIMULATE/{kind}", "command", None,
                        c.comments))
    st.simulated = True


def _model_recs(ctx: Ctx, model: Statement) -> list[Rec]:
    return ctx.by_stmt.get(id(model), [])


def _switch(ctx: Ctx, c: Statement, st: _State) -> None:
    kinds = [k for k in c.defn.flags if c.has(k)]
    if len(kinds) != 1:
        ctx.error(c, "expected one element type (SFORCE, JOINT, ...); got "
                  + (", ".join(kinds) or "none"))
        return
    kind = kinds[0]
    ids = list(c.get("ID", []))
    rng = c.get("RANGE")
    if rng is not None:
        if len(rng) != 2 or rng[0] > rng[1]:
            ctx.error(c, "RANGE= expects two ids, the first not above the second")
            return
        ids += [i for i in ctx.stmts.get(kind, {}) if rng[0] <= i <= rng[1]]
    if not ids:
        ctx.error(c, "no ID= or RANGE=; expected the ids of the elements")
        return
    on = c.name == "ACTIVATE"
    for i in ids:
        key = (kind, i)
        if key in ctx.refused and not st.simulated and not on:
            del ctx.refused[key]                # switched off before it could act: not needed
            ctx.warn(c, f"{kind}/{i} deactivated before any analysis: left out")
            continue
        model = ctx.stmts.get(kind, {}).get(i)
        if model is None:
            ctx.error(c, f"no {kind}/{i} in the model")
            continue
        recs = [r for r in _model_recs(ctx, model) if r.section == "model"]
        if not recs:
            continue                             # not translated (its problem is reported)
        tag = recs[0].tag
        if (key in st.off) == (not on):
            continue                             # already in that state
        if tag in _ZERO:
            cur = st.current.setdefault((tag, recs[0].attrs["id"]), dict(recs[0].attrs))
            attrs = {n: ("0" if not on else cur[n]) for n in _ZERO[tag] if n in cur}
            ctx.recs.append(Rec(tag, {"id": recs[0].attrs["id"], **attrs}, c.file, c.line,
                                f"{c.name}/{kind}", "command", None, c.comments))
        elif not st.simulated and not on:
            for r in recs:
                r.removed = True
            ctx.warn(c, f"{kind}/{i} deactivated before any analysis: left out of the model")
        else:
            ctx.error(c, f"{'activating' if on else 'deactivating'} {kind}/{i} between analyses "
                         "would change the model's structure (its equations or unknowns), which "
                         "poise cannot do; expected it before the first SIMULATE")
            continue
        if on:
            st.off.pop(key, None)
        else:
            st.off[key] = c


def _redefine(ctx: Ctx, c: Statement, st: _State) -> None:
    """A model statement written again: the changed attributes as an XML command."""
    if c.name in _PLACED:
        keys = [k for k in c.values if _PLACED[c.name] is None or k in _PLACED[c.name]]
        if keys:
            ctx.error(c, f"changing {', '.join(keys)} of {c.who} between analyses would move "
                         "markers, which poise cannot do; expected changes of values such as "
                         "MASS or IP")
            return
    if c.defn.has_id == "yes":
        model = ctx.stmts.get(c.name, {}).get(c.id)
        if model is None:
            ctx.error(c, f"no {c.who} in the model to change")
            return
        if (c.name, c.id) in st.off:
            ctx.error(c, f"{c.who} is deactivated; expected ACTIVATE before changing it")
            return
    else:
        model = next(iter(ctx.stmts.get(c.name, {}).values()), None)
        if model is None:
            model = next((s for s in getattr(ctx, "statements", ()) if s.name == c.name), None)
    base = dict(model.values) if model is not None else {}
    merged = Statement(c.name, c.id, c.line, c.file, {**base, **c.values}, list(c.comments),
                       model.label if model is not None else None, c.defn, c.written)
    n = len(ctx.recs)
    nprob = len(ctx.problems)
    TRANSLATORS[c.name](ctx, merged)
    new = ctx.recs[n:]
    del ctx.recs[n:]
    if len(ctx.problems) > nprob:
        return
    old = [r for r in _model_recs(ctx, model)] if model is not None else []
    for r in new:
        prev = next((o for o in old if o.tag == r.tag and o.section == "model"), None)
        changed = {k: v for k, v in r.attrs.items()
                   if prev is None or prev.attrs.get(k) != v} if r.tag else {}
        changed.pop("label", None)
        changed.pop("id", None)
        if not changed:
            continue
        if "id" in r.attrs:
            cur = st.current.setdefault((r.tag, r.attrs["id"]), dict(prev.attrs if prev else {}))
            cur.update(changed)
            changed = {"id": r.attrs["id"], **changed}
        ctx.recs.append(Rec(r.tag, changed, c.file, c.line, c.who, "command", r.text, c.comments))
