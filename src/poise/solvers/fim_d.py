"""FIM_D: quasi-static continuation by integrating F(q(t), lam(t), t) = 0 with SUNDIALS IDA.

Unknowns (``y``, length nq + nc): tangent coordinates relative to a reference state ``ref`` —
per body the CG translation ``pos - ref.pos`` and a rotation vector ``w`` with
``R = expm(w) R_ref`` (spatial) — followed by the multipliers. When a rotation vector exceeds
``REBASE_ANGLE`` the reference is moved to the current state and IDA is re-initialised (BDF
history restarts at order 1). Continuous angles are unwrapped from the reference
(``ref.angle + wrap(principal - ref.angle)``, valid while relative rotations stay < pi).

Residual: ``[Phi_q^T lam - Q; Phi]`` at ``state(y, t)`` — no ``y'`` terms, so every component is
algebraic (``algebraic_idx`` = all; scikit-sundae only passes it to ``IDASetId``, used by
``IDACalcIC``, which we do not call because the consistent ``yp0`` is supplied). All components
stay in IDA's local error test: the test compares the BDF predictor (polynomial extrapolation of
the path) with the Newton corrector, which is what controls the step size along the
equilibrium path. Jacobian: ``dF/dy = J_kkt(state) . diag(I, J_l(w_b))`` (``J_l`` = left
Jacobian of SO(3); the KKT Jacobian is ``Model.evaluate(...).J`` with ``sqrt(stability) M``
added to the coordinate block as in FIM_S), analytic, handed to IDA through ``jacfn``:

* ``N <= SPARSE_MIN`` (200) unknowns: IDA's dense solver;
* larger models: IDA's sparse direct solver (scikit-sundae ``linsolver="sparse"``: SUNDIALS
  SuperLU_MT, bundled in the scikit-sundae 1.2 wheel; COLAMD column order computed at IDA's
  first factorisation and reused, partial pivoting; one thread). The pattern (``sparsity``)
  is computed once per model by :class:`SparseJacobian`: the compile-time KKT pattern
  (``Assembler.pattern``), each rotation-column entry spread over its body's three rotation
  columns (the product with ``J_l`` mixes them), and the diagonal. ``jacfn`` fills the 1-D
  CSC data array by precomputed gathers (no matrix products, no pattern work per call).
  scikit-sundae 1.2 accepts an analytic ``jacfn`` with the sparse solver (``JJ`` is the CSC
  data); its ``sparsity``-only mode (a grouped finite-difference Jacobian) is not used.
  Measured (2 shared cores): from 115 to 665 unknowns IDA's steps cost the same or less than
  with the dense solver (the residual evaluations dominate below that). There is no size
  limit: the former FIM_S fallback above 1500 unknowns is gone.

Start of every IDA run (the first one, after each rebase, after a FIM_S fallback):
:meth:`_Chart.start`, one Jacobian factorisation and 5-7 residuals:

* consistent ``y0``: the start state is polished by chord-Newton on ``F(y, t0) = 0`` (a rebase
  restarts from IDA's last corrector, converged only to IDA's test in the old chart's weights;
  left unpolished that remainder is the first step's local error: 0.03-1.2 tolerance units
  over the 6 rebases of ``decks/qs_slider_crank_rev.xml``, 4.5 with a 0.1 corrector
  coefficient, where IDA then failed at ``h_min`` and fell back to FIM_S);
* consistent ``y0' = -F_y^{-1} F_t`` (``F_t`` by central differences in t,
  ``h = 1e-6 * max(1, |t|, interval)``, at fixed configuration);
* first step from the path's curvature: ``y'' = -F_y^{-1} d2F/ds2`` along ``(y0', 1)``
  (second central difference), ``h0 = 1 / sqrt(||y''||)`` in IDA's weighted RMS norm, so the
  order-1 local error ``h0^2 |y''| / 2`` is about half a tolerance unit. IDA's own choice,
  ``0.5 / ||y0'||`` (the step that moves y by half a tolerance unit), is a slope criterion:
  on the 8-link chain it gave 4.5e-7 where 3.7e-4 is accurate, and IDA then doubled the step
  for 14 steps before reaching the path's step size, at every start (2 of them: 28 of 157
  steps). ``h0`` is capped by the smallest print interval (a flat start must not step over
  what the requested output resolves: a path with zero curvature at t0 would otherwise start
  with one step to the end). When the deck writes ``h0_max`` (the schema has no default for
  it: the reference's 1e-8 is marked unsure, and as a default it cost the 1001-frame
  slider-crank 10 of its 27 IDA steps), the first run starts with it (IDA raises it to
  ``h_min``; the curvature is then not computed); restarts are internal re-initialisations
  and use the estimate.

Corrector: ``IDASetNonlinConvCoef(NONLIN_CONV_COEF = 0.03)`` (IDA's default 0.33). With every
equation algebraic the corrector *is* the equilibrium solve, and its leftover error enters the
BDF history as noise, which IDA's order selection reads as a rough path (the (k+2)-th
differences it uses to raise the order amplify noise ~2^(k+1)): on the 8-link chain the accepted
correctors were 0.04 (median) / 0.2 (90th percentile) tolerance units off the exact equilibrium
at 0.33, IDA ran mostly at order 3, and tightening the coefficient (0.33 / 0.1 / 0.03 / 0.01)
took the run from 157 to 139 / 122 / 100 steps. 0.03 adds Newton iterations roughly in
proportion to the steps saved (residual evaluations about equal), with fewer Jacobians and
5-10 % less solve time than 0.33 on the chains; set through ctypes on the validated ``IDAMem``
pointer (:meth:`IdaStats.set_nonlin_conv_coef`), IDA's default stays when the pointer is not
usable (the message says so).

Why a chain needs more steps than the slider-crank bench at the same tolerance: its path
is rough in pseudo-time, not badly scaled. The 8-link chain under a load ramped to 2.5 times
its weight swings links by more than a radian, most of it in the first quarter second; from
2001 FIM_S frames the weighted derivatives reach ``||y^(5)|| = 1e11`` (slider crank: 1e5), and
the error test alone then needs ~67 steps at order 3 / ~46 at order 4 (slider crank: ~6).
Scaling one group of ``atol`` (translations, rotations or multipliers) by 10 or 0.1 changes the
8-link chain's 157 steps by -12 % to +45 % (order-selection noise included), all three 10x
looser gives 105 steps for 7x the error; excluding every component from the error test (IDA's
``suppressalg``: all are algebraic) gives 20 steps and output errors of 1.7e-2 instead of
1.2e-6. Measured before/after (2 shared cores, fastest solve of 15): 8-link chain 157 -> 104
steps, 0.33 -> 0.26 s; 20-link 109 -> 75, 0.30 -> 0.24 s; ``decks/bench/slider_crank_qs_1000.xml``
27 -> 27 steps, 0.49 s both (then still capped by the former h0_max default 1e-8; without it
27 -> 17 steps). Over 7 decks x dae tolerances
1e-4..1e-8 the error against FIM_S per unit tolerance went from median 0.90 / max 4.2 to
0.53 / 2.0, still decreasing with the tolerance on every deck.

Tolerances (``Param_Transient``; defaults in brackets): ``tol = min(integr_tol [1e-3],
dae_constr_tol [1e-6])`` is IDA's ``rtol``; ``atol`` = ``tol * L`` (translations), ``tol``
(rotations), ``tol * max(1, |lam0|)`` per multiplier kind (defaults of a deck without
``Param_Transient``; with one, the schema's h_min 1e-6 applies). ``h_max`` [unbounded] (max_step),
``h_min`` [``H_FLOOR`` x span] (min_step), ``h0_max`` [none] (the first step when written, see above), ``max_order`` [5],
``dae_corrector_maxit`` [4] (max_nonlin_iters). ``dae_interpolation`` [TRUE]: output frames are
IDA's interpolants at the print times (steps are not limited by the print interval); FALSE:
IDA stops exactly at every print time (``tstop``) and the frame is a converged corrector.
Either way the point meets IDA's error test, not ``Param_Static``'s tolerances (up to 0.013 N
against ``max_imbalance`` 1e-8 on ``decks/bench/slider_crank_qs_1000.xml``): every such output
point is corrected onto the equilibrium by :class:`Corrector` (the points of one IDA step
together: one batched residual + Jacobian evaluation, stacked solves, one batched residual per
further correction; full Newton for a frame that does not get there), and a frame is converged
only if it meets ``max_imbalance`` / ``max_error`` (``frames/iterations`` = its corrections;
the correction's cost is in the analysis attributes ``correction_*``). An output frame's imbalance, constraint error and worst equation
(``frames/*`` and its ``iterations`` row, event ``ida``) are computed in
:func:`poise.solvers.driver.build_result` from the frame's output evaluation (the one that feeds
reactions, loads and stability), where every frame is certified
(:func:`poise.solvers.certify.certify`).

Budgets (deterministic, no wall clock): at most ``IDA_MAX_STEPS + IDA_STEPS_PER_FRAME`` x
frames accepted IDA steps per run, a step-size floor ``H_FLOOR`` x span, and a body more than
``ESCAPE`` model sizes from its chart's reference ends the run (an unbounded load): the frame
fails (``max_iterations`` / ``diverged``) with the reason, results written.

FIM_S (with the recovery of a static solve, :func:`~poise.solvers.fallback.solve_frame`) is
used for the first frame (assembly + Newton), the last frame (Newton polish of IDA's
end state) and whenever IDA fails (the next output frame is solved with FIM_S from the last
accepted state, then IDA restarts); each fallback is recorded in ``iterations/event``
(``fallback_fim_s``) with its reason, and listed in the message.

Per-step table ``steps/*`` (one row per accepted internal IDA step), from IDA's own counters
(:class:`IdaStats`: ``IDAGetLastOrder``, ``IDAGetLastStep`` and differences of
``IDAGetNumNonlinSolvIters``, ``IDAGetNumErrTestFails``, ``IDAGetNumNonlinSolvConvFails``,
``IDAGetNumJacEvals`` read through ctypes, because scikit-sundae 1.2 exposes only ``nfev`` and
``njev``): ``time``, ``step_size`` (h used), ``order`` (BDF order of the step, 1..max_order),
``nonlinear_iterations`` (Newton iterations of the step, failed attempts included; one residual
evaluation each), ``error_test_failures``, ``convergence_failures`` (failed attempts before the
step was accepted), ``jacobian_evaluations``, ``rebase`` (1 where IDA was re-initialised
before the step). A ``ONE_STEP`` call that returns IDA's pending solution without stepping
(after an interpolated output) adds no row. If the counters cannot be read safely (other
scikit-sundae build; the message says why), ``order`` and ``convergence_failures`` are -1,
``nonlinear_iterations`` counts residual evaluations, ``error_test_failures`` counts extra
trial times (both failure kinds).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from poise.core.errors import EvaluationError
from poise.model.frame_batch import batchable, evaluate_frames
from poise.model.model import State
from poise.elements.rotation import expm_so3, se3_left_jacobian, wrap_angle
from poise.solvers.context import Strategy, replicate
from poise.solvers.fallback import solve_frame
from poise.solvers.newton import FrameOutcome, Scales
from poise.solvers.quasistatic import MIN_SUBSTEP_FRACTION, fims_step, first_frame
from poise.solvers.status import Status

REBASE_ANGLE = 1.0        # rad
SPARSE_MIN = 200          # unknowns: above this IDA uses the sparse (SuperLU_MT) linear solver
DEFAULT_DAE_CONSTR_TOL = 1e-6
NONLIN_CONV_COEF = 0.03   # IDA's corrector convergence coefficient (IDA's default 0.33)
START_NEWTON = 3          # chord-Newton corrections of a (re)start point, at most
START_POLISH = 1e-3       # ... until the correction is below this (weighted RMS norm)
CORRECT_MAX_ITER = 4      # simplified-Newton corrections of an output frame, at most
CORRECT_RATE = 0.25       # contraction slower than this: refactorise at the frame (once a frame)
# deterministic budgets (a run whose load explodes must end, not integrate forever)
IDA_MAX_STEPS = 2000      # accepted IDA steps per run, plus IDA_STEPS_PER_FRAME per output frame
IDA_STEPS_PER_FRAME = 20
H_FLOOR = 1e-12           # IDA's step-size floor (min_step) as a fraction of the span (or h_min)
ESCAPE = 1e6              # a body this many model sizes from its chart's reference: no bounded path


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

    scikit-sundae 1.2 returns only ``nfev``/``njev`` from a step; the BDF order and the
    nonlinear-solver / error-test counters are not exposed. They are read here with
    ``IDAGetLastOrder``, ``IDAGetLastStep``, ``IDAGetNumSteps``, ``IDAGetNumNonlinSolvIters``,
    ``IDAGetNumErrTestFails``, ``IDAGetNumNonlinSolvConvFails`` and ``IDAGetNumResEvals`` of the
    ``libsundials_ida`` bundled in the wheel (ctypes), on the ``IDAMem`` pointer held by the
    Cython solver object (its first C field after the vtable). Guards, any failing one disables
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
        obj = getattr(solver, "_IDA__IDA", None)
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


class _Chart:
    """The map y -> State around a reference state, its Jacobian factor, and IDA callbacks."""

    def __init__(self, model, ref, eps, counters, sparse=None, tol=1e-6):
        self.model = model
        self.tol = tol
        self.ref = ref.copy()
        self.eps = eps
        self.cnt = counters
        self.sparse = sparse            # SparseJacobian, or None: dense
        self.stats = None               # IdaStats of the current IDA instance (set by _ida)
        self.conv_coef_set = False      # NONLIN_CONV_COEF applied to that instance (by _ida)
        self.nres = 0
        self.njac = 0
        self.trial_times = set()
        self.held = None                # a factorisation of dF/dy in this chart (Corrector)

    def state(self, y, t):
        m, ref = self.model, self.ref
        st = ref.copy()
        st.t = float(t)
        st.pos = ref.pos + y[m.trans_idx].reshape(-1, 3)
        if len(m.rot_idx):
            w = y[m.rot_idx].reshape(-1, 3)
            st.rot[m.rot_body] = np.matmul(expm_so3(w), ref.rot[m.rot_body])
            m.track_rotation(st, ref, w)
        st.lam = np.array(y[m.nq:], float)
        if m.n_extra:                   # scalar unknowns: algebraic, y = extra - ref.extra
            st.extra = ref.extra + y[m.extra_idx]
        if len(m.angle_I):
            p = m._principal_angles(st)
            st.angle = ref.angle + wrap_angle(p - ref.angle)
        return st

    def states(self, Y, T):
        """:meth:`state` of many points ``Y`` (F, N) at times ``T`` (F,): the rotations of every
        frame in one ``expm_so3`` call and the continuous angles in one pass."""
        m, ref = self.model, self.ref
        F_ = len(Y)
        pos = ref.pos[None] + Y[:, m.trans_idx].reshape(F_, -1, 3)
        rot = np.repeat(ref.rot[None], F_, axis=0)
        if len(m.rot_idx):
            E = expm_so3(Y[:, m.rot_idx].reshape(-1, 3)).reshape(F_, -1, 3, 3)
            rot[:, m.rot_body] = np.matmul(E, ref.rot[m.rot_body][None])
        ang = np.repeat(ref.angle[None], F_, axis=0)
        if len(m.angle_I):
            rx = np.concatenate([rot, np.broadcast_to(np.eye(3), (F_, 1, 3, 3))], axis=1)
            A = np.matmul(rx[:, m.marker_body], m.marker_A0)                # (F, nm, 3, 3)
            u_col = np.array([1, 2, 0])[m.angle_axis]
            e2_col = np.array([2, 0, 1])[m.angle_axis]

            def col(idx, c):
                return np.take_along_axis(A[:, idx], c[None, :, None, None], axis=3)[..., 0]

            u, e1, e2 = col(m.angle_I, u_col), col(m.angle_J, u_col), col(m.angle_J, e2_col)
            p = np.arctan2(np.sum(u * e2, axis=2), np.sum(u * e1, axis=2))
            ang = ref.angle[None] + wrap_angle(p - ref.angle[None])
        out = []
        for k in range(F_):
            st = State(pos[k], rot[k], np.array(Y[k, m.nq:], float), ang[k], float(T[k]),
                       None if ref.extra is None else ref.extra.copy())
            if m.n_extra:
                st.extra = ref.extra + Y[k, m.extra_idx]
            out.append(st)
        return out

    def max_rotation(self, y):
        m = self.model
        if not len(m.rot_idx):
            return 0.0
        return float(np.max(np.linalg.norm(y[m.rot_idx].reshape(-1, 3), axis=1)))

    def F(self, st):
        ev = self.model.evaluate(st, need_jac=False, active=self.cnt.active)
        self.cnt.residuals += 1
        return np.concatenate([ev.r, ev.phi])

    def jac(self, y, t):
        """``dF/dy``: dense ndarray, or the CSC data on ``self.sparse``'s pattern."""
        m = self.model
        st = self.state(y, t)
        ev = m.evaluate(st, need_jac=True, eps_mass=self.eps, active=self.cnt.active)
        self.cnt.jacobians += 1
        if self.sparse is not None:
            return self.sparse.values(ev.J, y[m.rot_idx].reshape(-1, 3))
        J = ev.J.toarray() if hasattr(ev.J, "toarray") else np.array(ev.J)
        if len(m.rot_idx):
            w = y[m.rot_idx].reshape(-1, 3)
            Jl = se3_left_jacobian(w)
            Jr = J[:, m.rot_idx].reshape(J.shape[0], -1, 3)
            J[:, m.rot_idx] = np.einsum("nbi,bij->nbj", Jr, Jl).reshape(J.shape[0], -1)
        return J

    # IDA callbacks
    def resfn(self, t, y, yp, res):
        self.nres += 1
        self.trial_times.add(float(t))
        try:
            res[:] = self.F(self.state(y, t))
        except EvaluationError:
            res[:] = 1e30

    def jacfn(self, t, y, yp, res, cj, JJ):
        self.njac += 1
        try:
            JJ[:, :] = self.jac(y, t)
        except EvaluationError:
            JJ[:, :] = np.eye(len(y))

    def jacfn_sparse(self, t, y, yp, res, cj, JJ):
        """``JJ``: the CSC data (1-D, pattern ``self.sparse.pattern()``)."""
        self.njac += 1
        try:
            JJ[:] = self.jac(y, t)
        except EvaluationError:
            JJ[:] = self.sparse.identity()

    def _factor(self, y, t):
        """Solver for ``dF/dy`` at (y, t): a callable b -> F_y^{-1} b."""
        J = self.jac(y, t)
        self.cnt.factorizations += 1
        if self.sparse is not None:
            import scipy.sparse.linalg as spla
            return spla.splu(self.sparse.matrix(J), permc_spec="COLAMD").solve
        import scipy.linalg as sla
        with warnings.catch_warnings():
            warnings.simplefilter("error", sla.LinAlgWarning)   # singular: LinAlgError below
            try:
                lu = sla.lu_factor(J)
            except sla.LinAlgWarning as e:
                raise np.linalg.LinAlgError(str(e)) from None
        return lambda b: sla.lu_solve(lu, b)

    def start(self, y, t, dt_scale, weight, span, want_h0=True):
        """Consistent start of an IDA run at (y, t): ``(y0, y0', h0)``.

        * ``y0``: ``y`` polished by chord-Newton on ``F(y, t) = 0`` (at most ``START_NEWTON``
          corrections, until the correction is below ``START_POLISH`` in the weighted RMS norm
          ``weight`` = IDA's error weights). A rebase restarts from IDA's last corrector, which
          met IDA's convergence test in the old chart's weights only; left as it is, that
          remainder is the first step's local error (see the module notes).
        * ``y0' = -F_y^{-1} F_t`` (``F_t`` by central differences in t).
        * ``h0``: first step from the path's curvature, ``y'' = -F_y^{-1} d2F/ds2`` along
          ``(y0', 1)`` (second central difference), ``h0 = 1 / sqrt(||y''||)`` in the same
          weighted norm: the order-1 local error ``h^2 |y''| / 2`` is then about half a tolerance
          unit. 0 when the estimate is not usable (IDA then uses its own) or not wanted.
        Cost: one Jacobian and 5-7 residuals (3 fewer without ``h0``). Any linear-algebra
        failure gives ``(y, 0, 0)``.
        """
        n = len(y)
        try:
            solve = self._factor(y, t)
            self.held = solve                   # kept for the output-frame corrections
            y = np.array(y, float)
            for _ in range(START_NEWTON):
                dy = solve(-self.F(self.state(y, t)))
                if not np.all(np.isfinite(dy)):
                    raise np.linalg.LinAlgError
                y = y + dy
                if np.sqrt(np.mean((dy * weight) ** 2)) <= START_POLISH:
                    break
            h = 1e-6 * max(1.0, abs(t), dt_scale)
            Ft = (self.F(self.state(y, t + h)) - self.F(self.state(y, t - h))) / (2 * h)
            yp = solve(-Ft)
            if not np.all(np.isfinite(yp)):
                raise np.linalg.LinAlgError
        except (np.linalg.LinAlgError, RuntimeError, ValueError, EvaluationError):
            return np.asarray(y, float), np.zeros(n), 0.0
        h0 = 0.0
        if not want_h0:
            return y, yp, h0
        try:
            # path parameter step: a 1e-3 part of the span, and at most 1e-3 of the model's
            # scales per coordinate (y' / weight, in tolerance units, times the tolerance)
            rate = float(np.max(np.abs(yp) * weight)) * self.tol
            d = min(1e-3 * span, 1e-3 / rate) if rate > 0 else 1e-3 * span
            g = (self.F(self.state(y + d * yp, t + d)) - 2.0 * self.F(self.state(y, t))
                 + self.F(self.state(y - d * yp, t - d))) / (d * d)
            ypp = solve(-g)
            c = float(np.sqrt(np.mean((ypp * weight) ** 2)))
            if np.isfinite(c) and c > 0:
                h0 = 1.0 / np.sqrt(c)
        except (np.linalg.LinAlgError, RuntimeError, ValueError, EvaluationError):
            pass
        return y, yp, h0


