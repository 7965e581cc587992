"""The one summary of an analysis and of a run: what the stderr line, ``--json``, ``poise show``
and the ``batch`` / ``sweep`` rows report.

One definition everywhere (from an :class:`~poise.results.data.AnalysisResult` in memory or read
back from a results file): the *worst frame* of each measure, with the frame named —

* ``iterations``: total over all frames;
* ``imbalance`` / ``error``: the largest over the frames (NaN frames ignored), with its frame
  index and time;
* ``frame_status``: ``converged``, or the status of the first frame that did not converge;
* ``singular``: where a quasi-static run ended at a singular configuration (``time``,
  ``kind``, ``elements`` (the constraints that lock: ``tag``, ``id``, ``label``, ``line``,
  ``share``), ``mode``), from the analysis attributes ``singular_*``; None otherwise;
* ``stability_class``: the worst class over the frames, ``stable < neutral < unknown < unstable``
  (``unknown``: not classified, so the run proved neither), at the frame with the most negative
  (unstable) or zero (neutral) modes among those of that class (the first on ties), with that
  frame's counts, mode text and numeric modes (``modes/*``).

A run (``batch`` / ``sweep`` rows) takes the same worst over its analyses.
"""
from __future__ import annotations

import json
import math
from collections import Counter
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from poise.results.data import STATUS_CONVERGED
from poise.solvers.stability import Mode

#: worse classes rank higher
STABILITY_RANK = {"stable": 0, "neutral": 1, "unknown": 2, "unstable": 3}
#: modes listed on the one-line summary (the rest as "...")
LINE_MODES = 3


@dataclass(frozen=True)
class ModeRecord:
    """A described mode as numbers (see :class:`poise.solvers.stability.Mode`)."""
    klass: str
    body: int
    kind: str
    direction: tuple
    eigenvalue: float | None
    label: str = ""          # a scalar unknown's name (kind coordinate), from the modes text

    def text(self, short: bool = False) -> str:
        return Mode(self.klass, self.body, self.kind, self.direction,
                    np.nan if self.eigenvalue is None else self.eigenvalue,
                    label=self.label).text(short)

    def as_dict(self) -> dict:
        return {"class": self.klass, "body": self.body, "kind": self.kind,
                "direction": [_finite(x) for x in self.direction],
                "eigenvalue": _finite(self.eigenvalue)}


@dataclass(frozen=True)
class AnalysisSummary:
    """Summary of one analysis (module docstring). Frame indices are 0-based output frames;
    times in the deck's time unit. ``None`` where the results hold no such data."""
    index: int
    analysis_type: str
    method: str
    status: str
    message: str = ""
    frames: int = 0
    iterations: int | None = None
    imbalance: float | None = None
    imbalance_frame: int | None = None
    imbalance_time: float | None = None
    error: float | None = None
    error_frame: int | None = None
    error_time: float | None = None
    frame_status: str | None = None
    frame_status_frame: int | None = None
    stability_class: str | None = None
    stability_frame: int | None = None
    stability_time: float | None = None
    n_negative: int | None = None
    n_zero: int | None = None
    stability_modes: str = ""
    modes: tuple = ()
    stability_counts: tuple = ()          # ((class, number of frames), ...) sorted by class
    unstable_frames: int = 0
    neutral_frames: int = 0
    singular: dict | None = None          # where a quasi-static run met a singular configuration

    @property
    def converged(self) -> bool:
        return self.status == STATUS_CONVERGED

    def as_dict(self) -> dict:
        """Plain JSON-ready dict (non-finite floats -> None, modes as dicts)."""
        d = {k: v for k, v in asdict(self).items() if k not in ("modes", "stability_counts")}
        d = {k: (_finite(v) if isinstance(v, float) else v) for k, v in d.items()}
        d["modes"] = [m.as_dict() for m in self.modes]
        d["stability_counts"] = dict(self.stability_counts)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "AnalysisSummary":
        """Inverse of :meth:`as_dict` (extra keys ignored)."""
        names = set(cls.__dataclass_fields__)
        kw = {k: v for k, v in d.items() if k in names}
        kw["modes"] = tuple(ModeRecord(m["class"], int(m["body"]), m["kind"],
                                       tuple(np.nan if x is None else float(x)
                                             for x in m["direction"]), m["eigenvalue"])
                            for m in d.get("modes") or ())
        kw["stability_counts"] = tuple(sorted((d.get("stability_counts") or {}).items()))
        return cls(**kw)


