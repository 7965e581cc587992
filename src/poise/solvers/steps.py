"""Newton's step, shaped: the step limits, the mass product, the neutral-direction filter and
the chord steps of Newton's quadratic phase.

:func:`limit_step` scales a step so that no body moves more than ``max_translation_step * L``
nor turns more than ``max_rotation_step``; :func:`neutral_filtered` removes from a regularised
Newton step the part only the ``stability`` mass term carries (zero-stiffness directions), so
that Newton converges quadratically next to neutral directions (docs/solvers.md, "Neutral
directions in Newton"); :func:`chord_step` reuses a kept factorisation (:func:`keep_factor`)
where its step does what Newton's would; :func:`mass_times` is the tangent mass matrix times a
vector.
"""
from __future__ import annotations

import numpy as np

from poise.core.lean import all_finite, einsum, row_norms
from poise.solvers.linalg import SingularMatrix

NEUTRAL_SHARE = 0.1           # S dx above this share of a limited step dx: neutral directions
TAIL_SHARE = 1e-6             # eps M dx above this share of the residual: filter the step
SMALL_S = 1e-3                # <Sx, Sx>_M / <x, Sx>_M below this: one solve, (I + S) x
SMALL_STEP = 1e-3             # step and eps M dx this far below their tolerances: as it is
REFILTER = 1e3                # |dx| above this many filtered steps: the filter's round-off refiltered
CHORD_STEP = 1e-2             # a chord step's share of the tolerances (steps.chord_step)
CHORD_RATE = 1e-2             # a chord step contracting this much: Newton's quadratic phase
KEEP_STEP = 1e-2              # a full step this small: its factorisation kept for a chord step


def limit_step(model, state, dq, settings):
    """Uniform step factor so that no body moves (actual screw displacement of its CG) more than
    ``max_translation_step * L`` nor rotates more than ``max_rotation_step``, and the
    configuration it accepted: ``(factor, retract(state, factor * dq))``, or ``(factor, None)``
    when the last retraction tried another factor. The line search starts from that
    configuration instead of retracting again (at most ``limits.limit_step_tries`` retractions)."""
    fac = 1.0
    if len(model.rot_idx):
        r = dq[model.rot_idx].reshape(-1, 3)
        mr = float(np.maximum.reduce(row_norms(r)))
        if mr > settings.max_rotation_step:
            fac = settings.max_rotation_step / mr
    lim = settings.max_translation_step * model.L
    for _ in range(settings.limits.limit_step_tries):
        trial = model.retract(state, fac * dq)
        disp = float(np.maximum.reduce(row_norms(trial.pos - state.pos))) if model.nb else 0.0
        if disp <= lim * 1.0001:
            return fac, trial
        fac *= 0.9 * lim / disp
    return fac, None


def step_size(dq, sc) -> float:
    """A coordinate step's size as Newton's convergence test measures it (translations relative
    to the model size, rotations in radians; the largest)."""
    return float(np.maximum.reduce(np.abs(dq) / sc.q_len)) if len(dq) else 0.0


def grew(dq, last_step: float, sc) -> bool:
    """Whether the step ``dq`` is longer than the last step taken (``last_step``; inf before
    the first): near a solution Newton's steps shrink, so a longer one is examined by
    :func:`neutral_filtered` for neutral content whose regularisation force is too small for
    its tail-share test (a neutral direction of tiny inertia, the spin of a slender rod)."""
    return bool(np.isfinite(last_step)) and step_size(dq, sc) > last_step


def keep_factor(model, f, x, sc, workspace=None):
    """The factorisation ``f`` that gave the step ``x``, kept for :func:`chord_step` (or None):
    a sparse model's step of at most ``KEEP_STEP`` (scaled). Keeping it releases the
    assembler's spare data buffer and column layout in ``workspace`` and its own matrix (a kept
    factorisation takes their place: at 10^5 links 0.3 GB; the buffers are rebuilt only if
    Newton factorises again, its solves are plain ones). Not for dense models (``N <= 600``):
    their factorisation costs little, and the batched sweep solver (:mod:`poise.solvers.batched`)
    takes Newton's own steps, as their single solves do."""
    if model.assembler.dense or step_size(x[:model.nq], sc) > KEEP_STEP:
        return None
    if workspace is not None:
        model.assembler.release(workspace)
    f.drop_matrix()
    return f


def chord_step(kept, b, sc, zinf):
    """The step ``f^-1 b`` by a kept factorisation ``kept = (f, d)`` of an earlier iterate's
    Jacobian (``d``: the size of the full step taken since it was used) when it does
    what Newton's step would, else None.

    Its contraction ``delta = |f^-1 b| / d`` (scaled sizes) estimates the relative change a
    Jacobian that old makes to the step, ``O(d)`` in Newton's quadratic phase. The chord step is
    taken when it certifies an iterate already within tolerance (``zinf <= 1``) by a step
    ``CHORD_STEP`` below ``max_error`` (its size is the error estimate; a ``delta`` up to 0.99
    keeps it below the tolerance), or when the chord leaves at most ``CHORD_STEP`` of the
    tolerances behind Newton's own next residual and step (``delta <= CHORD_RATE``,
    ``delta * zinf <= CHORD_STEP``, ``delta * |step| <= CHORD_STEP * max_error``): the next
    iterate is then measured and certified as after Newton's step.
    """
    if kept is None:
        return None
    f, d = kept
    try:
        x = f.solve(b)
    except SingularMatrix:
        return None
    if not all_finite(x):
        return None
    size = step_size(x[:len(sc.q_len)], sc)
    tol = CHORD_STEP * sc.max_error
    if zinf <= 1.0 and size <= tol:
        return x
    delta = size / d if d > 0.0 else np.inf
    if delta <= CHORD_RATE and delta * zinf <= CHORD_STEP and delta * size <= tol:
        return x
    return None


