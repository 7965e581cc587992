"""Read an Adams dataset (``.adm``) or command file (``.acf``) into a :class:`DeckSpec`.

The statements are translated into MotionSolve XML element records (:mod:`.records`), typed by
the XML reader's own builder and validated by its validator, so everything downstream (methods,
results, labels, units, sweeps) sees the deck an XML file with the same elements would give;
``poise convert`` writes those records. Locations stay the dataset's: ``FILE:LINE: JOINT/3:``.
Problems found while reading the statements are reported together (exit 3); validation of the
translated elements runs when there are none. Without a command file the dataset runs one
static analysis at t = 0.
"""
from __future__ import annotations

import hashlib
from dataclasses import replace

from poise.core.errors import DeckError, Problem, SourceLoc
from poise.deck.adm import constraints, data, forces, parts
from poise.deck.adm.lexer import Scanner, Statement, split_lines
from poise.deck.adm.records import Ctx, Rec
from poise.deck.adm.vocab import END, STATEMENTS, lookup
from poise.deck.build import Builder, place
from poise.deck.spec import DeckSpec, Expr
from poise.deck.validate import FileProblem, validate

SUFFIXES = (".adm", ".acf")
MAX_BYTES = 1 << 30

TRANSLATORS = {**parts.TRANSLATORS, **constraints.TRANSLATORS, **forces.TRANSLATORS,
               **data.TRANSLATORS}

#: XML attribute -> the dataset keyword it came from (expression messages name the keyword)
EXPR_KEYWORD = {"val_expression": "FUNCTION", "expr": "FUNCTION",
                **{f"{c}_expression": c.upper() for c in ("fx", "fy", "fz", "tx", "ty", "tz")},
                **{f"expr{k}": f"F{k}" for k in range(1, 9)}}


def is_dataset(path) -> bool:
    """Whether ``path`` names an Adams dataset or command file (by its suffix)."""
    return str(path).lower().endswith(SUFFIXES)


def decode(data: bytes, path: str) -> str:
    """The text of a dataset (UTF-8, else Latin-1); binary data is a located problem."""
    if b"\x00" in data[:1 << 16]:
        raise DeckError(FileProblem(SourceLoc(path, 0, "adm"), "not an Adams dataset: the file "
                                    "holds binary data (NUL bytes)"))
    if len(data) > MAX_BYTES:
        raise DeckError(FileProblem(SourceLoc(path, 0, "adm"), f"dataset larger than "
                                    f"{MAX_BYTES >> 30} GiB; is it the right file?"))
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def statements(text: str, path: str, table: dict, title: bool, problems: list,
               stop_at_end: bool = True) -> tuple[str, list[Statement]]:
    """The title and statements of a dataset's text; located problems appended to
    ``problems``."""
    head, chunks, bad = split_lines(text, title)
    problems += [FileProblem(SourceLoc(path, ln, "adm"), msg) for ln, msg in bad]
    out = []
    for c in chunks:
        written = c.head.rstrip("/").strip()
        if stop_at_end and written.upper() == END and not c.rest.strip():
            break
        defn, msg = lookup(written, table)
        if defn is None:
            problems.append(FileProblem(SourceLoc(path, c.line, "adm"), f"{written}: {msg}"))
            continue
        st = Statement(defn.name, None, c.line, path, comments=c.comments, label=c.label,
                       defn=defn, written=written)
        if defn.status in ("skip", "refuse"):
            st.id = _leading_id(c.rest)
        else:
            sc = Scanner(c, defn, path)
            st.id, st.values, label = sc.scan()
            if label is not None:
                st.label = label
            for ln, msg in sc.problems:
                problems.append(Problem(SourceLoc(path, ln, "adm", st.id, st.who), msg))
        if defn.has_id == "yes" and st.id is None:
            problems.append(Problem(SourceLoc(path, c.line, "adm", None, st.who),
                                    f"no id; expected {defn.name}/id, ..."))
            continue
        if defn.has_id == "no" and st.id is not None:
            problems.append(Problem(SourceLoc(path, c.line, "adm", st.id, st.who),
                                    f"{defn.name} takes no id; expected {defn.name}/ ..."))
            continue
        out.append(st)
    return head, out


def _leading_id(rest: str) -> int | None:
    t = rest.replace("\x1e", ",").split(",", 1)[0].strip()
    return int(t) if t.isdigit() else None


