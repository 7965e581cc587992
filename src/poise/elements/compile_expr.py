"""Expressions in the model: expression forces and ``Post_Request`` outputs.

Expressions are compiled with the resolver on the compile context
(:class:`poise.elements.resolver.ModelResolver`). Reaction channels (element forces JOINT, BUSH,
... and resultants FX..TZ) are read exactly: in ``Post_Request`` from the converged multipliers,
inside expression forces at every ``Model.evaluate`` (:class:`poise.elements.reaction_feed.
ReactionFeed`, with exact Jacobian terms, docs/expressions.md). A force that
reads an expression force which itself reads reactions is a located DeckError; gravity
(elements/gravity.py) and Control_Diff expressions reject reaction functions.
"""
from __future__ import annotations

from poise.deck.spec import Expr
from poise.elements import expr_forces as XF
from poise.elements.channels import ExprInfo
from poise.elements.reaction_feed import ReactionFeed
from poise.elements.registry import ElementType, expressions_of_time, not_conservative
from poise.elements.requests import build_request_hook, computed_requests
from poise.elements.resolver import ground_markers


def _is_null(v):
    return isinstance(v, Expr) and v.text.strip().upper() == "NULL"


def compile_expressions(spec, ctx):
    """Element compiler: expression forces, Post_Request hooks."""
    pc = ctx.pc
    res = ctx.resolver()
    ground = ground_markers(ctx.b)

    # ------------------------------------------------------------ forces
    items = list(getattr(ctx, "expr_forces", []))
    res.where = "force expressions"
    res.allow_reactions = True
    vec = [(o, el) for o, el in items if el.tag.startswith("Force_Vector")]
    sca = [(o, el) for o, el in items if el.tag == "Force_Scalar_TwoBody"]
    built = []
    if vec:
        fam = XF.build_vector_family(vec, ctx, res, ground)
        if fam is not None:
            built.append((fam, vec, [f"{a}_expression" for a in XF.VEC_ATTRS]))
    if sca:
        fam = XF.build_scalar_family(sca, ctx, res, ground)
        if fam is not None:
            built.append((fam, sca, ["val_expression"]))
    for fam, _, _ in built:
        ctx.families.append(fam)
    res.allow_reactions = False
    if res.channels:
        _reaction_feed(ctx, res, built, pc)

    # ------------------------------------------------------------ requests
    reqs = computed_requests(spec.elements("Post_Request"), pc)
    if reqs:
        res.allow_reactions = True
        res.where = "requests"
        hook = build_request_hook(reqs, ctx, res)   # outputs only: no family, no time source
        if hook is not None:
            ctx.frame_hooks = getattr(ctx, "frame_hooks", []) + [hook]


def _reaction_feed(ctx, res, built, pc):
    """Mark the expression families that read reaction channels, reject order-dependent reads
    (an element-force function of an expression force that itself reads reactions, or a
    resultant FX..TM that would include one) and attach the :class:`ReactionFeed`."""
    readers, reading_els, reading_mk = [], set(), set()
    for fam, its, _ in built:
        reads = any(b.C and (b.reaction_index >= 0).any() for b in fam.batches)
        fam.reads_reactions = bool(reads)
        if reads:
            readers.append(fam)
            for k, (_, el) in enumerate(its):
                reading_els.add((el.tag, el.id))
                reading_mk.add((int(fam.markers[k, 0]), int(fam.markers[k, 1])))
    if not readers:
        return
    bad = False
    for fam, its, attrs in built:
        if not fam.reads_reactions:
            continue
        for b, attr in zip(fam.batches, attrs):
            if not b.C:
                continue
            for i, row in enumerate(b.reaction_index):
                for c in row:
                    if c < 0:
                        continue
                    ch = res.channels[int(c)]
                    if ch[0] == "EL":
                        cyc = (ch[2], ch[3]) in reading_els
                        what = f"<{ch[2]} id={ch[3]}>"
                    else:
                        mi, mj = ch[1], ch[2]
                        cyc = any((a == mi and (mj < 0 or bb == mj)) or
                                  (bb == mi and (mj < 0 or a == mj)) for a, bb in reading_mk)
                        what = "a resultant that includes it"
                    if cyc:
                        bad = True
                        pc.error(its[i][1].loc, f"reads the element force of {what}, an "
                                 "expression force that itself reads reactions (order-dependent "
                                 "or cyclic); expected reactions of joints, jprims, motions or "
                                 "forces that read no reaction", attr)
    if bad:
        return
    ctx.reaction_feed = ReactionFeed(res.channels, ExprInfo(res, ctx.outputs), readers)


ELEMENTS = (ElementType(
    "expressions", ("Post_Request",), compile_expressions,
    after=("forces", "field_beam"),   # compiles the expression forces compile_forces routed here
    kernels=lambda: (XF.ExprVectorForce, XF.ExprScalarForce),
    potential_energy=not_conservative, time_dependent=expressions_of_time,
    outputs={"forces": None, "requests": ("Post_Request",)},
    datasets=("id", "values", "message"), fd_tests="tests/kernels/test_expr_families.py"),)
