"""``--require-stable``: when Newton's equilibrium is unstable, reach a stable one downhill.

:func:`seek_stable` (:class:`Escapes`, a :class:`~poise.solvers.iterate.Solver`) runs the
inertia-controlled Newton descent (:func:`~poise.solvers.descent.descend`) first from the input
Newton started from (the rest position downhill from the input), then, if that does not end
stable, leaves Newton's equilibrium along its unstable modes (escape: the trial of lowest
energy, both signs, shrinking) and descends again (unstable end point -> escape again). Every
escape and descent step is a history row; past the budget (``descent_steps_per_iter x
max_num_iter`` steps, ``max_escapes`` escapes: :mod:`~poise.solvers.limits`) the
analysis fails with status ``unstable``.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from poise.core.errors import EvaluationError
from poise.core.wording import plural
from poise.solvers.energy import potential_energy
from poise.solvers.history import Row
from poise.solvers.iterate import Next, Solver, iterate
from poise.solvers.linalg import SingularMatrix
from poise.solvers.descent import descend, energy_drop
from poise.solvers.newton import FrameOutcome, initial_multipliers
from poise.solvers.reach import assemble
from poise.solvers.stability import unknown_info
from poise.solvers.status import Status
from poise.solvers.trials import project

ESCAPE_ROT = 0.3          # rad: largest rotation of the first escape trial
ESCAPE_TRANS = 0.05       # x L: largest translation of the first escape trial
ESCAPE_SHRINK = (1.0, 0.3, 0.1, 0.03, 0.01)


def acceptable(info, settings) -> bool:
    """Is the classification good enough for ``require_stable``: ``stable``, or ``neutral``
    when ``allow_neutral``."""
    return info.klass == "stable" or (info.klass == "neutral" and settings.allow_neutral)


def require_stable_check(frames, message: str, settings) -> tuple:
    """The driver's step after a static frame is measured: with ``require_stable``, a
    converged frame whose classification is not :func:`acceptable` fails (status
    ``unstable``, exit 1; the results are written as they are). ``frames``: the analysis'
    :class:`~poise.solvers.record.FrameSet`. Returns ``(frames, message, failed)``."""
    out = frames.outcomes[0]
    if not settings.require_stable or not out.ok:
        return frames, message, False
    klass = frames.stability[0].klass
    if klass == "stable" or (klass == "neutral" and settings.allow_neutral):
        return frames, message, False
    why = f"the equilibrium found is {klass}"
    if klass == "neutral":
        why += " and --no-allow-neutral was given"
    elif klass == "unknown":
        why += " (its stability could not be established)"
    rest = "; ".join(m for m in message.split("; ") if m and m != "converged")
    return (frames.with_outcome(0, replace(out, status=Status.UNSTABLE)),
            "no stable equilibrium reached (--require-stable): " + why
            + (f"; {rest}" if rest else ""), True)

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


@dataclass(frozen=True)
class Seeking:
    """Where :class:`Escapes` stands: the point ``state`` and its classification ``info``, its
    potential energy, descent steps ``used``, escapes made, ``start`` (the input to descend
    from first, None once tried or not given); ``end``: ``(state, outcome, info, note)``
    once decided."""

    state: Any
    info: Any
    pe: float = np.nan
    used: int = 0
    escapes: int = 0
    start: Any = None
    end: tuple | None = None


class Escapes(Solver):
    """From the unstable equilibrium ``state`` (classification ``info``) to a stable one:
    the descent from the input first (when given), then escapes along the unstable modes,
    each followed by a descent (:func:`descend`). Budget: ``limits.max_escapes`` escapes,
    and ``limits.descent_steps_per_iter`` x max_num_iter descent steps in all. Result:
    ``(state, outcome, info, note)`` (:func:`seek_stable`)."""

    out_of_budget = Status.UNSTABLE

    def __init__(self, model, settings, frame, cnt, classify_at):
        self.model, self.settings, self.frame, self.cnt = model, settings, frame, cnt
        self.classify_at = classify_at
        self.limits = settings.limits
        self.budget = self.limits.descent_steps_per_iter * settings.max_num_iter

    def init(self, state, info, start):
        pe = potential_energy(self.model, state) if start is None else np.nan
        return Seeking(state, info, pe, start=start)

    def _verdict(self, s):
        """The status the point ``s`` ends with (None: go on)."""
        if s.end is not None:
            return s.end[1].status
        if s.start is not None:
            return None
        if acceptable(s.info, self.settings):
            return Status.CONVERGED
        if s.info.klass != "unstable" or s.used >= self.budget:
            return Status.UNSTABLE
        return None

    def terminate(self, s):
        status = self._verdict(s)
        return status is not None, status

    def step(self, s, left):
        if s.start is not None:
            return self._from_input(s)
        model, settings, frame, cnt = self.model, self.settings, self.frame, self.cnt
        info, used = s.info, s.used
        d = _escape_direction(model, info)
        if d is None:
            return Next(replace(s, end=(s.state, _fail(used, "unstable, and no unstable mode "
                                                             "vector to leave it along"),
                                        info, "")), 0)
        escapes = s.escapes + 1
        rows = [Row(frame, 0, event=f"stable: escape {escapes}: unstable "
                    f"({plural(info.n_negative, 'negative mode')})")]
        moved = None
        for f in ESCAPE_SHRINK:
            for sgn in (1.0, -1.0):
                try:
                    x, ok = project(model, model.retract(s.state, sgn * f * d), cnt)
                    if not ok:
                        x, _, ast = assemble(model, x, settings, rows, frame, cnt)
                        if not ast.ok:
                            continue
                    dv, pe_x = energy_drop(model, s.state, x, cnt, s.pe)
                except EvaluationError:
                    continue
                if dv < 0 and (moved is None or dv < moved[0]):
                    moved = (dv, x, pe_x)
            if moved is not None:
                break
        s = replace(s, escapes=escapes)
        if moved is None:
            return Next(replace(s, end=(s.state, _fail(used, "unstable, and no move along its "
                                                             "unstable modes lowers the "
                                                             "potential energy"), info, "")),
                        1, tuple(rows))
        _, state, pe = moved
        state = initial_multipliers(model, state, cnt)
        why = []
        state, out, pe, n = descend(model, state, settings, rows, frame, cnt,
                                    self.budget - used, pe, why=why)
        used += n
        s = replace(s, state=state, pe=pe, used=used)
        if out is None:
            reason = why[0] if why else (f"the descent did not reach an equilibrium within its "
                                         f"budget ({self.budget} = "
                                         f"{self.limits.descent_steps_per_iter} x max_num_iter "
                                         "steps)")
            return Next(replace(s, end=(state, _fail(used, reason + _zero_modes_at(
                self.classify_at, state)), unknown_info(
                f"not classified: not at an equilibrium ({reason})"), "")), 1, tuple(rows))
        return Next(replace(s, info=self.classify_at(state)), 1, tuple(rows))

    def _from_input(self, s):
        """The descent from the input Newton started from (at most half the budget)."""
        model, settings, frame, info = self.model, self.settings, self.frame, s.info
        rows = [Row(frame, 0, event=f"stable: Newton's equilibrium is unstable "
                    f"({plural(info.n_negative, 'negative mode')}): descent from the input")]
        why = []
        used = 0
        try:
            st, out, _, used = descend(model, s.start, settings, rows, frame, self.cnt,
                                       self.budget // 2, why=why)
        except (EvaluationError, SingularMatrix) as e:
            out = None
            why.append(f"{type(e).__name__}: {e}")
        if out is not None:
            i2 = self.classify_at(st)
            if acceptable(i2, settings):
                note = (f"--require-stable: Newton's equilibrium was unstable "
                        f"({plural(info.n_negative, 'negative mode')}); descended from the input "
                        f"({plural(used, 'step')}) to a "
                        f"{i2.klass} one")
                return Next(replace(s, start=None, used=used, end=(
                    st, FrameOutcome(Status.CONVERGED, used, np.nan, np.nan, "converged"), i2,
                    note)), 0, tuple(rows))
        rows.append(Row(frame, 0, event="stable: the descent from the input did not end at a "
                        "stable equilibrium" + (f" ({why[0]})" if why else "") +
                        "; leaving Newton's along its unstable modes"))
        pe = potential_energy(model, s.state)
        return Next(replace(s, start=None, used=used, pe=pe), 0, tuple(rows))

    def postprocess(self, s, status, used):
        if s.end is not None:
            return s.end
        info, n = s.info, s.used
        if status is Status.CONVERGED:
            note = (f"--require-stable: left {s.escapes} unstable equilibri"
                    f"{'um' if s.escapes == 1 else 'a'} downhill ({plural(n, 'descent step')}) "
                    f"to a {info.klass} one")
            return s.state, FrameOutcome(Status.CONVERGED, n, np.nan, np.nan, "converged"), \
                info, note
        if info.klass != "unstable":
            why = (f"the equilibrium reached is {info.klass}" +
                   (" and --no-allow-neutral was given" if info.klass == "neutral" else "") +
                   (f" ({info.modes})" if info.modes else ""))
            return s.state, _fail(n, why), info, ""
        return s.state, _fail(n, f"still unstable ({plural(info.n_negative, 'negative mode')}) "
                              f"after {plural(s.escapes, 'escape')} and "
                              f"{plural(n, 'descent step')} (budget "
                              f"{self.budget} = {self.limits.descent_steps_per_iter} x "
                              "max_num_iter)"), info, ""


def seek_stable(model, state, settings, history, frame, cnt, info, classify_at, start=None):
    """Continue from the unstable equilibrium ``state`` (classification ``info``) to a stable
    one (:class:`Escapes`, its rows appended to ``history``). ``classify_at(state) ->
    StabilityInfo``. Returns ``(state, outcome, info, note)``; ``outcome.ok`` only at an
    equilibrium whose classification is :func:`acceptable`; ``info`` is the returned state's
    classification (``unknown`` when the descent stopped short of an equilibrium), also when
    the outcome fails.

    ``start``: the (assembled) input Newton started from. The descent is tried from there
    first, with at most half the budget: it is the rest position reached downhill from the
    input (MKEAM's answer), and Newton's path into an unstable equilibrium often leaves the
    model in a shape far from any minimum (a chain released as a V converges to a kinked V;
    the descent from there is several times longer: docs/mkeam.md). If that does not end at an
    acceptable equilibrium, Newton's point is left along its unstable modes."""
    return iterate(Escapes(model, settings, frame, cnt, classify_at),
                   settings.limits.max_escapes,
                   history, state, info, start)


def _zero_modes_at(classify_at, state) -> str:
    """``"; the point reached has N zero-stiffness modes (...)"`` when it has any: the neutral
    directions a descent cannot resolve by energy (their energy does not change)."""
    try:
        info = classify_at(state)
    except (EvaluationError, SingularMatrix, ValueError, ArithmeticError):
        return ""
    if info.n_zero > 0:
        return (f"; the point reached has {plural(info.n_zero, 'zero-stiffness mode')} "
                f"({info.modes})")
    return ""


def _fail(used, why):
    return FrameOutcome(Status.UNSTABLE, used, np.nan, np.nan,
                        "no stable equilibrium reached (--require-stable): " + why)
