"""``--require-stable``: from an unstable equilibrium, continue downhill to a stable one.

Newton (FIM_S) converges to whichever equilibrium is near, stable or not. When the static
analysis is asked for a stable equilibrium (``require_stable``) and Newton stopped at an
unstable one, :func:`seek_stable` leaves it and continues by a stability-preserving Newton:

1. Escape: the unstable modes of the classification (``StabilityInfo.vectors``, up to six,
   computed by :mod:`poise.solvers.stability`) are combined into one direction; the state moves
   along it (both signs, amplitudes from ``ESCAPE_ROT`` rad / ``ESCAPE_TRANS`` x L down, each
   trial assembled onto the constraints) to the first trial that lowers the potential energy.
2. Descent: Newton steps on ``(K + mu M) dx = -F`` (the ``stability`` term of :func:`newton`,
   so the residual and hence the equilibrium are unchanged). ``mu`` starts above the magnitude
   of the most negative eigenvalue (``K + mu M`` positive definite on the constraint manifold:
   every step is a descent direction), is halved after every step that lowers the potential
   energy and multiplied by 4 (step rejected) after one that raises it; near the minimum it
   reaches 0 and the last steps are plain Newton (quadratic). The potential energy therefore
   never increases, so the walk cannot return to the equilibrium it left.
3. The equilibrium reached is classified again; still unstable (more negative modes than were
   described) -> back to 1.

Models without a potential energy (non-conservative loads) use the work of the applied
forces along each step (trapezoidal) as the energy change. Every escape and descent step is a
row of the iteration history (events ``stable: escape ...``, ``stable-descent mu=...``). The
budget is ``STEPS_PER_ITER x max_num_iter`` descent steps and ``MAX_ESCAPES`` escapes; past it
the analysis fails with status ``unstable`` and the last state is written.
"""
from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np

from poise.errors import EvaluationError
from poise.solvers.newton import FrameOutcome, assemble, newton
from poise.solvers.status import Status

ESCAPE_ROT = 0.3          # rad: largest rotation of the first escape trial
ESCAPE_TRANS = 0.05       # x L: largest translation of the first escape trial
ESCAPE_SHRINK = (1.0, 0.3, 0.1, 0.03, 0.01)
MAX_ESCAPES = 20
STEPS_PER_ITER = 2        # descent budget: this many x max_num_iter Newton steps in all
MU_UP, MU_DOWN = 4.0, 0.5
STEP_TRANS = 0.05         # x L: largest translation of one descent step (Newton step limit)
STEP_ROT = 0.3            # rad: largest rotation of one descent step


def acceptable(info, settings) -> bool:
    """Is the classification good enough for ``require_stable``: ``stable``, or ``neutral``
    when ``allow_neutral``."""
    return info.klass == "stable" or (info.klass == "neutral" and settings.allow_neutral)


def require_stable_check(ar, out, settings):
    """After a static analysis' datasets are written: with ``require_stable``, a converged
    frame whose classification is not :func:`acceptable` fails (status ``unstable``, exit 1;
    the results are written as they are)."""
    if not settings.require_stable or not out.ok:
        return
    klass = str(ar.datasets["frames/stability"][0])
    if klass == "stable" or (klass == "neutral" and settings.allow_neutral):
        return
    why = f"the equilibrium found is {klass}"
    if klass == "neutral":
        why += " and --no-allow-neutral was given"
    elif klass == "unknown":
        why += " (its stability could not be established)"
    out.status = Status.UNSTABLE
    ar.datasets["frames/converged"] = np.array([False])
    ar.datasets["frames/status"] = np.array([Status.UNSTABLE.value], dtype=str)
    ar.status = "failed"
    ar.message = "no stable equilibrium reached (--require-stable): " + why + "; " + ar.message


def potential_energy(model, state) -> float:
    """Potential energy of gravity and conservative elements (NaN if one is not conservative)."""
    from poise.solvers.mkeam import MkeamAnalysis
    return MkeamAnalysis.potential_energy(SimpleNamespace(model=model), state)


def _energy_drop(model, a, b, cnt, pa=None):
    """``V(b) - V(a)`` (potential energy, or minus the trapezoidal work of the applied forces
    along the tangent difference when the model has no potential). Returns (dV, V(b))."""
    pb = potential_energy(model, b)
    if pa is None:
        pa = potential_energy(model, a)
    if np.isfinite(pa) and np.isfinite(pb):
        return pb - pa, pb
    dq = model.local_difference(a, b)
    # residual r = -Q + G^T lam: its projection on a constraint-respecting step is -Q . dq
    ra = np.asarray(model.evaluate(a, need_jac=False).r).ravel()[:model.nq]
    rb = np.asarray(model.evaluate(b, need_jac=False).r).ravel()[:model.nq]
    cnt.residuals += 2
    return 0.5 * float((ra + rb) @ dq), np.nan


def _escape_direction(model, info):
    vs = [np.asarray(v, float) for v in info.vectors if np.all(np.isfinite(v))]
    if not vs:
        return None
    d = np.zeros(model.nq)
    for v in vs:
        n = float(np.max(np.abs(v * model.q_scale)))
        if n > 0:
            d += v / n
    # unit: the largest rotation 1 rad / translation 1 L
    rot = model.q_kind == 1
    sr = float(np.max(np.abs(d[rot]))) if np.any(rot) else 0.0
    st = float(np.max(np.abs(d[~rot]))) / model.L if np.any(~rot) else 0.0
    s = max(sr / ESCAPE_ROT, st / ESCAPE_TRANS)
    return d / s if s > 0 else None


