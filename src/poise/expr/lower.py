"""Semantic lowering: AST -> concrete IR (names resolved, VARVAL shared, constants folded).

The IR is a DAG of tuples (an explicit ``Reference_Variable`` is lowered once and every
``VARVAL`` of it refers to the same object): ``("c", value)``, ``("time",)``, ``("neg", a)``,
``("bin", op, a, b)`` (op in ``+ - * / ^``), ``("fn", NAME, (args...))``,
``("meas", NAME, ((marker_index, kind), ...), angle_key or None)``, ``("sc", scalar_index)``,
``("rx", reaction_channel)``, ``("spl", KIND, order, x, z, spline_table_index)``;
:func:`poise.expr.tape.extract` flattens it into a tape. A constant subtree that cannot be
folded (division by zero, overflow, a domain error) is a located problem, since it would fail
at every evaluation. Lowering runs on :func:`poise.expr.trampoline.run`, so neither deep nesting
nor long variable chains recurse in Python.
"""
from __future__ import annotations

import math

import numpy as np

from poise.core.errors import Problem

from .ast import BinOp, Call, Name, Num, Param, Unary
from .functions import ARITY, FUNCTIONS, DomainError
from .measures import CONTINUOUS, MEASURE_ARITY, MEASURE_SLOTS, VELOCITY_MEASURES
from .parser import parse
from .splines import SPLINE_KINDS, PreparedSpline
from .tokens import ExprSyntaxError, make_template
from .trampoline import run

__all__ = ["Lowering"]

CONSTANTS = {"PI": math.pi, "DTOR": math.pi / 180.0, "RTOD": 180.0 / math.pi}
REACTION_FUNCS = {"JOINT", "JPRIM", "MOTION", "MATE", "SFORCE", "VFORCE", "VTORQ", "GFORCE",
                  "BUSH", "SPDP", "BEAM", "FIELD", "PTCV", "CVCV"}
RESULTANT_FUNCS = {"FM": 1, "FX": 2, "FY": 3, "FZ": 4, "TM": 5, "TX": 6, "TY": 7, "TZ": 8}
_IMPURE = {"IMPACT", "BISTOP"}

#: MotionSolve functions poise does not evaluate, and why (a located error names the reason)
NOT_SUPPORTED = {
    "SWEEP": "a swept-sine excitation for dynamic analyses",
    "INVPSD": "a random excitation from a power spectral density (dynamic analyses)",
    "DELAY": "a time delay (it reads the solution's history, which statics has not)",
    "Q": "a flexible body's modal coordinate (poise has no flexible bodies)",
    "QDOT": "a flexible body's modal velocity (poise has no flexible bodies)",
    "QDDOT": "a flexible body's modal acceleration (poise has no flexible bodies)",
    "MODE": "the active mode of a linear analysis",
    "NFORCE": "the force of a Force_MultiPoint (not supported)",
    "SENVAL": "a sensor's value (sensors are not supported)",
    "CONTACT": "a Force_Contact's force (read contacts/force in the results instead)",
    "CURVE": "a Reference_ParamCurve evaluated in an expression",
    "INTERP": "interpolation of measured data (use AKISPL, CUBSPL, LINSPL or FITSPL)",
    "USER": "a compiled user function (poise runs Python user routines of elements with "
            "script_name only)",
}


def known_names() -> list:
    """Every function and constant name the language knows (for did-you-mean)."""
    return sorted({*ARITY, *MEASURE_SLOTS, *VELOCITY_MEASURES, *REACTION_FUNCS,
                   *RESULTANT_FUNCS, *SPLINE_KINDS, "FRICTION", "VARVAL", "DIF", "DIF1",
                   "ARYVAL", "PINVAL", "POUVAL"})


def unknown_function(name: str) -> str:
    """The message for a call of a function poise does not evaluate."""
    if name in NOT_SUPPORTED:
        return f"{name} is a MotionSolve function poise does not evaluate: {NOT_SUPPORTED[name]}"
    import difflib
    close = difflib.get_close_matches(name, known_names(), n=3, cutoff=0.6)
    hint = f"; did you mean {' or '.join(close)}?" if close else ""
    return f"unknown function {name!r}{hint}"
_BINOPS = {"+": "+", "-": "-", "*": "*", "/": "/", "**": "^"}


class _Fail(Exception):
    """Internal: a located problem was recorded; abandon the current subtree."""


_OVERFLOW = "constant sub-expression is not a finite number (overflow)"


def fold_bin(op, a, b):
    """Fold a binary operation on two floats: ``(value, None)`` or ``(None, why)``."""
    with np.errstate(all="ignore"):
        if op == "+":
            v = a + b
        elif op == "-":
            v = a - b
        elif op == "*":
            v = a * b
        elif op == "/":
            if b == 0:
                return None, "division by zero in a constant sub-expression"
            v = a / b
        else:
            if a < 0 and b != math.trunc(b):
                return None, "negative number raised to a non-integer power"
            if a == 0 and b < 0:
                return None, "division by zero (0 raised to a negative power)"
            v = float(np.power(a, b))
    return (v, None) if math.isfinite(v) else (None, _OVERFLOW)


