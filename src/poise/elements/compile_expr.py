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
from poise.elements.forces import FORCES
from poise.elements.reaction_feed import ReactionChannels
from poise.elements.registry import (ElementType, OutputGroup, expressions_of_time,
                                     not_conservative)
from poise.elements.requests import build_request_hook, computed_requests


def _is_null(v):
    return isinstance(v, Expr) and v.text.strip().upper() == "NULL"


def compile_expressions(spec, ctx):
    """Element compiler: expression forces, Post_Request hooks."""
    pc = ctx.pc
    ground = ctx.geometry.marker_on_ground

    # ------------------------------------------------------------ forces
    items = ctx.routed("expressions")
    res = ctx.resolver("force expressions", reactions=True)
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
        ctx.add_family(fam)
    if ctx.channels:
        _reaction_feed(ctx, built, pc)

    # ------------------------------------------------------------ requests
    reqs = computed_requests(spec.elements("Post_Request"), pc)
    if reqs:
        hook = build_request_hook(reqs, ctx, ctx.resolver("requests", reactions=True))
        if hook is not None:                        # outputs only: no family, no time source
            ctx.add_frame_hook(hook)


def _reaction_feed(ctx, built, pc):
    """Reject order-dependent reads of the expression families that read reaction channels
    (an element-force function of an expression force that itself reads reactions, or a
    resultant FX..TM that would include one) and register the :class:`ReactionChannels`."""
    readers, reading_els, reading_mk = [], set(), set()
    channels = ctx.channels
    for fam, its, _ in built:
        if fam.reads_reactions:
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
                    ch = channels[int(c)]
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
    ctx.set_reaction_channels(ReactionChannels(channels))


ELEMENTS = (ElementType(
    "expressions", ("Post_Request",), compile_expressions,
    rank=70, needs=("forces",),   # compiles the expression forces compile_forces routed here
    kernels=lambda: (XF.ExprVectorForce, XF.ExprScalarForce),
    tileable=lambda: (XF.ExprVectorForce, XF.ExprScalarForce),
    potential_energy=not_conservative, time_dependent=expressions_of_time,
    outputs=(FORCES, OutputGroup("requests", "R", "request", "request",
                                 "`Post_Request`", ("Post_Request",),
                                 ("id", "label", "type", "channel", "channel_units", "values",
                                  "message"), model_ids=False)),
    fd_tests="tests/kernels/test_expr_families.py"),)
