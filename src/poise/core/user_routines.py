"""Python user routines (UCOSUB / SFOSUB / GFOSUB / VARSUB style).

A deck element names a Python function through ``script_name`` (a ``.py`` file, relative to the
deck's directory), ``usrsub_fnc_name`` (default ``ucosub`` / ``sfosub`` / ``gfosub`` /
``varsub`` by element) and ``usrsub_param_string="USER(p1, p2, ...)"``; ``interpreter`` must be
``PYTHON`` when given. The file is imported once per compile with ``importlib`` under a unique
module name (``poise_user_<hash of the path>``); ``sys.path`` is not changed.

Decks come from anywhere (CI runs decks nobody read), so deck code runs only when the caller
allows it (:data:`RUN`: ``--allow-user-code`` / ``allow_user_code=True``); otherwise a deck that
names a script is a located deck error (:data:`REFUSE`) and ``poise check`` validates the
reference without importing anything (:data:`SKIP`). Whatever the mode, ``script_name`` must
stay inside the deck's directory tree: absolute paths, ``..`` components and symlinks that
resolve outside are refused. The user code's stdout goes to stderr (``--json`` stays strict).

Calling convention (all elements)::

    def fn(id, time, par, q):
        ...
        return value                    # or (value, derivatives)

* ``id`` the element id, ``time`` the analysis time, ``par`` the tuple of floats of
  ``USER(...)``, ``q`` a :class:`MarkerAccess` (marker states by deck marker id, 0 = global
  frame): ``q.P(i)`` origin, ``q.x(i)``, ``q.y(i)``, ``q.z(i)`` axes, ``q.A(i)`` axes as columns
  (all global, deck units), and the measures ``q.dx(i, j=0, k=0)``, ``q.dy``, ``q.dz``
  (components of ``P_i - P_j`` along k's axes), ``q.dm(i, j=0)``, ``q.ax/ay/az(i, j=0)``
  (principal angles in (-pi, pi]).
* ``value``: ``Constraint_UserConstr`` one or more constraint values (``Phi = 0``);
  ``Force_Scalar_TwoBody`` the force / torque magnitude (same sign conventions as ``val``);
  ``Force_Vector_*`` 6 components ``fx fy fz tx ty tz`` (or 3 for FORCEONLY / TORQUEONLY) along
  ``ref_marker_id``'s axes; ``Reference_Variable`` the variable's value.
* ``derivatives`` (optional): ``{(marker_id, "P" | "x" | "y" | "z"): array (m, 3)}``, the
  partial derivatives of the m values w.r.t. the global vectors the function read (axis columns
  treated as independent vectors; ``(3,)`` allowed when m = 1). Missing entries are zero. Without
  derivatives poise uses **central finite differences** over every vector the function read
  (step ``1e-6 L`` for origins, ``1e-6`` for axes); constraint Hessians (the geometric stiffness
  ``sum lam_r d2 Phi_r / dy2``) are always central differences of the gradient (step ``1e-4 L``
  / ``1e-4`` when the gradient itself comes from finite differences, else ``1e-6``).
* The set of marker vectors a function reads is recorded at a first call at the input
  configuration; it must not change later (a read of a new vector fails the solve).
* A user function that raises (anything, also ``SystemExit`` / ``KeyboardInterrupt``) or returns
  NaN/Inf fails the solve (exit 1, results written) with a message naming the element, the
  function and the file. A missing file or function, an import error (again anything raised,
  ``SystemExit(0)`` included), ``interpreter`` other than PYTHON and DLL routines
  (``usrsub_dll_name`` without a Python script) are located deck errors (exit 3).
"""
from __future__ import annotations

import functools
import hashlib
import importlib.util
import re
import sys
from pathlib import Path

import numpy as np

from poise.core.errors import DeckError, EvaluationError, Problem
from poise.core.interrupts import kept_interrupts

DEFAULT_NAMES = {"Constraint_UserConstr": "ucosub", "Force_Scalar_TwoBody": "sfosub",
                 "Force_Vector_OneBody": "gfosub", "Force_Vector_TwoBody": "gfosub",
                 "Reference_Variable": "varsub"}