def _fold_fn(name, vals):
    """Fold a pure function of constants: ``(value, None)`` or ``(None, why)``."""
    try:
        with np.errstate(all="ignore"):
            v, _ = FUNCTIONS[name]([np.array([x]) for x in vals], [False] * len(vals))
    except DomainError as e:
        return None, f"{e.message} (constant arguments)"
    v = float(v[0])
    return (v, None) if math.isfinite(v) else (None, _OVERFLOW)


class Lowering:
    """Lowers expressions of one batch (shared caches for variables and splines).

    Every node method is a generator: a sub-lowering is ``(yield self.lower(node))`` and
    :func:`~poise.expr.trampoline.run` drives the chain (no Python recursion).

    Parameters
    ----------
    resolver : Resolver
        Model-side name resolution (see CONTRACT.md).
    """

    def __init__(self, resolver):
        self.resolver = resolver
        self.problems: list[Problem] = []
        self.var_problems: list[Problem] = []   # problems inside inlined variables
        self.var_cache: dict = {}
        self.var_stack: list = []
        self.spline_index: dict = {}
        self.splines: list[PreparedSpline] = []
        self._ctx = None          # (loc, attr) of the text being lowered
        self.nums: list = []      # numbers of the template being lowered

    # -- errors ----------------------------------------------------------------------------
    def error(self, col, message):
        loc, attr = self._ctx
        self.problems.append(Problem(loc, message, f"{attr} col {col}" if col else attr))
        raise _Fail

    # -- entry -----------------------------------------------------------------------------
    def lower_expr(self, expr):
        """Lower one ``Expr`` (or float) to concrete IR; None if a problem was recorded."""
        if not hasattr(expr, "text"):
            return ("c", float(expr))
        return run(self._lower_text(expr.text, expr.loc, expr.attr))

    def _lower_text(self, text, loc, attr):
        saved = self._ctx, self.nums, self.problems
        self._ctx = (loc, attr)
        try:
            node = None
            if "#" not in text:
                try:
                    tmpl, self.nums = make_template(text)
                    node = parse(tmpl, True)
                except ExprSyntaxError:
                    node = None
            if node is not None:
                # fast path: cached template parse; on any problem redo it from the original
                # text so that reported columns are exact
                self.problems = []
                try:
                    return (yield self.lower(node))
                except _Fail:
                    pass
                finally:
                    self.problems = saved[2]
            try:
                node = parse(text)
            except ExprSyntaxError as e:
                self.error(e.col, e.message)
            return (yield self.lower(node))
        except _Fail:
            return None
        finally:
            self._ctx, self.nums = saved[0], saved[1]

    # -- nodes -----------------------------------------------------------------------------
    def _leaf(self, node):
        """IR of a leaf node (number, parameter, name) without a sub-generator; else None."""
        t = node.__class__
        if t is Param:
            return ("c", self.nums[node.index])
        if t is Num:
            return ("c", node.value)
        if t is Unary:
            a = node.arg.__class__
            if a is Num or a is Param:
                v = node.arg.value if a is Num else self.nums[node.arg.index]
                return ("c", -v if node.op == "-" else v)
            return None
        if t is Name:
            if node.name == "TIME":
                return ("time",)
            if node.name in CONSTANTS:
                return ("c", CONSTANTS[node.name])
            symbol = getattr(self.resolver, "symbol", None)       # optional (CONTRACT.md)
            if symbol is not None:
                try:
                    return ("sc", int(symbol(node.name)))
                except KeyError:
                    pass
            self.error(node.col, f"unknown name {node.name!r}")
        return None

    def _sub(self, node):
        """Generator lowering a non-leaf node (a call directly, without a ``lower`` level)."""
        return self.call(node) if node.__class__ is Call else self.lower(node)

    def lower(self, node):
        leaf = self._leaf(node)
        if leaf is not None:
            return leaf
        if isinstance(node, BinOp):
            a = self._leaf(node.left)
            if a is None:
                a = yield self._sub(node.left)
            b = self._leaf(node.right)
            if b is None:
                b = yield self._sub(node.right)
            op = _BINOPS[node.op]
            if a[0] == "c" and b[0] == "c":
                v, why = fold_bin(op, a[1], b[1])
                if why is not None:
                    self.error(node.col, why)
                return ("c", v)
            return ("bin", op, a, b)
        if isinstance(node, Unary):
            a = self._leaf(node.arg)
            if a is None:
                a = yield self._sub(node.arg)
            if node.op == "+":
                return a
            return ("c", -a[1]) if a[0] == "c" else ("neg", a)
        if isinstance(node, Call):
            return (yield self.call(node))
        raise TypeError(node)  # pragma: no cover

    def _arity(self, node, lo, hi):
        n = len(node.args)
        if not lo <= n <= hi:
            want = f"{lo}" if lo == hi else (f"{lo}..{hi}" if hi < 99 else f"at least {lo}")
            self.error(node.col, f"{node.name} takes {want} arguments, got {n}")

    def int_arg(self, node, i, default=0):
        """Integer constant argument ``i`` of a call (``default`` when omitted)."""
        if i >= len(node.args):
            return default
        ir = self._leaf(node.args[i])
        if ir is None:
            ir = yield self.lower(node.args[i])
        return self._int_value(node, i, ir)

    def _int_value(self, node, i, ir):
        if ir[0] != "c" or ir[1] != math.trunc(ir[1]):
            self.error(node.args[i].col, f"{node.name} argument {i + 1} must be an integer "
                       "constant")
        return int(ir[1])

    def _int_fast(self, node, i, default=0):
        """``int_arg`` without a sub-generator when the argument is a leaf; else None."""
        if i >= len(node.args):
            return default
        ir = self._leaf(node.args[i])
        return None if ir is None else self._int_value(node, i, ir)

    def _marker_index(self, node, i, mid):
        try:
            return int(self.resolver.marker_index(mid))
        except KeyError:
            if mid == 0:          # global frame (contract: maps to -1)
                return -1
            self.error(node.args[i].col, f"unknown marker id {mid}")

    def marker(self, node, i):
        mid = self._int_fast(node, i)
        if mid is None:
            mid = yield self.int_arg(node, i)
        return self._marker_index(node, i, mid)

    def call(self, node):
        name = node.name
        if name in ARITY:
            self._arity(node, *ARITY[name])
            args = []
            for a in node.args:
                ir = self._leaf(a)
                args.append(ir if ir is not None else (yield self._sub(a)))
            if name in ("MAX", "MIN") and len(args) > 2:
                acc = args[0]
                for b in args[1:]:
                    acc = self._fn(node, [acc, b])
                return acc
            return self._fn(node, args)
        if name in MEASURE_SLOTS:
            self._arity(node, *MEASURE_ARITY[name])
            ids = []
            for i in range(3):
                mid = self._int_fast(node, i)
                if mid is None:
                    mid = yield self.int_arg(node, i)
                ids.append(self._marker_index(node, i, mid))
            slots = tuple((ids[w], kind) for w, kind in MEASURE_SLOTS[name])
            key = None
            if name in CONTINUOUS:
                key = int(self.resolver.angle_key(ids[0], ids[1], CONTINUOUS[name]))
            return ("meas", name, slots, key)
        if name in VELOCITY_MEASURES:
            self._arity(node, *VELOCITY_MEASURES[name])
            for i in range(len(node.args)):
                yield self.marker(node, i)
            return ("c", 0.0)
        if name in REACTION_FUNCS or name in RESULTANT_FUNCS or name == "FRICTION":
            return (yield self.reaction(node))
        if name in SPLINE_KINDS:
            return (yield self.spline(node))
        if name in ("VARVAL", "DIF", "DIF1"):
            self._arity(node, 1, 1)
            vid = self._int_fast(node, 0)
            if vid is None:
                vid = yield self.int_arg(node, 0)
            return (yield self.state(node, vid))
        if name in ("PINVAL", "POUVAL"):
            return (yield self.plant(node))
        if name == "ARYVAL":
            self._arity(node, 2, 2)
            aid, k = (yield self.int_arg(node, 0)), (yield self.int_arg(node, 1))
            try:
                vals = np.asarray(self.resolver.array(aid), dtype=float).ravel()
            except KeyError:
                self.error(node.args[0].col, f"unknown Reference_Array id {aid}")
            if not 1 <= k <= len(vals):
                self.error(node.args[1].col, f"ARYVAL index {k} outside 1..{len(vals)}")
            v = float(vals[k - 1])
            if not math.isfinite(v):
                self.error(node.col, f"Reference_Array id {aid} value {k} is not finite")
            return ("c", v)
        self.error(node.col, unknown_function(name))

    def plant(self, node):
        """``PINVAL(id, k)`` / ``POUVAL(id, k)``: the k-th variable of a Control_PlantInput /
        Control_PlantOutput (``variable_id_list``), i.e. ``VARVAL`` of that variable."""
        self._arity(node, 2, 2)
        pid, k = (yield self.int_arg(node, 0)), (yield self.int_arg(node, 1))
        what = "Control_PlantInput" if node.name == "PINVAL" else "Control_PlantOutput"
        fn = getattr(self.resolver, "plant_variables", None)
        try:
            if fn is None:
                raise KeyError(pid)
            ids = list(fn(what, pid))
        except KeyError:
            self.error(node.args[0].col, f"unknown {what} id {pid}")
        if not 1 <= k <= len(ids):
            self.error(node.args[1].col, f"{node.name} index {k} outside 1..{len(ids)} "
                       f"({what} id {pid} lists {len(ids)} variables)")
        return (yield self.state(node, int(ids[k - 1]), "VARVAL"))

    def _fn(self, node, args):
        name = node.name
        if name not in _IMPURE and all(a[0] == "c" for a in args):
            v, why = _fold_fn(name, [a[1] for a in args])
            if why is not None:
                self.error(node.col, f"{name}: {why}")
            return ("c", v)
        return ("fn", name, tuple(args))

    def reaction(self, node):
        name = node.name
        if name in RESULTANT_FUNCS:
            self._arity(node, 1, 3)
            i = yield self.int_arg(node, 0)
            j = yield self.int_arg(node, 1)
            k = yield self.int_arg(node, 2)
            call = (name, i, j, RESULTANT_FUNCS[name], k)
        elif name == "FRICTION":
            self._arity(node, 2, 3)
            call = (name, (yield self.int_arg(node, 0)), 0, (yield self.int_arg(node, 1)),
                    (yield self.int_arg(node, 2)))
        else:
            self._arity(node, 3, 4)
            call = (name,)
            for n in range(4):
                call += ((yield self.int_arg(node, n)),)
        try:
            ch = self.resolver.reaction(*call)
        except NotImplementedError as e:
            self.error(node.col, str(e) or f"{name} is not supported")
        except KeyError:
            self.error(node.col, f"{name}: unknown element id {call[1]}")
        return ("rx", int(ch))

    def spline(self, node):
        self._arity(node, 3, 4)
        x = yield self.lower(node.args[0])
        z = yield self.lower(node.args[1])
        sid = yield self.int_arg(node, 2)
        order = yield self.int_arg(node, 3)
        if not 0 <= order <= 2:
            self.error(node.args[3].col, f"{node.name} derivative order must be 0, 1 or 2")
        key = (node.name, sid)
        if key not in self.spline_index:
            try:
                xs, ys, zs, lin = self.resolver.spline(sid)
            except KeyError:
                self.error(node.args[2].col, f"unknown Reference_Spline id {sid}")
            try:
                sp = PreparedSpline(node.name, xs, ys, zs, lin)
            except ValueError as e:
                self.error(node.args[2].col, f"Reference_Spline id {sid}: {e}")
            self.spline_index[key] = len(self.splines)
            self.splines.append(sp)
        return ("spl", node.name, order, x, z, self.spline_index[key])

    def state(self, node, vid, name=None):
        r = self.resolver
        name = name or node.name
        try:
            if name == "DIF":
                k = r.diff_state(vid)
                if isinstance(k, tuple):           # ("const", value): statically held state
                    v = float(k[1])
                    if not math.isfinite(v):
                        self.error(node.col, f"Control_Diff id {vid} value is not finite")
                    return ("c", v)
                return ("sc", int(k))
            if name == "DIF1":
                k = r.diff_derivative(vid)
                return ("c", 0.0) if k is None else ("sc", int(k))
            kind, val = r.variable(vid)
        except KeyError:
            what = "Reference_Variable" if name == "VARVAL" else "Control_Diff"
            self.error(node.args[0].col, f"unknown {what} id {vid}")
        if kind == "implicit":
            return ("sc", int(val))
        if vid in self.var_stack:
            chain = " -> ".join(str(v) for v in self.var_stack + [vid])
            self.error(node.col, f"recursive VARVAL: {chain}")
        if vid not in self.var_cache:
            if not hasattr(val, "text"):
                v = float(val)
                self.var_cache[vid] = ("c", v) if math.isfinite(v) else None
            else:
                self.var_stack.append(vid)
                outer, self.problems = self.problems, self.var_problems
                try:
                    self.var_cache[vid] = yield self._lower_text(val.text, val.loc, val.attr)
                finally:
                    self.var_stack.pop()
                    self.problems = outer
        ir = self.var_cache[vid]
        if ir is None:
            self.error(node.col, f"Reference_Variable id {vid} is invalid")
        return ir


def known_function(name: str) -> bool:
    """Whether the expression language computes function ``name`` (case-insensitive): the
    dispatch of :meth:`Lowering.call`, read from its tables (an Adams request naming a function
    poise does not compute, such as ORIENT, can then be told apart before compiling)."""
    n = name.upper()
    return (n in ARITY or n in MEASURE_SLOTS or n in VELOCITY_MEASURES or n in REACTION_FUNCS
            or n in RESULTANT_FUNCS or n in SPLINE_KINDS
            or n in ("FRICTION", "VARVAL", "DIF", "DIF1", "ARYVAL", "IF"))

