"""Run recursive generator code without deep Python recursion.

The parser and the lowering are written as ordinary recursive descent, except that a recursive
call ``f(x)`` is spelled ``(yield f(x))`` and :func:`run` performs it. The first
``MAX_RECURSION`` levels run as plain (fast) recursion; deeper sub-calls continue on a heap stack,
so nesting depth (parentheses, long operator chains, chains of ``Reference_Variable``) is bounded
by memory, not by the interpreter's recursion limit. Exceptions propagate up the chain exactly
as in plain recursion (``try``/``finally`` in the generators run as usual).
"""
from __future__ import annotations

__all__ = ["run"]

MAX_RECURSION = 100       # levels of plain recursion (two Python frames each) before the heap


def run(gen, depth: int = 0):
    """Drive ``gen`` (and every generator it yields) to completion; return its value."""
    if depth >= MAX_RECURSION:
        return _run_heap(gen)
    send = exc = None
    while True:
        try:
            req = gen.send(send) if exc is None else gen.throw(exc)
        except StopIteration as s:
            return s.value
        try:
            send, exc = run(req, depth + 1), None
        except Exception as e:
            send, exc = None, e


def _run_heap(gen):
    stack = [gen]
    push, pop = stack.append, stack.pop
    send = None
    exc = None
    while True:
        g = stack[-1]
        try:
            if exc is None:
                req = g.send(send)
            else:
                e, exc = exc, None
                req = g.throw(e)
        except StopIteration as s:
            pop()
            if not stack:
                return s.value
            send = s.value
            continue
        except Exception as e:
            pop()
            if not stack:
                raise
            send, exc = None, e
            continue
        push(req)
        send = None
