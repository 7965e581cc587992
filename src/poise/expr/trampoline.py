"""Run recursive generator code without Python recursion.

The parser and the lowering are written as ordinary recursive descent, except that a recursive
call ``f(x)`` is spelled ``(yield f(x))``: the generator hands the sub-generator to :func:`run`,
which keeps the call chain on a heap stack. Nesting depth (parentheses, long operator chains,
chains of ``Reference_Variable``) is therefore bounded by memory, not by the interpreter's
recursion limit. Exceptions propagate up the chain exactly as in plain recursion (``try``/
``finally`` in the generators run as usual).
"""
from __future__ import annotations

__all__ = ["run"]


def run(gen):
    """Drive ``gen`` (and every generator it yields) to completion; return its value."""
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
