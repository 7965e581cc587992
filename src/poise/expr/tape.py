"""Tapes: concrete IR (:mod:`poise.expr.lower`) -> structural key + per-instance data.

:func:`extract` replaces the concrete data by local numbers (constants -> parameter numbers,
slots/scalars/reactions deduplicated per expression) and flattens the DAG into a *tape* of
instructions in evaluation order (shared nodes once): the hashable *structural key*; equal keys
are evaluated together as one vectorised group (:mod:`poise.expr.batch`). Kept apart from the
lowering because it knows nothing of names, the resolver or folding: only the IR's shape.
"""
from __future__ import annotations

__all__ = ["extract", "Instance"]


class Instance:
    """Per-instance data of one lowered expression (see :func:`extract`)."""

    __slots__ = ("params", "slots", "scalars", "reactions", "angles", "splines")

    def __init__(self):
        self.params: list = []
        self.slots: list = []
        self.scalars: list = []
        self.reactions: list = []
        self.angles: list = []
        self.splines: list = []


_MERGED = frozenset(("time", "meas", "sc", "rx"))     # equal leaves: one instruction


def _children(n):
    tag = n[0]
    if tag == "bin":
        return (n[2], n[3])
    if tag == "neg":
        return (n[1],)
    if tag == "fn":
        return n[2]
    if tag == "spl":
        return (n[3], n[4])
    return ()


def extract(ir):
    """Split concrete IR into a structural key (a tape) and per-instance data.

    The DAG is walked once per node object (a variable used many times is evaluated once;
    recursion near the root, a heap stack below any depth); equal state leaves (the same
    measure of the same slots, TIME, a scalar, a channel) are also merged. Instructions refer
    to earlier ones by position; the last one is the result.

    Returns
    -------
    key : tuple of tuple
        Hashable tape: ``("c", p)``, ``("time",)``, ``("neg", i)``, ``("bin", op, i, j)``,
        ``("fn", NAME, (i, ...))``, ``("meas", NAME, (slot, ...), angle)``, ``("sc", k)``,
        ``("rx", k)``, ``("spl", KIND, order, i, j, s)`` with local numbers.
    inst : Instance
        Parameter values, slot ``(marker, kind)`` pairs, scalar/reaction indices, angle keys and
        spline table indices, in the order the key refers to them.
    """
    inst = Instance()
    slot_map, sc_map, rx_map = {}, {}, {}
    ops: list = []
    cse: dict = {}
    memo: dict = {}           # id(IR node) -> tape position

    def local(mapping, lst, v):
        if v not in mapping:
            mapping[v] = len(lst)
            lst.append(v)
        return mapping[v]

    def emit(n):
        """Tape position of node ``n`` whose operands are all in ``memo``."""
        tag = n[0]
        if tag == "c":                            # always a new instruction
            inst.params.append(n[1])
            k = memo[id(n)] = len(ops)
            ops.append(("c", len(inst.params) - 1))
            return k
        if tag == "time":
            op = n
        elif tag == "neg":
            op = ("neg", memo[id(n[1])])
        elif tag == "bin":
            op = ("bin", n[1], memo[id(n[2])], memo[id(n[3])])
        elif tag == "fn":
            op = ("fn", n[1], tuple(memo[id(a)] for a in n[2]))
        elif tag == "meas":
            loc = []
            for s in n[2]:
                if s[0] < 0:                      # global frame: never shared
                    inst.slots.append(s)
                    loc.append(len(inst.slots) - 1)
                else:
                    loc.append(local(slot_map, inst.slots, s))
            a = -1
            if n[3] is not None:
                inst.angles.append(n[3])
                a = len(inst.angles) - 1
            op = ("meas", n[1], tuple(loc), a)
        elif tag == "sc":
            op = ("sc", local(sc_map, inst.scalars, n[1]))
        elif tag == "rx":
            op = ("rx", local(rx_map, inst.reactions, n[1]))
        elif tag == "spl":
            inst.splines.append(n[5])
            op = ("spl", n[1], n[2], memo[id(n[3])], memo[id(n[4])], len(inst.splines) - 1)
        else:
            raise ValueError(tag)  # pragma: no cover
        if tag in _MERGED:
            k = cse.get(op)
            if k is None:
                k = cse[op] = len(ops)
                ops.append(op)
        else:
            k = len(ops)
            ops.append(op)
        memo[id(n)] = k
        return k

    def walk(n, depth):
        """Post-order, left to right: plain recursion near the root, a heap stack below."""
        if depth > 200:
            return walk_heap(n)
        tag = n[0]
        if tag == "c":
            inst.params.append(n[1])
            k = memo[id(n)] = len(ops)
            ops.append(("c", len(inst.params) - 1))
            return k
        if tag == "bin":                          # the common case, inline
            a, b = n[2], n[3]
            ia = memo.get(id(a))
            if ia is None:
                ia = walk(a, depth + 1)
            ib = memo.get(id(b))
            if ib is None:
                ib = walk(b, depth + 1)
            k = memo[id(n)] = len(ops)
            ops.append(("bin", n[1], ia, ib))
            return k
        for c in _children(n):
            if id(c) not in memo:
                walk(c, depth + 1)
        return emit(n)

    def walk_heap(root):
        stack = [root]
        while stack:
            n = stack[-1]
            if id(n) in memo:
                stack.pop()
                continue
            pending = [c for c in _children(n) if id(c) not in memo]
            if pending:
                stack.extend(reversed(pending))
                continue
            stack.pop()
            emit(n)
        return memo[id(root)]

    walk(ir, 0)
    assert memo[id(ir)] == len(ops) - 1
    return tuple(ops), inst