@dataclass(frozen=True)
class RunSummary:
    """Worst over the analyses of a run (``batch`` / ``sweep`` rows)."""
    status: str
    iterations: int | None
    imbalance: float | None
    imbalance_analysis: int | None
    imbalance_frame: int | None
    stability_class: str | None
    stability_analysis: int | None
    stability_frame: int | None
    n_negative: int | None
    n_zero: int | None
    stability_modes: str
    modes: tuple
    message: str
    analyses: tuple = field(default=())

    def row(self) -> dict:
        """The row fields (JSON-ready)."""
        return {"status": self.status, "iterations": self.iterations,
                "imbalance": _finite(self.imbalance),
                "imbalance_analysis": self.imbalance_analysis,
                "imbalance_frame": self.imbalance_frame,
                "stability_class": self.stability_class,
                "stability_analysis": self.stability_analysis,
                "stability_frame": self.stability_frame,
                "n_negative": self.n_negative, "n_zero": self.n_zero,
                "stability_modes": self.stability_modes,
                "modes": [m.as_dict() for m in self.modes], "message": self.message}


def _finite(x: Any) -> float | None:
    if x is None:
        return None
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _get(ds, key):
    v = ds.get(key) if hasattr(ds, "get") else None
    return None if v is None else np.asarray(v)


def _time(t, k):
    return None if t is None or k is None or k >= len(t) else _finite(t[k])


def _item(v, k, conv):
    return None if v is None or k >= len(v) else conv(v[k])


def _worst_value(v):
    """(max, its first frame) over the finite-or-inf entries of ``v`` (NaN ignored)."""
    if v is None or not len(v):
        return None, None
    v = np.asarray(v, float).ravel()
    ok = ~np.isnan(v)
    if not ok.any():
        return None, None
    k = int(np.flatnonzero(ok)[np.argmax(v[ok])])
    return float(v[k]), k


