"""IDA (SUNDIALS, through scikit-sundae) for FIM_D: settings, sparse Jacobian, counters.

:class:`TransientSettings` (``Param_Transient``), :class:`SparseJacobian` (``dF/dy`` on a
pattern fixed per model, filled by gathers), :class:`IdaStats` (IDA's own per-step counters
read through ctypes: scikit-sundae exposes only ``nfev``/``njev``) and :func:`run_ida` (one IDA
instance). Design notes and measurements: docs/fim_d.md.

scikit-sundae's public API has no per-step order or counters and no way to set IDA's corrector
coefficient, which FIM_D's results depend on; :class:`IdaStats` therefore reads the solver
object's C layout, which only the releases in :data:`SUPPORTED` are known to have (tested:
:data:`TESTED`; pyproject pins the same range). :func:`run_ida` refuses any other release with a
clear message (:class:`UnsupportedSundae`, exit 2) instead of running with other numbers.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from poise.core.errors import UsageError
from poise.elements.rotation import se3_left_jacobian

#: scikit-sundae releases (major, minor) whose solver layout IdaStats reads: [1.1, 1.3)
SUPPORTED = ((1, 1), (1, 3))
#: the releases FIM_D was run and compared with (same results on every example deck)
TESTED = ("1.1.3", "1.2.0")
#: where each supported release keeps its Cython solver on the public ``sksundae.ida.IDA``
_INNER = ("_IDA__IDA", "_IDA")       # 1.2: name-mangled; 1.1: plain
PIN = "scikit-sundae>=1.1,<1.3"


class UnsupportedSundae(UsageError):
    """The installed scikit-sundae is not a release FIM_D supports (exit 2, says what to
    install)."""


def check_supported(version: str | None = None) -> None:
    """Raise :class:`UnsupportedSundae` unless scikit-sundae ``version`` (default: the imported
    one) is in :data:`SUPPORTED`."""
    if version is None:
        import sksundae                 # lazy: SUNDIALS loads only for FIM_D runs
        version = str(getattr(sksundae, "__version__", "unknown"))
    try:
        mm = tuple(int(x) for x in version.split(".")[:2])
    except ValueError:
        mm = None
    if mm is not None and len(mm) == 2 and SUPPORTED[0] <= mm < SUPPORTED[1]:
        return
    raise UnsupportedSundae(
        f"FIM_D needs scikit-sundae 1.1 or 1.2 (it reads IDA's step order and counters, and "
        f"sets IDA's corrector coefficient, through the solver object of these releases; tested "
        f"with {', '.join(TESTED)}), but {version} is installed; run: pip install '{PIN}' "
        "(or use --method FIM_S)")

DEFAULT_DAE_CONSTR_TOL = 1e-6
NONLIN_CONV_COEF = 0.03   # IDA's corrector convergence coefficient (IDA's default 0.33)
H_FLOOR = 1e-12           # IDA's step-size floor (min_step) as a fraction of the span (or h_min)


@dataclass(frozen=True)
class TransientSettings:
    """FIM_D's settings from ``Param_Transient`` (module notes; defaults of a deck without one).

    ``tol`` = min(integr_tol, dae_constr_tol) (IDA's rtol); ``h_max`` / ``h_min`` / ``h0``
    (h0_max) 0 = not set; ``max_order``; ``maxit`` (dae_corrector_maxit); ``interpolate``
    (dae_interpolation); ``span``: end - start of the output times.
    """

    tol: float = min(1e-3, DEFAULT_DAE_CONSTR_TOL)
    h_max: float = 0.0
    h_min: float = 0.0
    h0: float = 0.0
    max_order: int = 5
    maxit: int = 4
    interpolate: bool = True
    span: float = 1.0

    @classmethod
    def from_attrs(cls, tr: dict, span: float) -> "TransientSettings":
        def get(k, d=None):
            v = tr.get(k)
            return d if v is None else v
        tol = min(float(get("integr_tol", 1e-3)),
                  float(get("dae_constr_tol", DEFAULT_DAE_CONSTR_TOL)))
        interp = get("dae_interpolation", True)
        if isinstance(interp, str):
            interp = interp.upper() not in ("FALSE", "NO", "0")
        return cls(tol=tol, h_max=float(get("h_max", 0.0) or 0.0),
                   h_min=float(get("h_min", 0.0) or 0.0),
                   h0=float(get("h0_max", 0.0) or 0.0),
                   max_order=int(get("max_order", 5)),
                   maxit=int(get("dae_corrector_maxit", 4)),
                   interpolate=bool(interp), span=float(span))


class SparseJacobian:
    """``dF/dy = J_kkt . D(w)`` in CSC form on a pattern computed once per model.

    ``D(w) = diag(I, J_l(w_b), I)``: each rotation triplet's three columns of ``J_kkt`` are
    combined with the 3x3 left Jacobian of SO(3), so an entry of a rotation column spreads over
    the body's three rotation columns. The pattern is the union of the KKT pattern
    (:meth:`~poise.model.assembly.Assembler.pattern`, fixed at compile time), that spread and the
    diagonal (explicit zeros where structurally empty: IDA's fallback identity and SuperLU's
    pivoting need no other pattern). ``values(J, w)`` maps the KKT values to the CSC data with
    precomputed gathers: ``sum_c J[i, 3b+c] Jl_b[c, c']`` for rotation columns, ``J[i, j]``
    elsewhere.
    """

    def __init__(self, model):
        N = model.N
        self.N = N
        r0, c0 = model.assembler.pattern()
        key0 = r0 * N + c0                      # row-major sorted, = order of the CSR data
        self.nnz0 = n0 = key0.size
        self.r0, self.c0 = r0, c0
        rot = np.asarray(model.rot_idx, np.int64)
        nrot = rot.size // 3
        is_rot = np.zeros(N, bool)
        is_rot[rot] = True
        pos = np.zeros(N, np.int64)
        pos[rot] = np.tile(np.arange(3), nrot)
        trip = np.zeros(N, np.int64)
        trip[rot] = np.repeat(np.arange(nrot), 3)
        base = np.arange(N) - pos               # first column of a rotation triplet
        sel = is_rot[c0]
        rr = np.concatenate([r0[~sel], np.repeat(r0[sel], 3), np.arange(N)])
        cc = np.concatenate([c0[~sel], (base[c0[sel]][:, None] + np.arange(3)).ravel(),
                             np.arange(N)])
        ck = np.unique(cc * N + rr)             # column-major: CSC order
        cols, rows = ck // N, ck % N
        self.nnz = ck.size
        self.indices = rows.astype(np.int32)
        self.indptr = np.searchsorted(cols, np.arange(N + 1)).astype(np.int32)
        self.diag = np.searchsorted(ck, np.arange(N) * N + np.arange(N))

        def slot(r, c):                         # position in the KKT data, n0 if absent
            if n0 == 0:
                return np.zeros(r.shape, np.int64)
            k = r * N + c
            i = np.minimum(np.searchsorted(key0, k), n0 - 1)
            return np.where(key0[i] == k, i, n0)

        plain = ~is_rot[cols]
        self.src = slot(rows, cols)             # rotation columns: overwritten in values()
        self.rot_pos = np.nonzero(~plain)[0]
        rr_, cc_ = rows[~plain], cols[~plain]
        b, cp, k = base[cc_], pos[cc_], trip[cc_]
        self.rot_src = np.stack([slot(rr_, b + c) for c in range(3)])          # (3, nr)
        self.rot_coef = np.stack([k * 9 + c * 3 + cp for c in range(3)])       # into Jl.ravel()

    def pattern(self):
        """The CSC pattern (ones) handed to IDA as ``sparsity``."""
        import scipy.sparse as sp
        return sp.csc_matrix((np.ones(self.nnz), self.indices, self.indptr),
                             shape=(self.N, self.N))

    def values(self, J, w):
        """CSC data of ``J . D(w)`` from the KKT Jacobian ``J`` (CSR on the assembler pattern, or
        dense) and the rotation vectors ``w`` (nrot, 3)."""
        if hasattr(J, "tocsr"):
            if J.data.size != self.nnz0:
                raise ValueError("KKT Jacobian does not have the assembler's pattern")
            d = J.data
        else:
            d = np.asarray(J)[self.r0, self.c0]
        d = np.append(d, 0.0)
        v = d[self.src]
        if self.rot_pos.size:
            Jl = se3_left_jacobian(np.asarray(w, float).reshape(-1, 3)).ravel()
            v[self.rot_pos] = (d[self.rot_src[0]] * Jl[self.rot_coef[0]]
                               + d[self.rot_src[1]] * Jl[self.rot_coef[1]]
                               + d[self.rot_src[2]] * Jl[self.rot_coef[2]])
        return v

    def matrix(self, data):
        import scipy.sparse as sp
        return sp.csc_matrix((data, self.indices, self.indptr), shape=(self.N, self.N))

    def identity(self):
        v = np.zeros(self.nnz)
        v[self.diag] = 1.0
        return v


class IdaStats:
    """Per-step statistics of one IDA instance read with the SUNDIALS C API.

    scikit-sundae (1.1, 1.2) returns only ``nfev``/``njev`` from a step; the BDF order and the
    nonlinear-solver / error-test counters are not exposed. They are read here with
    ``IDAGetLastOrder``, ``IDAGetLastStep``, ``IDAGetNumSteps``, ``IDAGetNumNonlinSolvIters``,
    ``IDAGetNumErrTestFails``, ``IDAGetNumNonlinSolvConvFails`` and ``IDAGetNumResEvals`` of the
    ``libsundials_ida`` bundled in the wheel (ctypes), on the ``IDAMem`` pointer held by the
    Cython solver object (its first C field after the vtable; the object is ``_IDA__IDA`` of the
    public wrapper in 1.2, ``_IDA`` in 1.1: :data:`_INNER`). Guards, any failing one disables
    the reader (``ok`` False, ``reason`` says why; the caller then records order -1): the
    object's C size is the one of the known layout; the pointer is non-NULL and the ``IDAMem``
    starts with the solver's own ``SUNContext`` (the next field); the library exports the
    functions; and after every step ``IDAGetNumResEvals``/``IDAGetNumJacEvals`` must equal
    scikit-sundae's own ``nfev``/``njev`` (:meth:`step`).
    """

    _lib = None
    _lib_reason = ""
    _BASICSIZE = 144        # PyObject_HEAD, vtable, 9 C pointers, NEQ (padded), 5 objects
    _LONG = ("NumSteps", "NumNonlinSolvIters", "NumErrTestFails", "NumNonlinSolvConvFails",
             "NumResEvals", "NumJacEvals")

    @classmethod
    def library(cls):
        if cls._lib is None and not cls._lib_reason:
            import ctypes
            import glob
            import os
            try:
                import sksundae
                libdir = os.path.join(os.path.dirname(os.path.dirname(sksundae.__file__)),
                                      "scikit_sundae.libs")
                paths = sorted(glob.glob(os.path.join(libdir, "libsundials_ida*.so*")))
                if not paths:
                    raise OSError(f"no libsundials_ida in {libdir}")
                lib = ctypes.CDLL(paths[0])
                vp = ctypes.c_void_p
                for name in cls._LONG:
                    f = getattr(lib, "IDAGet" + name)
                    f.argtypes, f.restype = [vp, ctypes.POINTER(ctypes.c_long)], ctypes.c_int
                for name, typ in (("LastOrder", ctypes.c_int), ("LastStep", ctypes.c_double)):
                    f = getattr(lib, "IDAGet" + name)
                    f.argtypes, f.restype = [vp, ctypes.POINTER(typ)], ctypes.c_int
                cls._lib = lib
            except (OSError, AttributeError, ImportError) as e:
                cls._lib_reason = f"SUNDIALS IDA library not usable: {e}"
        return cls._lib

    def __init__(self, solver):
        import ctypes
        self.ok, self.reason, self.mem = False, "", None
        self.prev = dict.fromkeys(self._LONG, 0)
        lib = self.library()
        obj = next((o for o in (getattr(solver, n, None) for n in _INNER) if o is not None), None)
        if lib is None:
            self.reason = self._lib_reason
        elif obj is None or type(obj).__basicsize__ != self._BASICSIZE:
            self.reason = "unknown scikit-sundae solver layout"
        else:
            mem = ctypes.c_void_p.from_address(id(obj) + 24).value
            ctx = ctypes.c_void_p.from_address(id(obj) + 32).value
            if not mem or not ctx or ctypes.c_void_p.from_address(mem).value != ctx:
                self.reason = "IDA memory pointer not found"
            else:
                self.lib, self.mem, self.ok = lib, mem, True
                self.solver = solver        # keeps the C memory alive while it is read
                if self.read()["NumSteps"] != 0:
                    self.ok, self.reason = False, "IDA memory pointer not validated"

    def set_nonlin_conv_coef(self, epcon):
        """``IDASetNonlinConvCoef``: the corrector stops when its estimated remaining error is
        below ``epcon`` (weighted RMS norm). Returns False (IDA keeps its default 0.33) when the
        reader is disabled."""
        if not self.ok:
            return False
        import ctypes
        f = self.lib.IDASetNonlinConvCoef
        f.argtypes, f.restype = [ctypes.c_void_p, ctypes.c_double], ctypes.c_int
        return f(self.mem, float(epcon)) == 0

    def read(self):
        import ctypes
        out = {}
        for name in self._LONG:
            v = ctypes.c_long()
            getattr(self.lib, "IDAGet" + name)(self.mem, ctypes.byref(v))
            out[name] = int(v.value)
        k, h = ctypes.c_int(), ctypes.c_double()
        self.lib.IDAGetLastOrder(self.mem, ctypes.byref(k))
        self.lib.IDAGetLastStep(self.mem, ctypes.byref(h))
        out["LastOrder"], out["LastStep"] = int(k.value), float(h.value)
        return out

    def step(self, r):
        """Counters of the step just taken (differences since the previous call; ``NumSteps``
        0 if the call returned without a step), or None if the reader is disabled or fails its
        check against scikit-sundae's ``nfev``/``njev``."""
        if not self.ok:
            return None
        cur = self.read()
        if cur["NumResEvals"] != r.nfev or cur["NumJacEvals"] != r.njev \
                or cur["NumSteps"] - self.prev["NumSteps"] not in (0, 1):
            self.ok, self.reason = False, "IDA counters disagree with scikit-sundae's"
            return None
        d = {k: cur[k] - self.prev[k] for k in self._LONG}
        d["LastOrder"], d["LastStep"] = cur["LastOrder"], cur["LastStep"]
        self.prev = cur
        return d


def run_ida(chart, ts_settings, atol, t0, y0, yp0, first_step):
    check_supported()                 # another release: a clear error, not other numbers
    from sksundae.ida import IDA      # lazy: SUNDIALS loads only for FIM_D runs
    n = len(y0)
    opts = dict(algebraic_idx=list(range(n)), rtol=ts_settings.tol, atol=atol,
                jacfn=chart.jacfn, linsolver="dense", max_order=ts_settings.max_order,
                max_nonlin_iters=ts_settings.maxit, max_num_steps=100000)
    if chart.sparse is not None:
        opts.update(jacfn=chart.jacfn_sparse, linsolver="sparse",
                    sparsity=chart.sparse.pattern(), nthreads=1)
    opts["max_step"] = ts_settings.h_max if ts_settings.h_max > 0 else ts_settings.span
    opts["min_step"] = max(ts_settings.h_min, H_FLOOR * ts_settings.span)
    if first_step > 0:
        opts["first_step"] = first_step
    with warnings.catch_warnings():
        # sparsity + jacfn: scikit-sundae notes that its finite-difference sparse Jacobian is
        # not used (the analytic one is), which is the intent
        warnings.filterwarnings("ignore", message="Custom sparse Jacobian approximation")
        solver = IDA(chart.resfn, **opts)
    r = solver.init_step(t0, y0, yp0)
    if not r.success:
        raise RuntimeError(r.message)
    chart.stats = IdaStats(solver)
    chart.conv_coef_set = chart.stats.set_nonlin_conv_coef(NONLIN_CONV_COEF)
    return solver
