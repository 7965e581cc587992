"""Compile ``Control_Diff`` and implicit / user ``Reference_Variable`` into scalar unknowns.

Scalar unknowns are registered on demand (:func:`scalar_unknown`), either by the expression
resolver when an expression reads ``DIF(id)`` / ``VARVAL(id)`` or by :func:`compile_diff_vars`
(run after the expression compiler) for every remaining state, so expression forces compiled
earlier already know their scalar columns.

The static equations of each kind (deck_format 6.5, 6.1) and the outputs: :func:`compile_diff_vars`.
"""
from __future__ import annotations

import numpy as np

from poise.deck.spec import Expr
from poise.elements.diff_vars import ScalarEquation, build_scalar_equations
from poise.elements.registry import ElementType
from poise.elements.resolver import (compile_batch_located, ground_markers, held, is_user,
                                     scalar_unknown)
from poise.elements.compile_user import compile_user_variables


def compile_diff_vars(spec, ctx):
    """Element compiler (after the expression compiler): equations of the scalar unknowns.

    Statics (deck_format 6.5, 6.1):

    * ``Control_Diff`` (``type="EXPRESSION"``): unknown ``y`` seeded from ``ic``; equation
      ``expr(y, q, t) = 0`` (explicit ``y' = expr`` with ``y' = 0``) or ``expr(y, DIF1 = 0, q, t) = 0``
      (implicit). ``is_static_hold="TRUE"``: no unknown; ``DIF(id)`` is the constant ``ic`` (poise
      has no transient phase that could move a held state away from its initial value).
      ``DIF1(id)`` is 0 in statics.
    * implicit ``Reference_Variable``: unknown ``v`` seeded from ``ic`` (0), equation
      ``expr(v, q, t) = 0``; ``static_hold="TRUE"``: ``VARVAL(id)`` is the constant ``ic``.
    * ``Reference_Variable type="USERSUB"`` (Python VARSUB): unknown ``v`` with the equation
      ``v - varsub(...) = 0`` (families/user.py); ``static_hold``: constant ``ic``.

    Outputs: frame hook ``diffs/id`` (D,), ``diffs/value`` (F, D), ``variables/id`` (V,),
    ``variables/value`` (F, V) for every Control_Diff and every implicit / user variable (held ones
    report their constant).
    """
    diffs = spec.elements("Control_Diff")
    vars_ = [e for e in spec.elements("Reference_Variable")
             if e.attrs.get("is_implicit") or is_user(e)]
    if not diffs and not vars_:
        return
    pc = ctx.pc
    res = ctx.resolver()
    res.allow_reactions = False
    res.where = "Control_Diff / Reference_Variable expressions"
    ground = ground_markers(ctx.b)
    items = []             # (el, unknown, expression) with expression equations
    user_items = []
    for el in diffs:
        if held(el):
            ctx.effect("Control_Diff:static_hold")
            continue
        if is_user(el):
            pc.error(el.loc, "Control_Diff with a user subroutine (DIFSUB) is not supported; "
                     "expected type=\"EXPRESSION\" with expr", "type")
            continue
        k = scalar_unknown(ctx, "diff", el.id)
        ex = el.attrs.get("expr")
        if ex is None:
            pc.error(el.loc, "Control_Diff needs expr", "expr")
            continue
        items.append((el, k, ex if isinstance(ex, Expr) else float(ex)))
        ctx.effect("Control_Diff:" + ("implicit" if el.attrs.get("is_implicit") else "explicit"))
    for el in vars_:
        if held(el):
            ctx.effect("Reference_Variable:static_hold")
            continue
        k = scalar_unknown(ctx, "var", el.id)
        if is_user(el):
            user_items.append((el, k))
            ctx.effect("Reference_Variable:USERSUB")
            continue
        ex = el.attrs.get("expr")
        if ex is None:
            pc.error(el.loc, "implicit Reference_Variable needs expr (its residual)", "expr")
            continue
        items.append((el, k, ex if isinstance(ex, Expr) else float(ex)))
        ctx.effect("Reference_Variable:implicit")
    if items:
        batch = compile_batch_located([it[2] for it in items], res, pc)
        if batch is not None:
            fam = build_scalar_equations(batch, np.array([it[1] for it in items], int), ground,
                                         np.arange(len(items)), [it[0].loc for it in items])
            ctx.families.append(fam)
    if user_items:
        compile_user_variables(spec, ctx, user_items)
    ctx.frame_hooks.append(_output_hook(ctx, diffs, spec.elements("Reference_Variable")))


def _output_hook(ctx, diffs, all_vars):
    vars_ = [e for e in all_vars if e.attrs.get("is_implicit") or is_user(e)]

    def spec_of(kind, els):
        ids = np.array([e.id for e in els], np.int64)
        src = []
        for e in els:
            k = scalar_unknown(ctx, kind, e.id)
            src.append(k)
        return ids, src

    d_ids, d_src = spec_of("diff", diffs)
    v_ids, v_src = spec_of("var", vars_)

    def values(src, extra):
        return np.array([s[1] if isinstance(s, tuple) else float(extra[s]) for s in src], float)

    def hook(model, state):
        out = {}
        if len(d_ids):
            out["diffs/id"] = d_ids
            out["diffs/value"] = values(d_src, state.extra)
        if len(v_ids):
            out["variables/id"] = v_ids
            out["variables/value"] = values(v_src, state.extra)
        return out

    return hook


ELEMENTS = (ElementType(
    "diff_vars", ("Control_Diff", "Reference_Variable"), compile_diff_vars,
    after=("expressions", "contacts"),  # scalar unknowns the expressions registered come first
    kernels=lambda: (ScalarEquation,),
    outputs={"diffs": ("Control_Diff",), "variables": ("Reference_Variable",)},
    datasets=("id", "value"), fd_tests="tests/test_extra_unknowns.py"),)