def summarize(a) -> AnalysisSummary:
    """The :class:`AnalysisSummary` of ``a``: an :class:`~poise.results.data.AnalysisResult`
    (or any object with ``index``, ``analysis_type``, ``method``, ``status``, ``message``,
    ``datasets`` and ``attrs``)."""
    ds = a.datasets
    attrs = getattr(a, "attrs", {}) or {}
    t = _get(ds, "time")
    n = 0 if t is None else int(len(t))
    it = _get(ds, "frames/iterations")
    if it is not None and len(it):
        iterations = int(np.sum(it))
    elif _get(ds, "iterations/iteration") is not None:
        iterations = int(len(_get(ds, "iterations/iteration")))
    else:
        iterations = int(attrs["iterations"]) if attrs.get("iterations") is not None else None
    imb, kimb = _worst_value(_get(ds, "frames/imbalance"))
    if imb is None and attrs.get("imbalance") is not None:
        imb = _finite(attrs.get("imbalance"))
    err, kerr = _worst_value(_get(ds, "frames/error"))
    fs, kfs = None, None
    st = _get(ds, "frames/status")
    conv = _get(ds, "frames/converged")
    if st is not None and len(st):
        bad = np.flatnonzero(~np.asarray(conv, bool)) if conv is not None and len(conv) == len(st) \
            else np.flatnonzero(np.asarray(st, str) != STATUS_CONVERGED)
        fs, kfs = (str(st[bad[0]]), int(bad[0])) if len(bad) else (STATUS_CONVERGED, None)
    stab: dict = {}
    cls = _get(ds, "frames/stability")
    counts: tuple = ()
    n_uns = n_neu = 0
    if cls is not None and len(cls):
        cls = np.asarray(cls, str)
        counts = tuple(sorted(Counter(cls.tolist()).items()))
        n_uns, n_neu = int(np.sum(cls == "unstable")), int(np.sum(cls == "neutral"))
        rank = np.array([STABILITY_RANK.get(c, STABILITY_RANK["unknown"]) for c in cls])
        worst = np.flatnonzero(rank == rank.max())
        nneg = _get(ds, "frames/n_negative")
        nzero = _get(ds, "frames/n_zero")
        text = _get(ds, "frames/stability_modes")
        k = int(worst[0])
        key = nneg if cls[k] == "unstable" else nzero if cls[k] == "neutral" else None
        if key is not None and len(key) == len(cls):
            k = int(worst[np.argmax(np.asarray(key)[worst])])
        stab = dict(stability_class=str(cls[k]) if cls[k] in STABILITY_RANK else "unknown",
                    stability_frame=k, stability_time=_time(t, k),
                    n_negative=_item(nneg, k, int), n_zero=_item(nzero, k, int),
                    stability_modes=_item(text, k, str) or "",
                    modes=_modes(ds, k))
    return AnalysisSummary(
        index=int(a.index), analysis_type=str(a.analysis_type), method=str(a.method),
        status=str(a.status), message=str(a.message or ""), frames=n, iterations=iterations,
        imbalance=imb, imbalance_frame=kimb, imbalance_time=_time(t, kimb),
        error=err, error_frame=kerr, error_time=_time(t, kerr),
        frame_status=fs, frame_status_frame=kfs, stability_counts=counts,
        unstable_frames=n_uns, neutral_frames=n_neu, singular=_singular(attrs), **stab)


def _singular(attrs) -> dict | None:
    """The ``singular`` summary entry from the analysis attributes ``singular_*``."""
    t = _finite(attrs.get("singular_time"))
    if t is None:
        return None
    try:
        elements = json.loads(attrs.get("singular_elements") or "[]")
    except (TypeError, ValueError):
        elements = []
    return {"time": t, "kind": str(attrs.get("singular_kind", "")), "elements": elements,
            "mode": str(attrs.get("singular_mode", "") or "")}


def _modes(ds, k) -> tuple:
    """Frame ``k``'s numeric modes (``modes/*``, flat in frame order, ``frames/n_modes``)."""
    n = _get(ds, "frames/n_modes")
    if n is None or k >= len(n) or _get(ds, "modes/body") is None:
        return ()
    a = int(np.sum(n[:k]))
    b = a + int(n[k])
    cls, kind = _get(ds, "modes/class"), _get(ds, "modes/kind")
    body, dirn = _get(ds, "modes/body"), _get(ds, "modes/direction")
    eig = _get(ds, "modes/eigenvalue")
    # a scalar unknown's name is only in the text (``unstable: <name>``, in the same order)
    text = _get(ds, "frames/stability_modes")
    parts = [p.split(": ", 1)[-1] for p in str(text[k]).split("; ")] \
        if text is not None and k < len(text) else []
    parts = [p for p in parts if not p.startswith("... ")]
    return tuple(ModeRecord(str(cls[j]), int(body[j]), str(kind[j]),
                            tuple(float(x) for x in dirn[j]), _finite(eig[j]),
                            parts[j - a] if str(kind[j]) == "coordinate" and
                            j - a < len(parts) else "")
                 for j in range(a, b))


