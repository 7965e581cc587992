"""``Post_Request`` outputs: 8 channels per request, evaluated after each converged frame.

Every request type is reduced to eight expressions of the expression language (compiled once,
one batch per channel over all requests) plus reaction channels read exactly from the converged
multipliers (:func:`poise.elements.channels.channel_values`):

The hook writes ``requests/id`` (R,), ``requests/values`` (R, 8) and ``requests/message`` (a
string, empty when every channel evaluated) per frame. A channel whose evaluation fails (e.g.
division by zero at the converged state, or a frame that failed before) is NaN and the reason is
in ``requests/message``.

The channels of each request type: :func:`build_request_hook`.
"""
from __future__ import annotations

import numpy as np

from poise.deck.spec import Expr
from poise.core.errors import EvaluationError

from dataclasses import dataclass, replace

from poise.elements.channels import ExprInfo, channel_values
from poise.elements.registry import reaction_aliases
from poise.elements.resolver import compile_batch_located
from poise.expr import EvalContext


def _channels(el, pc):
    """Eight Expr/float/None channel definitions of one request."""
    a = el.attrs
    t = str(a.get("type", "EXPRESSION")).upper()
    i, j, rm = a.get("i_marker_id"), a.get("j_marker_id") or 0, a.get("ref_marker_id") or 0

    def X(text):
        return Expr(text, el.loc, "type")
    if t == "EXPRESSION":
        out = []
        for k in range(1, 9):
            v = a.get(f"expr{k}")
            if v is None or (isinstance(v, Expr) and v.text.strip().upper() == "NULL"):
                out.append(None)
            else:
                out.append(v)
        return out
    if t in ("MARKER_DISPLACEMENT", "MARKER_FORCE") and i is None:
        pc.error(el.loc, f"{t} needs i_marker_id", "i_marker_id")
        return [None] * 8
    if t == "MARKER_DISPLACEMENT":
        return [X(f"DM({i},{j})"), X(f"DX({i},{j},{rm})"), X(f"DY({i},{j},{rm})"),
                X(f"DZ({i},{j},{rm})"), None, X(f"YAW({i},{j})"), X(f"PITCH({i},{j})"),
                X(f"ROLL({i},{j})")]
    if t == "MARKER_FORCE":
        return [X(f"{f}({i},{j},{rm})") for f in ("FM", "FX", "FY", "FZ", "TM", "TX", "TY", "TZ")]
    if t == "ELEMENTAL_FORCE":
        kind = reaction_aliases().get(str(a.get("elem_type", "")).upper().replace(" ", "_"))
        if kind is None or a.get("elem_id") is None:
            pc.error(el.loc, f"elem_type {a.get('elem_type')!r} / elem_id not usable; expected "
                     "elem_type JOINT, JPRIM, MOTION, SFORCE, VFORCE, VTORQ, GFORCE, BUSH or "
                     "SPDP and an elem_id", "elem_type")
            return [None] * 8
        jf = int(a.get("jflag", 0) or 0)
        return [X(f"{kind}({a['elem_id']},{jf},{c},{rm})") for c in range(1, 9)]
    return [0.0] * 8                                      # velocities / accelerations


#: request types poise computes (every other request is output only: skipped with a warning)
COMPUTED = ("EXPRESSION", "MARKER_DISPLACEMENT", "MARKER_VELOCITY", "MARKER_ACCELERATION",
            "MARKER_FORCE", "ELEMENTAL_FORCE")
_USER = ("usrsub_param_string", "usrsub_fnc_name", "usrsub_dll_name", "script_name")


def computed_requests(reqs, pc):
    """The requests poise computes. The others are output only (user REQSUB routines and
    scripts, types poise does not know): one warning per type with the count, not an error."""
    keep, skip = [], {}
    for el in reqs:
        a = el.attrs
        t = str(a.get("type") or ("USERSUB" if any(a.get(k) for k in _USER)
                                  else "EXPRESSION")).upper()
        if t in COMPUTED:
            keep.append(el)
        else:
            skip.setdefault(t, []).append(el)
    for t, els in skip.items():
        n = len(els)
        what = ("a user subroutine or script (REQSUB)" if t == "USERSUB"
                else "a type poise does not compute")
        lines = ", ".join(str(e.loc.line) for e in els[:8]) + (", ..." if n > 8 else "")
        pc.warn(els[0].loc, f"Post_Request type {t} is {what}: output only, not computed; {n} "
                f"request{'s' if n > 1 else ''} skipped (line{'s' if n > 1 else ''} {lines}); "
                f"poise computes the types {', '.join(COMPUTED)}", "type")
    return keep