class Corrector:
    """Brings IDA's output points onto the equilibrium, to the ``Param_Static`` tolerances.

    IDA's interpolant (or corrector, with ``dae_interpolation`` FALSE) meets IDA's local error
    test, not ``max_imbalance`` / ``max_error``: on ``decks/bench/slider_crank_qs_1000.xml`` the
    output frames were up to 0.013 N off against 1e-8. The output points passed by one IDA step
    are corrected together (:meth:`batch`): Newton corrections in the chart's coordinates,
    ``y <- y - F_y(y_0)^{-1} F(y, t)``, with each frame's Jacobian taken once at its
    interpolated point (one batched residual + Jacobian evaluation,
    :func:`~poise.model.frame_batch.evaluate_frames`), then one batched residual and one
    stacked back-substitution per further correction. A frame is accepted when its residual
    meets the FIM_S scales (force rows ``max_imbalance``, moment rows ``max_imbalance * L``,
    constraint rows ``max_error`` (x L)) and the next correction — its error estimate — is
    ``<= max_error`` (translations / L, rotations in rad). Frames still off after
    ``CORRECT_MAX_ITER`` corrections, or models that are not batched, go through :meth:`one`:
    simplified Newton with a factorisation held per chart (refactorised at the frame when the
    contraction is slower than ``CORRECT_RATE``); the caller runs a full Newton (FIM_S) on a
    frame that still fails. ``stats``: frames, corrections, residual evaluations,
    factorisations, full-Newton fallbacks and the wall time spent here.
    """

    def __init__(self, model, settings, active):
        self.model = model
        self.active = np.asarray(active, bool)      # the solve's active constraint rows
        self.sc = Scales(model, settings)
        self.max_error = settings.max_error
        self.chart = None
        self.solve = None
        self.stats = dict(frames=0, corrections=0, residuals=0, factorisations=0, newton=0,
                          seconds=0.0)

    # ------------------------------------------------------------------ measures
    def _z(self, F):
        """Tolerance-scaled infinity norm of residual rows ``F`` (..., N)."""
        nq = self.model.nq
        zr = np.abs(F[..., :nq]) / self.sc.r_tol
        zp = np.abs(F[..., nq:]) / self.sc.phi_tol
        return np.maximum(zr.max(axis=-1, initial=0.0), zp.max(axis=-1, initial=0.0))

    def _err(self, dy):
        return np.max(np.abs(dy[..., :self.model.nq]) / self.sc.q_len, axis=-1, initial=0.0)

    # ------------------------------------------------------------------ batched
    def batch(self, chart, Y, T):
        """Correct the output points ``Y`` (F, N) at times ``T`` (F,). Returns ``(Y, iterations
        (F,), error estimates (F,), ok (F,))``."""
        import time as _t
        m = self.model
        Y = np.array(Y, float)
        F_ = len(Y)
        its = np.zeros(F_, int)
        errs = np.full(F_, np.nan)
        ok = np.zeros(F_, bool)
        if not F_:
            return Y, its, errs, ok
        t0 = _t.perf_counter()
        st = self.stats
        st["frames"] += F_
        done = False
        if batchable(m):
            saved = self.active
            inact = np.nonzero(~saved)[0] + m.nq
            try:
                ev = evaluate_frames(m, chart.states(Y, T), need_jac=True)
                st["residuals"] += F_
                Fv = np.concatenate([ev.r, np.where(saved, ev.phi, 0.0)], axis=1)
                J = self._chart_jacobian(ev.J, Y, inact)
                st["factorisations"] += F_
                live = np.arange(F_)
                for it in range(CORRECT_MAX_ITER + 1):
                    dy = np.linalg.solve(J[live], -Fv[live][..., None])[..., 0]
                    if not np.all(np.isfinite(dy)):
                        raise np.linalg.LinAlgError("non-finite correction")
                    e = self._err(dy)
                    good = (self._z(Fv[live]) <= 1.0) & (e <= self.max_error)
                    errs[live], its[live], ok[live[good]] = e, it, True
                    live, dy = live[~good], dy[~good]
                    if not live.size or it == CORRECT_MAX_ITER:
                        break
                    Y[live] += dy
                    st["corrections"] += live.size
                    ev = evaluate_frames(m, chart.states(Y[live], T[live]), need_jac=False)
                    st["residuals"] += live.size
                    Fv[live] = np.concatenate([ev.r, np.where(saved, ev.phi, 0.0)], axis=1)
                done = True
            except (np.linalg.LinAlgError, EvaluationError, ValueError):
                pass
        if not done:
            ok[:], its[:] = False, 0
        st["seconds"] += _t.perf_counter() - t0
        for k in np.nonzero(~ok)[0]:
            y, n, e, good = self.one(chart, Y[k], T[k])
            Y[k], its[k], errs[k], ok[k] = y, its[k] + n, e, good
        return Y, its, errs, ok

    def _chart_jacobian(self, J, Y, inact):
        """``dF/dy`` of each frame from its KKT Jacobian (F, N, N) at the chart point: the
        rotation columns times the left Jacobian of SO(3) (as :meth:`_Chart.jac`), redundant
        rows as in :meth:`Model.jacobian` (identity on their multiplier, no coupling)."""
        m = self.model
        J = np.array(J, float)
        if len(m.rot_idx):
            F_, N = J.shape[0], J.shape[1]
            w = Y[:, m.rot_idx].reshape(F_, -1, 3)
            Jl = se3_left_jacobian(w.reshape(-1, 3)).reshape(F_, -1, 3, 3)
            Jr = J[:, :, m.rot_idx].reshape(F_, N, -1, 3)
            J[:, :, m.rot_idx] = np.einsum("fnbi,fbij->fnbj", Jr, Jl).reshape(F_, N, -1)
        if len(inact):
            J[:, inact, :] = 0.0
            J[:, :, inact] = 0.0
            J[:, inact, inact] = 1.0
        return J

    # ------------------------------------------------------------------ one frame
    def one(self, chart, y, t):
        """Simplified Newton on one output point with the chart's held factorisation:
        ``(y, corrections, error estimate, ok)``."""
        import time as _t
        t0 = _t.perf_counter()
        st = self.stats
        if chart is not self.chart:
            self.chart, self.solve = chart, chart.held
        y = np.array(y, float)
        it, ok, err = 0, False, np.nan
        refreshed = False

        def step(F):
            dy = -self.solve(F)
            if not np.all(np.isfinite(dy)):
                raise np.linalg.LinAlgError("non-finite correction")
            return dy, float(self._err(dy))

        try:
            F = chart.F(chart.state(y, t))
            st["residuals"] += 1
            z_prev = np.inf
            while True:
                z = float(self._z(F))
                if self.solve is None:
                    self.solve, refreshed = chart._factor(y, t), True
                    st["factorisations"] += 1
                dy, err = step(F)
                if z <= 1.0 and err <= self.max_error:
                    ok = True
                    break
                if it >= CORRECT_MAX_ITER:
                    break
                if it > 0 and z > CORRECT_RATE * z_prev and not refreshed:
                    self.solve, refreshed = chart._factor(y, t), True
                    st["factorisations"] += 1
                    dy, err = step(F)
                y = y + dy
                it += 1
                z_prev = z
                F = chart.F(chart.state(y, t))
                st["residuals"] += 1
        except (np.linalg.LinAlgError, RuntimeError, ValueError, EvaluationError):
            ok = False
        st["corrections"] += it
        st["seconds"] += _t.perf_counter() - t0
        return y, it, err, ok