KIND_NAMES = ("P", "x", "y", "z")
USR_ATTRS = ("usrsub_param_string", "usrsub_fnc_name", "script_name", "usrsub_dll_name")


def uses_user_routine(el) -> bool:
    """True when an element is given by a user subroutine rather than by values/expressions."""
    if str(el.attrs.get("type", "")).upper() == "USERSUB":
        return True
    return any(el.attrs.get(a) for a in USR_ATTRS)


def parse_par(text) -> tuple:
    """``"USER(1, 2.5, -3e-1)"`` -> ``(1.0, 2.5, -0.3)`` (the ``USER( )`` wrapper optional)."""
    if text is None:
        return ()
    s = str(text).strip()
    m = re.fullmatch(r"(?is)\s*USER\s*\((.*)\)\s*", s)
    if m:
        s = m.group(1)
    s = s.strip()
    if not s:
        return ()
    return tuple(float(t.replace("D", "E").replace("d", "e")) for t in re.split(r"[\s,]+", s) if t)


#: user-code modes of :func:`load` (``compile_model(spec, user_code=...)``)
RUN, REFUSE, SKIP = "run", "refuse", "skip"

ALLOW_HINT = ("poise runs code named by a deck only when allowed: pass --allow-user-code "
              "(allow_user_code=True in the Python API)")

_MODULES: dict = {}


class _UserStdout:
    """User code's ``print`` goes to stderr: stdout is poise's (strict JSON under ``--json``)."""

    def __enter__(self):
        self._old = sys.stdout
        sys.stdout = sys.stderr

    def __exit__(self, *exc):
        sys.stdout = self._old
        return False


def _import(path: Path, data: bytes, digest: str):
    """The module of the script bytes ``data`` (the bytes hashed are the bytes run)."""
    key = (str(path), digest)
    if key in _MODULES:
        return _MODULES[key]
    name = "poise_user_" + hashlib.sha1(str(path).encode()).hexdigest()[:12]
    spec = importlib.util.spec_from_file_location(name, str(path))
    mod = importlib.util.module_from_spec(spec)
    with kept_interrupts(), _UserStdout():
        exec(compile(data, str(path), "exec"), mod.__dict__)  # noqa: S102 - allowed user code
    _MODULES[key] = mod
    return mod


def deck_dir(el) -> Path:
    """The directory a deck's scripts are resolved in (the current one for in-memory decks)."""
    f = el.loc.file
    return Path(f).resolve().parent if f and f[0] != "<" else Path.cwd().resolve()


def script_path(el) -> Path:
    """``script_name`` resolved inside the deck's directory tree; DeckError when it is absolute,
    has a ``..`` component, resolves (through symlinks) outside that tree or is not a file.
    Nothing is read or executed."""
    script = str(el.attrs.get("script_name"))
    base = deck_dir(el)
    rel = Path(script)
    if rel.is_absolute() or script.startswith(("/", "\\")) \
            or ".." in Path(script.replace("\\", "/")).parts:
        raise DeckError(Problem(el.loc, f"{script!r} leaves the deck's directory (an absolute "
                                "path or '..'; refused, also with --allow-user-code); expected "
                                f"a script inside the deck's directory tree {base}",
                                "script_name"))
    try:
        path = (base / rel).resolve()
    except (OSError, ValueError, RuntimeError) as e:     # NUL byte, symlink loop, ...
        raise DeckError(Problem(el.loc, f"{script!r} is not a usable path ({e}); "
                                "expected a .py file inside the deck's directory",
                                "script_name")) from None
    if not path.is_relative_to(base):
        raise DeckError(Problem(el.loc, f"{script!r} resolves to {path}, outside the deck's "
                                "directory tree (through a symlink; refused, also with "
                                f"--allow-user-code); expected a script inside {base}",
                                "script_name"))
    if not path.is_file():
        raise DeckError(Problem(el.loc, f"user script {path} not found (script_name is "
                                "relative to the deck's directory)", "script_name"))
    return path


def function_name(el) -> str:
    return str(el.attrs.get("usrsub_fnc_name") or DEFAULT_NAMES.get(el.tag, "usrsub"))