def seek_stable(model, state, settings, history, frame, cnt, info, classify_at):
    """Continue from the unstable equilibrium ``state`` (classification ``info``) to a stable
    one. ``classify_at(state) -> StabilityInfo``. Returns ``(state, outcome, info, note)``;
    ``outcome.ok`` only at an equilibrium whose classification is :func:`acceptable`."""
    budget = STEPS_PER_ITER * settings.max_num_iter
    used = 0
    escapes = 0
    pe = potential_energy(model, state)
    while True:
        if acceptable(info, settings):
            note = (f"--require-stable: left {escapes} unstable equilibri"
                    f"{'um' if escapes == 1 else 'a'} downhill ({used} descent steps) to a "
                    f"{info.klass} one")
            return state, FrameOutcome(Status.CONVERGED, used, np.nan, np.nan, "converged"), info, note
        if info.klass != "unstable":
            why = (f"the equilibrium reached is {info.klass}" +
                   (" and --no-allow-neutral was given" if info.klass == "neutral" else "") +
                   (f" ({info.modes})" if info.modes else ""))
            return state, _fail(used, why), info, ""
        if escapes >= MAX_ESCAPES or used >= budget:
            return state, _fail(used, f"still unstable ({info.n_negative} negative modes) after "
                                f"{escapes} escapes and {used} descent steps (budget "
                                f"{budget} = {STEPS_PER_ITER} x max_num_iter)"), info, ""
        d = _escape_direction(model, info)
        if d is None:
            return state, _fail(used, "unstable, and no unstable mode vector to leave it along"), \
                info, ""
        escapes += 1
        history.add(frame, 0, np.nan, np.nan, event=f"stable: escape {escapes}: unstable "
                    f"({info.n_negative} negative modes)")
        moved = None
        for f in ESCAPE_SHRINK:
            for sgn in (1.0, -1.0):
                try:
                    x = model.retract(state, sgn * f * d)
                    x, _, ast = assemble(model, x, settings, history, frame, cnt)
                    if not ast.ok:
                        continue
                    dv, pe_x = _energy_drop(model, state, x, cnt, pe)
                except EvaluationError:
                    continue
                if dv < 0 and (moved is None or dv < moved[0]):
                    moved = (dv, x, pe_x)
            if moved is not None:
                break
        if moved is None:
            return state, _fail(used, "unstable, and no move along its unstable modes lowers "
                                "the potential energy"), info, ""
        _, state, pe = moved
        from poise.solvers.newton import initial_multipliers
        state = initial_multipliers(model, state, cnt)
        mu0 = _mu_start(model, state, info, d)
        mu = mu0
        out = None
        # plain Newton from the escaped point first: kept only if it ends at an equilibrium of
        # lower potential energy than the one left (then it cannot be that one again)
        pe_left = pe
        try:
            st, o = newton(model, state, replace(settings, fallback=False), history, frame, cnt,
                           event="stable-newton")
            used += o.iterations
            if o.ok:
                dv, pe_n = _energy_drop(model, state, st, cnt, pe)
                if pe + dv < pe_left:
                    state, out, pe = st, o, pe + dv
        except EvaluationError:
            pass
        while out is None and used < budget:
            s_mu = replace(settings, stability=mu * mu, fallback=False, line_search=False,
                           max_translation_step=min(settings.max_translation_step, STEP_TRANS),
                           max_rotation_step=min(settings.max_rotation_step, STEP_ROT))
            try:
                st, o = newton(model, state, s_mu, history, frame, cnt, max_iter=1,
                               event=f"stable-descent mu={mu:.3g}")
            except EvaluationError:
                o = None
            used += 1
            if o is not None and o.ok:
                state, out = st, o
                break
            if o is None or o.status is Status.NONFINITE or o.iterations == 0:
                mu = max(mu * MU_UP, mu0 * 1e-3)
                continue
            try:
                dv, pe_new = _energy_drop(model, state, st, cnt, pe)
            except EvaluationError:
                dv = np.inf
            scale = 1e-12 * max(abs(pe) if np.isfinite(pe) else 0.0, 1.0)
            if dv <= scale:
                state, pe = st, pe_new
                # a step cut by the step limit: the model is not yet quadratic at this scale
                # (trust region), so mu is not relaxed
                mu *= 1.0 if o.error >= 0.98 * STEP_TRANS else MU_DOWN
                if mu < 1e-10 * mu0:
                    mu = 0.0
            else:
                mu = max(mu * MU_UP, mu0 * 1e-3)
        if out is None:
            return state, _fail(used, f"the descent did not reach an equilibrium within its "
                                f"budget ({budget} = {STEPS_PER_ITER} x max_num_iter steps)"), \
                info, ""
        info = classify_at(state)


def _mu_start(model, state, info, d):
    """A ``mu`` [1/s^2] twice the magnitude of the most negative eigenvalue per unit mass: the
    eigenvalue [force/length] over the mass of the escape direction ``d`` (Rayleigh quotient
    of the mass diagonal, both in length coordinates)."""
    u = d * model.q_scale
    md = model.mass_diagonal(state) / model.q_scale ** 2
    m_eff = float(u @ (md * u)) / max(float(u @ u), 1e-300)
    w = abs(info.min_eigenvalue) if np.isfinite(info.min_eigenvalue) else 1.0
    return 2.0 * w / max(m_eff, 1e-300)


def _fail(used, why):
    return FrameOutcome(Status.UNSTABLE, used, np.nan, np.nan,
                        "no stable equilibrium reached (--require-stable): " + why)