def _ida(chart, ts_settings, atol, t0, y0, yp0, first_step):
    from sksundae.ida import IDA
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


class IdaContinuation(Strategy):
    """FIM_D: the equilibrium path integrated by IDA between the output frames (module notes);
    frame 0 and the last frame by FIM_S, FIM_S fallbacks where IDA fails. One ``step`` is one
    IDA step (it may pass several output frames)."""

    name = "FIM_D"

    def init(self, ctx, state):
        model, s, ts = ctx.model, ctx.settings, ctx.times
        st, out = first_frame(ctx, state)
        ctx.frames, ctx.outcomes = [st], [out]
        self.done = not out.ok or len(ts) == 1
        if self.done:
            return
        if ctx.time_independent:
            replicate(ctx)
            self.done = True
            return
        self.sparse = SparseJacobian(model) if model.N > SPARSE_MIN else None
        self.tsd = tsd = TransientSettings.from_attrs(ctx.request.transient,
                                                      max(float(ts[-1] - ts[0]), 1e-300))
        self.eps = float(np.sqrt(s.stability))
        self.interval = float(np.min(np.diff(ts)))
        self.T_end = float(ts[-1])
        self.tol = tsd.tol
        self.steps = dict(time=[], step_size=[], order=[], nonlinear_iterations=[],
                          error_test_failures=[], convergence_failures=[],
                          jacobian_evaluations=[], rebase=[])
        self.stats_off = []          # why IDA's own counters could not be read (order -1)
        self.conv_coef_off = []      # why IDA's corrector coefficient could not be set
        self.fallbacks = []
        self.correct = Corrector(model, s, ctx.data.mask(model))
        self.k_out = 1
        self.n_starts = 0
        self.max_steps = IDA_MAX_STEPS + IDA_STEPS_PER_FRAME * len(ts)
        self.ref = st
        self.rebased = 1
        self.chart = self.solver = None
        self.t_last, self.y_last = st.t, None

    def terminate(self, ctx):
        return self.done or self.k_out >= len(ctx.times)

    def _atol(self, model, st):
        tol = self.tol
        a = np.empty(model.N)
        a[:model.nq] = np.where(model.q_kind == 1, tol, tol * model.L)
        lam = np.abs(st.lam)
        for kind in (0, 1):
            sel = model.row_kind == kind
            if sel.any():
                a[model.nq:][sel] = tol * max(1.0, float(lam[sel].max()) if sel.any() else 1.0)
        return a

    def _start(self, ctx, ref, first):
        model, tsd = ctx.model, self.tsd
        chart = _Chart(model, ref, self.eps, ctx.data, self.sparse, self.tol)
        y0 = np.concatenate([np.zeros(model.nq), ref.lam])
        atol = self._atol(model, ref)
        capped = first and tsd.h0 > 0       # the user's (or the deck schema's) h0_max
        y0, yp0, h0 = chart.start(y0, ref.t, self.interval,
                                  1.0 / (self.tol * np.abs(y0) + atol), self.T_end - ref.t,
                                  want_h0=not capped)
        # no first step beyond the output resolution
        h0 = min(tsd.h0, self.interval) if capped else min(h0, self.interval)
        solver = _ida(chart, tsd, atol, ref.t, y0, yp0, h0)
        return chart, solver, y0

    def _fall_back(self, ctx, reason, last_state):
        """FIM_S for output frame ``k_out`` from ``last_state``; ends the run if it fails."""
        ok = _fallback(ctx, self.k_out, reason, self.fallbacks, last_state)
        self.k_out += 1
        if not ok:
            self.done = True
            return
        self.ref = ctx.frames[-1]

    def step(self, ctx):
        model, s, ts, hist = ctx.model, ctx.settings, ctx.times, ctx.history
        T_end = self.T_end
        if self.solver is None:
            try:
                self.chart, self.solver, self.y_last = self._start(ctx, self.ref,
                                                                   self.n_starts == 0)
                self.n_starts += 1
                if not self.chart.conv_coef_set and not self.conv_coef_off:
                    self.conv_coef_off.append(self.chart.stats.reason)
                self.t_last = self.ref.t
            except (RuntimeError, ValueError) as e:
                self.solver = None
                self._fall_back(ctx, f"IDA could not start at t={self.ref.t:.9g}: {e}",
                                self.ref)
                return
        chart, solver = self.chart, self.solver
        stop = T_end if self.tsd.interpolate else float(ts[self.k_out])
        n0r, nj0 = chart.nres, chart.njac
        chart.trial_times = set()
        try:
            r = solver.step(stop, method="onestep", tstop=stop)
            ok_step = bool(r.success)
            msg = r.message
        except (RuntimeError, ValueError) as e:
            ok_step, msg = False, str(e)
        if not ok_step:
            reason = f"IDA failed after t={self.t_last:.9g}: {msg}"
            last = (chart.state(self.y_last, self.t_last) if self.y_last is not None
                    else ctx.frames[-1])
            self.solver = None
            self._fall_back(ctx, reason, last)
            self.rebased = 1
            return
        d = chart.stats.step(r) if chart.stats is not None else None
        if (d["NumSteps"] == 0) if d is not None else (r.t == self.t_last and chart.nres == n0r):
            # no step taken: ONE_STEP after an interpolated output returns IDA's pending
            # solution at t_n first (nothing to record)
            pass
        else:
            if d is not None:
                row = (d["LastStep"], d["LastOrder"], d["NumNonlinSolvIters"],
                       d["NumErrTestFails"], d["NumNonlinSolvConvFails"], d["NumJacEvals"])
            else:
                # IDA's counters unreadable: order -1; iterations = residual evaluations (one
                # per Newton iteration); retries = extra trial times (both failure kinds)
                if chart.stats is not None and chart.stats.reason not in self.stats_off:
                    self.stats_off.append(chart.stats.reason)
                row = (r.t - self.t_last, -1, chart.nres - n0r,
                       max(len(chart.trial_times) - 1, 0), -1, chart.njac - nj0)
            for k, v in zip(("time", "step_size", "order", "nonlinear_iterations",
                             "error_test_failures", "convergence_failures",
                             "jacobian_evaluations", "rebase"), (r.t, *row, self.rebased)):
                self.steps[k].append(v)
            self.rebased = 0
        self.t_last, self.y_last = float(r.t), np.array(r.y, float)
        t_last, y_last = self.t_last, self.y_last
        over = _over_budget(len(self.steps["time"]), self.max_steps, y_last, model, t_last)
        if over is not None:
            ctx.frames.append(chart.state(y_last, t_last))
            ctx.outcomes.append(over)
            hist.add(self.k_out, 0, np.nan, np.nan, np.nan, np.nan, over.message, "ida")
            self.k_out += 1
            self.done = True
            return
        tol_t = 1e-12 * max(1.0, abs(T_end))
        # output frames passed by this step (interpolated), except the last one
        pend = []
        while self.k_out < len(ts) - 1 and ts[self.k_out] <= t_last + tol_t:
            tk = float(ts[self.k_out])
            if abs(tk - t_last) <= tol_t:
                yk = y_last
            else:
                yk = np.array(solver.step(tk).y, float)
            pend.append((self.k_out, tk, yk))
            self.k_out += 1
        # onto the equilibrium to the Param_Static tolerances (Corrector, all the output points
        # of this step at once); imbalance / constraint error / worst equation of each "ida"
        # row: from the frame's output evaluation at the result (the same state)
        if pend:
            Tp = np.array([p[1] for p in pend])
            Yc, n_c, errs, ok_c = self.correct.batch(chart, np.array([p[2] for p in pend]), Tp)
            sts = chart.states(Yc, Tp)
            for j, (k, tk, yk) in enumerate(pend):
                ctx.measured[len(ctx.frames)] = len(hist.rows)
                hist.add(k, n_c[j], np.nan, np.nan, errs[j], np.nan, "", "ida")
                if ok_c[j]:
                    st, o = sts[j], FrameOutcome(Status.CONVERGED, int(n_c[j]), np.nan, errs[j],
                                                 "ida")
                else:
                    self.correct.stats["newton"] += 1
                    st, o = solve_frame(model, chart.state(yk, tk), s, hist, k, ctx.data,
                                        event="ida_newton")
                    o.iterations += int(n_c[j])
                ctx.frames.append(st)
                ctx.outcomes.append(o)
                ctx.report("FIM_D", k + 1, len(ts))
        if self.k_out == len(ts) - 1 and t_last >= T_end - tol_t:
            # last frame: FIM_S polish of IDA's end state
            st = chart.state(y_last, T_end)
            st, o = solve_frame(model, st, s, hist, self.k_out, ctx.data, event="final_fim_s")
            if not o.ok:
                reason = f"Newton polish of the last frame failed ({o.status.value})"
                _fallback(ctx, self.k_out, reason, self.fallbacks, chart.state(y_last, t_last))
            else:
                ctx.frames.append(st)
                ctx.outcomes.append(o)
            self.k_out += 1
            self.done = True
            return
        if chart.max_rotation(y_last) > REBASE_ANGLE:
            self.ref = chart.state(y_last, t_last)
            self.solver = None
            self.rebased = 1

    def postprocess(self, ctx):
        if not hasattr(self, "steps"):        # frame 0 failed or nothing to integrate
            return {}, {}
        model, notes, fallbacks = ctx.model, ctx.notes, self.fallbacks
        if fallbacks:
            notes.append(f"{len(fallbacks)} FIM_S fallbacks: " + "; ".join(fallbacks[:3])
                         + (" ..." if len(fallbacks) > 3 else ""))
        nsteps = len(self.steps["time"])
        notes.append(f"IDA: {nsteps} steps, tol {self.tol:g}"
                     + (f", sparse linear solver (SuperLU_MT, N = {model.N})"
                        if self.sparse else ""))
        if self.stats_off:
            notes.append("IDA step order not available: " + "; ".join(self.stats_off))
        if self.conv_coef_off:
            notes.append(f"IDA corrector coefficient left at IDA's default 0.33 (not "
                         f"{NONLIN_CONV_COEF:g}): " + "; ".join(self.conv_coef_off))
        datasets = {f"steps/{k}": np.asarray(v, dtype=float if k in ("time", "step_size")
                                             else np.int64)
                    for k, v in self.steps.items()}
        attrs = {"ida_steps": nsteps}
        for k, v in self.correct.stats.items():
            attrs[f"correction_{k}"] = v
        attrs["fim_s_fallbacks"] = len(fallbacks)
        attrs["dae_tol"] = self.tol
        attrs["ida_linear_solver"] = "sparse" if self.sparse is not None else "dense"
        return datasets, attrs