def mass_times(model, state, v, Jg=None):
    """``M v`` for a tangent vector ``v`` (nq,): body masses on translations, world inertia on
    rotations, zero on scalar unknowns. ``Jg``: the world inertias at ``state``
    (``model.world_inertia(state)``) when the caller has them already. Cases of a batch
    (:mod:`poise.solvers.batched`): ``v`` (C, nq) and their ``Jg`` (C, nr, 3, 3) given."""
    out = np.zeros(v.shape[:-1] + (model.nq,))
    if v.ndim == 1 and model.rigid_blocks():     # translations and rotations: strided views
        vt, vr = model.coord_parts(v)
        o6 = out[:6 * model.nb].reshape(model.nb, 6)
        o6[:, :3] = model.body_mass[:, None] * vt
        if len(vr):
            o6[:, 3:] = einsum("nij,nj->ni",
                               model.world_inertia(state) if Jg is None else Jg, vr)
        return out
    out[..., model.trans_idx] = model.body_mass.repeat(3) * v[..., model.trans_idx]
    if len(model.rot_idx):
        if Jg is None:
            Jg = model.world_inertia(state)
        vr = v[..., model.rot_idx]
        out[..., model.rot_idx] = einsum("...nij,...nj->...ni", Jg,
                                         vr.reshape(vr.shape[:-1] + (-1, 3))).reshape(vr.shape)
    return out


def neutral_filtered(model, state, f, x, eps, sc, zinf, limited, Jg=None):
    """The Newton step ``x = A^-1 (-F)`` (``A = K + eps M``) with near-neutral directions filtered
    out, or None when the regularisation does not dominate it.

    Along a direction of zero stiffness (the spin of a slender rod about its axis) a residual
    that is consistent only to second order still has a component ``O(e^2)`` there, which ``A``
    divides by ``eps`` times that direction's (possibly tiny) inertia: a huge spurious step that
    the step limits then cut down to nothing, so Newton stalls. With ``S = eps A^-1 M``
    (eigenvalues ``eps / (lambda + eps)`` for the generalised stiffness ``lambda``), the step
    ``(I - S)(I + 2 S) x`` scales each direction by ``lambda (lambda + 3 eps) / (lambda + eps)^3``:
    zero along neutral directions (the minimum-norm step) and ``1/lambda (1 - 3 (eps/lambda)^2)``
    along stiff ones (Newton's step, quadratic convergence for ``eps << lambda``). Examined only
    when ``eps M x`` carries more than ``TAIL_SHARE`` of the residual (then the regularisation
    would slow Newton down to a linear rate ``eps/lambda``), or when the step limits cut ``x``
    or it is longer than the last step taken (``limited``, :func:`grew`) and ``S x`` is more
    than ``NEUTRAL_SHARE`` of ``x`` (scaled); never for a step
    ``SMALL_STEP`` below the convergence tolerance with a regularisation force as far below
    the force tolerance (no step shape can matter there). ``S x`` costs a solve with the same
    factorisation; ``S^2 x`` a second one, only when ``S`` is not small on ``x``
    (``<Sx, Sx>_M > SMALL_S <x, Sx>_M``, the M-norm estimate of ``|S^2 x| / |S x|``, which
    neutral content of ``x`` lifts towards 1); otherwise the step is ``(I + S) x``, Newton's
    step to ``O((eps/lambda)^2)`` (it differs from the two-solve step by ``2 S^2 x``). A
    filtered step more than ``REFILTER`` times shorter than ``x`` is filtered once more: the
    cancellation's round-off, relative to ``|x|``, lies along the neutral directions too.
    ``limited`` may be a callable, asked only when the tail share alone does not decide (the
    step limits cost a retraction). ``Jg``: the world inertias at ``state`` when the caller has
    them (``Evaluation.inertia``).
    """
    if not eps > 0 or model.nq == 0:
        return None
    nq = model.nq
    if Jg is None and len(model.rot_idx):                               # every product's M
        Jg = model.world_inertia(state)
    Mx = mass_times(model, state, x[:nq], Jg)
    reg = eps * Mx
    rz = float(np.maximum.reduce(np.abs(reg) / sc.r_tol))
    size = step_size(x[:nq], sc)
    if size <= SMALL_STEP * sc.max_error and rz <= SMALL_STEP:
        return None
    share = rz / max(zinf, 1e-300)
    if not (share > TAIL_SHARE or (limited() if callable(limited) else limited)):
        return None
    pad = np.zeros(len(x) - nq)
    try:
        Sx = f.solve(np.concatenate([reg, pad]))
        y = Sx[:nq]
        if share <= TAIL_SHARE and not step_size(y, sc) > NEUTRAL_SHARE * size:
            return None
        My = mass_times(model, state, y, Jg)
        xy, yy = float(Mx @ y), float(My @ y)
        if xy > 0.0 and yy <= SMALL_S * xy:
            xf = x + Sx                          # S small on x: no neutral content to filter
        else:
            z = x + 2.0 * Sx
            xf = z - f.solve(np.concatenate([reg + (2.0 * eps) * My, pad]))
    except SingularMatrix:
        return None
    if not all_finite(xf):
        return None
    # the filter cancels x's neutral content; when that content dwarfs what is left, the
    # cancellation's round-off (relative to |x|, and along the neutral directions) is itself a
    # spurious neutral step, of a size set by round-off: filter what is left once more
    if size > REFILTER * step_size(xf[:nq], sc):
        again = neutral_filtered(model, state, f, xf, eps, sc, zinf, True, Jg)
        if again is not None:
            xf = again
    return xf