def summarize_run(res) -> RunSummary:
    """Worst over the analyses of a :class:`~poise.results.data.RunResult`: iterations summed,
    the largest imbalance (with its analysis and frame), the worst stability class (the first
    analysis on ties), the failed analyses' messages."""
    sums = tuple(summarize(a) for a in res.analyses)
    its = [s.iterations for s in sums if s.iterations is not None]
    imb = [(s.imbalance, s.index, s.imbalance_frame) for s in sums if s.imbalance is not None]
    wi = max(imb, key=lambda x: x[0]) if imb else (None, None, None)
    st = [s for s in sums if s.stability_class is not None]
    ws = max(st, key=lambda s: STABILITY_RANK[s.stability_class]) if st else None
    msgs = [f"analysis {s.index}: {' '.join(s.message.split())}"
            for s in sums if not s.converged and s.message]
    return RunSummary(
        status=res.status, iterations=sum(its) if its else (0 if not sums else None),
        imbalance=wi[0], imbalance_analysis=wi[1], imbalance_frame=wi[2],
        stability_class=ws.stability_class if ws else None,
        stability_analysis=ws.index if ws else None,
        stability_frame=ws.stability_frame if ws else None,
        n_negative=ws.n_negative if ws else None, n_zero=ws.n_zero if ws else None,
        stability_modes=ws.stability_modes if ws else "", modes=ws.modes if ws else (),
        message="; ".join(msgs), analyses=sums)


# ------------------------------------------------------------------------------ text
def _num(x) -> str:
    return "n/a" if x is None else f"{x:.3g}"


def frame_at(frames: int, frame, time) -> str:
    """`` at frame 412 (t=0.41)`` naming a worst frame when there are several, else ``""``."""
    if frames <= 1 or frame is None:
        return ""
    return f" at frame {frame}" + ("" if time is None else f" (t={time:.6g})")


def equilibrium_phrase(s: AnalysisSummary) -> str:
    """``to an UNSTABLE equilibrium (2 negative modes: body 2 rotation about x, ...)`` for a
    converged analysis whose worst frame is unstable or neutral, else ``""``."""
    if not s.converged or s.stability_class not in ("unstable", "neutral"):
        return ""
    uns = s.stability_class == "unstable"
    count = s.n_negative if uns else s.n_zero
    word = "negative" if uns else "zero"
    what = [m.text(short=True) for m in s.modes if m.klass == s.stability_class]
    shown = what[:LINE_MODES]
    more = (count or 0) > len(shown)
    head = f"{count} {word} mode{'s' if count != 1 else ''}"
    detail = head + (": " + ", ".join(shown) if shown else "") + (", ..." if more and shown else "")
    frames = s.unstable_frames if uns else s.neutral_frames
    where = ""
    if s.frames > 1:
        where = f" at {frames} of {s.frames} frames"
        detail = f"worst frame {s.stability_frame}" + (
            "" if s.stability_time is None else f", t={s.stability_time:.6g}") + f": {detail}"
    return f"to {'an UNSTABLE' if uns else 'a NEUTRAL'} equilibrium{where} ({detail})"


def summary_line(s: AnalysisSummary, seconds: float | None = None, style=None) -> str:
    """``analysis 0: static FIM_S converged in 5 iterations, imbalance 3.2e-09, 0.012 s``;
    ``converged to an UNSTABLE equilibrium (...)`` when the worst frame is unstable (neutral
    likewise); the worst imbalance with its frame for several frames; ``: message`` when the
    analysis failed. ``style(status)`` may decorate the status word (colour)."""
    status = style(s.status) if style else s.status
    head = f"analysis {s.index}: {s.analysis_type} {s.method} {status}"
    eq = equilibrium_phrase(s)
    if eq:
        head += f" {eq}"
    if s.iterations is not None:
        verb = "in" if s.converged else "after"
        head += f" {verb} {s.iterations} iteration{'s' if s.iterations != 1 else ''}"
    if s.frames != 1:
        head += f" ({s.frames} frames)"
    parts = [head, f"imbalance {_num(s.imbalance)}"
             f"{frame_at(s.frames, s.imbalance_frame, s.imbalance_time)}"]
    if seconds is not None:
        parts.append(f"{seconds:.3g} s")
    line = ", ".join(parts)
    if not s.converged and s.message:
        line += f": {' '.join(s.message.split())}"
    return line