def _over_budget(n_steps, max_steps, y, model, t):
    """A failed outcome when the run exceeded its IDA step budget or a body left every scale
    of the model (``ESCAPE`` model sizes from its chart's reference); else None."""
    if n_steps > max_steps:
        return FrameOutcome(Status.MAX_ITERATIONS, 0, np.nan, np.nan,
                            f"IDA step budget exhausted ({max_steps} steps) at t={t:.9g}")
    d = float(np.max(np.abs(y[model.trans_idx]))) if model.nb else 0.0
    if not d <= ESCAPE * model.L:
        return FrameOutcome(Status.DIVERGED, 0, np.nan, np.nan,
                            f"the equilibrium path left every scale of the model at t={t:.9g} "
                            f"(a body moved {d / model.L:.3g} model sizes, more than {ESCAPE:g}: is a load "
                            "unbounded?)")
    return None


def _fallback(ctx, k_out, reason, fallbacks, last_state):
    """Solve output frame ``k_out`` with FIM_S from ``last_state``; record the reason."""
    fallbacks.append(reason)
    ctx.history.add(k_out, 0, np.nan, np.nan, np.nan, np.nan, reason, "fallback_fim_s")
    frames, ts = ctx.frames, ctx.times
    hist = list(frames[-2:])
    if last_state.t > hist[-1].t:
        hist.append(last_state)
    min_dt = MIN_SUBSTEP_FRACTION * (ts[k_out] - ts[k_out - 1])
    st, o, _ = fims_step(ctx.model, hist, float(ts[k_out]), ctx.settings, ctx.history, ctx.data,
                         k_out, min_dt)
    frames.append(st)
    ctx.outcomes.append(o)
    return o.ok