def build_request_hook(reqs, ctx, res):
    """Compile all requests; returns the frame hook ``hook(model, state) -> {path: array}``.

    ================== ===========================================================================
    type               channels 1..8
    ================== ===========================================================================
    EXPRESSION         ``expr1`` ... ``expr8``; ``"NULL"`` or absent -> NaN
    MARKER_DISPLACEMENT DM(I,J), DX(I,J,RM), DY(I,J,RM), DZ(I,J,RM), NaN, YAW(I,J), PITCH(I,J),
                       ROLL(I,J)  (J, RM absent: global frame; angles in radians; yaw-pitch-roll
                       rather than 3-1-3 because 3-1-3 is singular at zero tilt, the planar case)
    MARKER_FORCE       FM, FX, FY, FZ, TM, TX, TY, TZ (I, J, RM): resultant of every joint, jprim,
                       motion and force element acting between I and J (all elements at I when J is
                       absent), on I's body at the I origin, components in RM axes
    ELEMENTAL_FORCE    KIND(elem_id, jflag, 1..8, RM) with KIND from ``elem_type`` (JOINT, JPRIM,
                       MOTION, SFORCE, VFORCE, VTORQ, GFORCE, BUSH, SPDP or the element tag)
    MARKER_VELOCITY,   0 (static and quasi-static analyses have no velocities)
    MARKER_ACCELERATION
    ================== ===========================================================================
    """
    pc = ctx.pc
    chans = [_channels(el, pc) for el in reqs]
    R = len(reqs)
    null = np.array([[c is None for c in row] for row in chans], bool).reshape(R, 8)
    batches = []
    for k in range(8):
        col = [row[k] if row[k] is not None else 0.0 for row in chans]
        batches.append(compile_batch_located(col, res, pc))
    if any(b is None for b in batches):
        return None
    ids = np.array([el.id if el.id is not None else -1 for el in reqs], np.int64)
    return RequestOutputs(ids, null, tuple(batches), res.channels, ctx.element_markers)


@dataclass(frozen=True, eq=False)
class RequestOutputs:
    """Frame hook of the requests: ``requests/id``, ``requests/values`` (R, 8), ``requests/
    message``. ``null`` (R, 8) marks NULL channels, ``batches`` the 8 channel batches,
    ``channels`` the reaction channels they read; :meth:`bind` builds the channel plan with
    the model (``plan``)."""

    ids: np.ndarray
    null: np.ndarray
    batches: tuple
    channels: tuple
    element_markers: object
    plan: object = None

    def bind(self, model) -> "RequestOutputs":
        """This hook with its reaction-channel plan for ``model`` (being built)."""
        info = ExprInfo(model.outputs, self.element_markers)
        return replace(self, plan=info.plan(model, self.channels), element_markers=None)

    def __call__(self, model, state):
        R = len(self.ids)
        vals = np.full((R, 8), np.nan)
        msgs = []
        rx = None
        try:
            rx = channel_values(model, state, self.plan)
        except EvaluationError as e:
            msgs.append(f"reactions: {e}")
        P, A, _ = model.marker_kinematics(state)
        xc = EvalContext(t=float(state.t), P=P, A=A, angle=state.angle, extra=state.extra,
                         reactions=rx if rx is not None else np.full(len(self.channels),
                                                                     np.nan))
        for k, b in enumerate(self.batches):
            uses_rx = b.reaction_index.shape[1] > 0 and bool((b.reaction_index >= 0).any())
            if rx is None and uses_rx:
                continue
            try:
                v = b.evaluate(xc).value
            except EvaluationError as e:
                msgs.append(str(e))
                continue
            vals[:, k] = np.where(self.null[:, k], np.nan, v)
        return {"requests/id": self.ids, "requests/values": vals,
                "requests/message": np.array("; ".join(msgs))}