def describe(el) -> dict:
    """What ``poise check`` reports of a user-routine element (nothing is imported)."""
    return dict(tag=el.tag, id=el.id, script=str(el.attrs.get("script_name")),
                function=function_name(el), line=el.loc.line)


def load(el, mode: str = REFUSE):
    """(function, path, par, sha256 of the script) of an element's Python user routine.

    ``mode``: :data:`RUN` imports the script; :data:`REFUSE` raises a located DeckError saying
    how to allow it; :data:`SKIP` checks the reference and returns ``None`` (nothing runs).
    DeckError when unusable (see the module doc)."""
    a = el.attrs
    script, dll = a.get("script_name"), a.get("usrsub_dll_name")
    interp = a.get("interpreter")
    if not script:
        if dll:
            raise DeckError(Problem(el.loc, f"DLL user subroutines ({dll}) are not supported; "
                                    "expected a Python routine (script_name=\"file.py\" "
                                    "interpreter=\"PYTHON\")", "usrsub_dll_name"))
        raise DeckError(Problem(el.loc, "user subroutine without script_name; expected "
                                "script_name=\"file.py\" (Python, next to the deck)",
                                "script_name"))
    if interp is not None and str(interp).strip().upper() != "PYTHON":
        raise DeckError(Problem(el.loc, f"interpreter {interp!r} is not supported; expected "
                                "PYTHON", "interpreter"))
    path = script_path(el)
    fname = function_name(el)
    try:
        par = parse_par(a.get("usrsub_param_string"))
    except ValueError:
        raise DeckError(Problem(el.loc, "usrsub_param_string: expected USER(number, ...)",
                                "usrsub_param_string")) from None
    if mode == SKIP:
        return None
    if mode != RUN:
        raise DeckError(Problem(el.loc, f"names the Python user routine {fname!r} in {path}; "
                                f"{ALLOW_HINT}", "script_name"))
    try:
        data = path.read_bytes()
    except OSError as e:
        raise DeckError(Problem(el.loc, f"cannot read user script {path}: {e.strerror or e}",
                                "script_name")) from None
    digest = hashlib.sha256(data).hexdigest()
    try:
        mod = _import(path, data, digest)
    except BaseException as e:  # noqa: BLE001 - SystemExit/KeyboardInterrupt too: never exit 0
        raise DeckError(Problem(el.loc, f"importing user script {path} (for routine "
                                f"{fname!r}) failed: {_raised(e)}", "script_name")) from None
    fn = getattr(mod, fname, None)
    if not callable(fn):
        raise DeckError(Problem(el.loc, f"user script {path} has no function {fname!r}",
                                "usrsub_fnc_name"))
    return fn, path, par, digest


def _raised(e: BaseException) -> str:
    """One line naming what user code raised (``SystemExit(0)`` included)."""
    if isinstance(e, SystemExit):
        return f"it raised SystemExit({e.code!r})"
    text = " ".join(str(e).split())
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


class _NewSlot(Exception):
    pass


class MarkerAccess:
    """Marker states handed to user functions (see the module doc)."""

    def __init__(self, time, vec, marker_index, record=None):
        self.time = float(time)
        self._vec = vec                      # (marker_id, kind) -> (3,) array
        self._mi = marker_index
        self._rec = record                   # set: record reads (first call), None: strict

    def _get(self, mid, kind):
        mid = int(mid)
        if mid == 0:
            return np.zeros(3) if kind == 0 else np.eye(3)[:, kind - 1]
        if mid not in self._mi:
            raise KeyError(f"marker {mid} does not exist")
        key = (mid, kind)
        if self._rec is not None:
            self._rec.add(key)
        elif key not in self._vec:
            raise _NewSlot(key)
        return np.array(self._vec[key], float)

    def P(self, i):
        return self._get(i, 0)

    pos = P

    def x(self, i):
        return self._get(i, 1)

    def y(self, i):
        return self._get(i, 2)

    def z(self, i):
        return self._get(i, 3)

    def A(self, i):
        return np.stack([self.x(i), self.y(i), self.z(i)], axis=1)

    def _d(self, i, j, k, c):
        d = self.P(i) - self.P(j)
        return float(d @ (np.eye(3)[:, c] if int(k) == 0 else self._get(k, c + 1)))

    def dx(self, i, j=0, k=0):
        return self._d(i, j, k, 0)

    def dy(self, i, j=0, k=0):
        return self._d(i, j, k, 1)

    def dz(self, i, j=0, k=0):
        return self._d(i, j, k, 2)

    def dm(self, i, j=0):
        return float(np.linalg.norm(self.P(i) - self.P(j)))

    def _ang(self, i, j, u, e1, e2):
        a = self._get(i, u)
        return float(np.arctan2(a @ self._get(j, e2), a @ self._get(j, e1)))

    def ax(self, i, j=0):
        return self._ang(i, j, 2, 2, 3)

    def ay(self, i, j=0):
        return self._ang(i, j, 3, 3, 1)

    def az(self, i, j=0):
        return self._ang(i, j, 1, 1, 2)