def translate(ctx: Ctx, stmts: list[Statement]) -> None:
    """Records of the model statements (in dataset order) into ``ctx``."""
    for s in stmts:
        if s.id is None or s.defn.status != "translate":
            continue
        by_id = ctx.stmts.setdefault(s.name, {})
        prev = by_id.get(s.id)
        if prev is not None:
            ctx.error(s, f"{s.who} is defined twice (also at line {prev.line})")
            continue
        by_id[s.id] = s
    parts.place(ctx, stmts)
    if not any(fr.ground for fr in ctx.parts.values()):
        ctx.problems.append(FileProblem(SourceLoc(ctx.file, 1, "adm"), "no ground part; "
                                        "expected one PART/id, GROUND"))
    carry: list[str] = []            # comments of statements that made no element
    for s in stmts:
        n = len(ctx.recs)
        _translate_one(ctx, s)
        if len(ctx.recs) > n:
            ctx.recs[n].comments[:0] = carry
            carry = []
        else:
            name = f" '{s.label}'" if s.label is not None else ""
            carry += s.comments + [f"{s.who}{name} (line {s.line}): {_fate(ctx, s)}"]
    ctx.trailing = carry


def _fate(ctx: Ctx, s: Statement) -> str:
    if s.defn.status == "skip":
        return f"skipped ({s.defn.why}: no effect on statics)"
    if s.defn.status == "refuse":
        return f"not translated ({s.defn.why})"
    m = ctx.markers.get(s.id) if s.name == "MARKER" else None
    if m is not None and m.floating:
        return "a FLOATING marker (written where a two-body vector force needs it)"
    return "no element"


def _translate_one(ctx: Ctx, s: Statement) -> None:
    status = s.defn.status
    if status == "skip":
        ctx.skipped.setdefault(s.name, []).append(s)
        return
    if status == "refuse":
        ctx.refuse(s, s.defn.kind, s.defn.why)
        return
    if s.id is not None and ctx.stmts.get(s.name, {}).get(s.id) is not s:
        return                                          # a duplicate (reported)
    for v in s.values.values():
        kw = (s.defn.keywords if v.kind != "flag" else s.defn.flags)[v.name]
        if kw.ignored:
            ctx.ignored_kw.setdefault((s.name, v.name), []).append(s)
    TRANSLATORS[s.name](ctx, s)


def summarize(ctx: Ctx, defs: dict) -> None:
    """One warning per skipped statement kind and per keyword without effect on statics."""
    for name, sts in ctx.skipped.items():
        s0 = sts[0]
        n = len(sts)
        ctx.warnings.append(Problem(ctx.loc(s0), f"{n} {name} statement{'s' * (n > 1)} "
                                    f"skipped ({defs[name].why}: no effect on statics)"))
    for (name, key), sts in ctx.ignored_kw.items():
        n = len(sts)
        ctx.warnings.append(Problem(ctx.loc(sts[0]), f"{key} ignored in {n} {name} "
                                    f"statement{'s' * (n > 1)} (no effect on statics)"))


def build(ctx: Ctx, spec: DeckSpec, check: bool) -> DeckSpec:
    """Type the records with the XML builder, give them the dataset's locations, validate."""
    probs = ctx.all_problems()
    if probs:
        raise DeckError(probs)
    recs = [r for r in ctx.recs if not r.removed]
    b = Builder(spec.path)
    b.flush([[r.tag, r.attrs, r.text, r.line, r.section, k] for k, r in enumerate(recs)])
    fixed = []
    for (el, where, shp), r in zip(b.items, recs):
        loc = SourceLoc(r.file, r.line, el.tag, el.id, r.who)
        el.loc = loc
        for k, v in el.attrs.items():
            if isinstance(v, Expr):
                el.attrs[k] = replace(v, loc=loc, attr=EXPR_KEYWORD.get(k, k))
        fixed.append((el, where, shp))
    place(spec, fixed)
    spec.warnings.extend(ctx.warnings)
    spec.warnings.extend(w for _, w in b.warnings)
    spec.ignored = list(ctx.ignored)
    if check:
        validate(spec)
    return spec


def no_command_file(ctx: Ctx, path: str) -> None:
    """One static analysis at t = 0 (a dataset read without a command file)."""
    st = Statement("SIMULATE", None, 1, path, comments=["no command file: one static analysis "
                                                       "at t = 0"])
    ctx.recs.append(Rec("Simulate", {"analysis_type": "STATIC"}, path, 1, "SIMULATE/STATIC",
                        "command", None, st.comments))
    ctx.recs.append(Rec("Stop", {}, path, 1, "STOP", "command"))


def read_adm(path: str, data: bytes, *, check: bool = True, ignore=()) -> tuple[DeckSpec, Ctx]:
    """A dataset with its own single static analysis (no command file)."""
    spec, ctx, _ = model_spec(path, data, ignore)
    no_command_file(ctx, path)
    return build(ctx, spec, check), ctx


def model_spec(path: str, data: bytes, ignore=()) -> tuple[DeckSpec, Ctx, str]:
    """(spec without elements, context with the model's records, title) of a dataset."""
    text = decode(data, path)
    spec = DeckSpec(path=path, sha256=hashlib.sha256(data).hexdigest())
    ctx = Ctx(path, ignore)
    title, stmts = statements(text, path, STATEMENTS, True, ctx.problems)
    translate(ctx, stmts)
    summarize(ctx, STATEMENTS)
    ctx.title = title
    ctx.statements = stmts
    return spec, ctx, title