def _keeping_interrupts(method):
    """The method's user calls share one relay of Ctrl-C/SIGTERM (installed once per call of
    the method, not per user call): a real interrupt ends the run (exit 130)."""
    @functools.wraps(method)
    def kept(*args, **kwargs):
        with kept_interrupts():
            return method(*args, **kwargs)
    return kept


class UserRoutine:
    """One element's user function: recorded slots, values, derivatives, Hessians."""

    def __init__(self, el, fn, path, par, marker_index, L):
        self.el = el
        self.fn = fn
        self.path = path
        self.par = par
        self.mi = marker_index             # deck marker id -> compiled index
        self.L = float(L)
        self.slots: list = []              # [(marker_id, kind)]
        self.m = 0
        self.time_dependent = True

    # ------------------------------------------------------------------ calls
    def _where(self):
        return f"user function {self.fn.__name__} in {self.path}"

    def _call(self, t, vec, record=None):
        q = MarkerAccess(t, vec, self.mi, record)
        with kept_interrupts():       # a real Ctrl-C/SIGTERM interrupts the run (exit 130)
            try:
                with _UserStdout():
                    out = self.fn(self.el.id, float(t), self.par, q)
            except _NewSlot as e:
                mid, kind = e.args[0]
                raise EvaluationError(f"{self._where()} read {KIND_NAMES[kind]} of marker {mid},"
                                      " which it did not read at the first call (the marker "
                                      "vectors a user routine reads must not change)",
                                      self.el.loc) from None
            except BaseException as e:  # noqa: BLE001 - anything user code raises (SystemExit,
                # KeyboardInterrupt too) fails the solve cleanly, never exits the process
                raise EvaluationError(f"{self._where()} raised "
                                      f"{_raised(e).removeprefix('it raised ')}",
                                      self.el.loc) from None
        der = None
        if isinstance(out, tuple) and len(out) == 2 and isinstance(out[1], dict):
            out, der = out
        try:
            val = np.atleast_1d(np.asarray(out, float)).ravel()
        except (TypeError, ValueError):
            raise EvaluationError(f"{self._where()} returned {out!r}; expected a number or a "
                                  "sequence of numbers", self.el.loc) from None
        if not np.all(np.isfinite(val)):
            raise EvaluationError(f"{self._where()} returned a non-finite value (NaN/Inf): "
                                  f"{val.tolist()}", self.el.loc)
        return val, der

    def vectors(self, t, P, A):
        return {(mid, k): (P[self.mi[mid]] if k == 0 else A[self.mi[mid]][:, k - 1])
                for mid, k in self.slots}

    @_keeping_interrupts
    def probe(self, t, P, A):
        """First call at the input configuration: records the vectors read, the value count
        and whether the result depends on time."""
        rec = set()
        allv = _AllVectors(P, A, self.mi)
        v0, _ = self._call(t, allv, rec)
        self.slots = sorted(rec)
        self.m = len(v0)
        vec = self.vectors(t, P, A)
        v1, _ = self._call(t + 1.0, vec)
        self.time_dependent = bool(np.any(v1 != v0)) if len(v1) == len(v0) else True
        return v0

    @_keeping_interrupts
    def values(self, t, vec):
        v, _ = self._call(t, vec)
        if len(v) != self.m:
            raise EvaluationError(f"{self._where()} returned {len(v)} values; expected "
                                  f"{self.m} (as at the first call)", self.el.loc)
        return v

    def _derivative_key(self, key) -> tuple[int, int]:
        """``(marker_id, "P"|"x"|"y"|"z")`` -> (marker id, kind index), else EvaluationError."""
        ok = isinstance(key, tuple) and len(key) == 2 and str(key[1]) in KIND_NAMES
        try:
            mid = int(key[0]) if ok else None
        except (TypeError, ValueError):
            mid = None
        if mid is None:
            raise EvaluationError(f"{self._where()} returned a derivative keyed {key!r}; "
                                  "expected (marker_id, 'P' | 'x' | 'y' | 'z')", self.el.loc)
        return mid, KIND_NAMES.index(str(key[1]))

    def _steps(self, scale=1e-6):
        return [scale * self.L if k == 0 else scale for _, k in self.slots]

    @_keeping_interrupts
    def evaluate(self, t, vec, need_jac=True, h=1e-6):
        """Values (m,) and derivatives (m, S, 3) w.r.t. the recorded vectors."""
        v, der = self._call(t, vec)
        if len(v) != self.m:
            raise EvaluationError(f"{self._where()} returned {len(v)} values; expected "
                                  f"{self.m} (as at the first call)", self.el.loc)
        if not need_jac:
            return v, None
        S = len(self.slots)
        D = np.zeros((self.m, S, 3))
        if der is not None:
            index = {s: k for k, s in enumerate(self.slots)}
            for key, g in der.items():
                mid, k = self._derivative_key(key)
                if (mid, k) not in index:
                    continue            # derivative w.r.t. a vector it does not read: zero
                try:
                    g = np.asarray(g, float).reshape(self.m, 3)
                except (TypeError, ValueError):
                    raise EvaluationError(
                        f"{self._where()} returned the derivative {key!r}: {g!r}; expected "
                        f"{self.m} x 3 numbers (d value / d vector)", self.el.loc) from None
                D[:, index[(mid, k)]] = g
            if not np.all(np.isfinite(D)):
                raise EvaluationError(f"{self._where()} returned non-finite derivatives",
                                      self.el.loc)
            return v, D
        for s, (key, hs) in enumerate(zip(self.slots, self._steps(h))):
            for c in range(3):
                vp, vm = _perturbed(vec, key, c, hs)
                D[:, s, c] = (self.values(t, vp) - self.values(t, vm)) / (2 * hs)
        return v, D

    @_keeping_interrupts
    def hessian(self, t, vec, w):
        """``sum_r w_r d2 v_r / dy2`` (3S, 3S) by central differences of the gradient."""
        S = len(self.slots)
        H = np.zeros((3 * S, 3 * S))
        if not np.any(w):
            return H
        _, der = self._call(t, vec)
        scale = 1e-6 if der is not None else 1e-4
        for s, (key, hs) in enumerate(zip(self.slots, self._steps(scale))):
            for c in range(3):
                vp, vm = _perturbed(vec, key, c, hs)
                gp = np.einsum("r,rk->k", w, self.evaluate(t, vp)[1].reshape(self.m, -1))
                gm = np.einsum("r,rk->k", w, self.evaluate(t, vm)[1].reshape(self.m, -1))
                H[:, 3 * s + c] = (gp - gm) / (2 * hs)
        return 0.5 * (H + H.T)


class _AllVectors(dict):
    """Every marker vector on demand (first call, while recording)."""

    def __init__(self, P, A, mi):
        super().__init__()
        self.P, self.A, self.mi = P, A, mi

    def __missing__(self, key):
        mid, k = key
        i = self.mi[mid]
        return self.P[i] if k == 0 else self.A[i][:, k - 1]

    def __contains__(self, key):
        return True


def _perturbed(vec: dict, key, c: int, h: float):
    """Copies of the slot-vector dict with component ``c`` of ``vec[key]`` moved by +h and -h."""
    e = np.zeros(3)
    e[c] = h
    vp, vm = dict(vec), dict(vec)
    vp[key] = vec[key] + e
    vm[key] = vec[key] - e
    return vp, vm
