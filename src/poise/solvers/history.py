"""Per-iteration history, recorded as data: a table with the declared :data:`COLUMNS`.

Rows may carry the body poses of the iterate (``pos`` (B, 3), ``rot`` (B, 3, 3)):
:meth:`History.poses` gives one per history row (a row recorded without a pose repeats the
previous recorded pose, NaN before the first). Memory is bounded: once ``B x 12 x stored rows``
would exceed :attr:`History.MAX_POSE_VALUES`, only every ``k``-th pose-bearing row (k doubling
as needed) and the last one are kept, with the history rows they belong to and
``pose_stride = k``. :mod:`poise.results.layout` writes the table (``iterations/*``).

A row is a :class:`Row`. The frame-level strategies return theirs from their steps and the
loop (:func:`poise.solvers.iterate.iterate`) appends them; the fallback chain labels the rows
of each of its stages by running it on a :meth:`History.stage` view.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

COLUMNS = ("frame", "iteration", "imbalance", "error", "step_norm", "step_length",
           "worst_equation", "event", "strategy")

#: MKEAM's own columns (an MKEAM analysis writes them: NaN / -1 on the rows of other solvers)
MKEAM_COLUMNS = ("kinetic_energy", "peak_time", "max_dq", "potential_energy",
                 "integrator_steps")

#: ``iterations/strategy`` values: the recovery stage a row belongs to (``plain``: the method as
#: requested, no recovery; the others are the fallback chain's strategies, solvers/fallback.py)
STRATEGIES = ("plain", "stability", "continuation", "mkeam", "polish")


@dataclass(frozen=True)
class Row:
    """One ``iterations/*`` row: what one iteration (or one event) of a solver did.

    ``imbalance``: largest force/moment residual; ``error``: constraint error or last update
    (relative); ``step_norm`` / ``step_length``: the scaled step and its line-search factor;
    ``worst_equation``: the equation furthest from its tolerance (or a message);
    ``event``: what the row is (``newton``, ``assembly``, ``continuation mu=...``,
    ``fallback: ...``); ``strategy``: the recovery stage (:data:`STRATEGIES`). ``pos`` /
    ``rot``: the pose of the iterate the row measured (optional, not kept on the row).
    ``mkeam``: an MKEAM iteration's :data:`MKEAM_COLUMNS` values. ``measured_at``: output
    frame whose output evaluation gives the row's imbalance, error and worst equation (FIM_D's
    interpolated frames: the frame is certified there; :meth:`History.columns`).
    """

    frame: int
    iteration: int
    imbalance: float = np.nan
    error: float = np.nan
    step_norm: float = np.nan
    step_length: float = np.nan
    worst_equation: str = ""
    event: str = "newton"
    strategy: str = "plain"
    pos: np.ndarray | None = None
    rot: np.ndarray | None = None
    mkeam: tuple | None = None
    measured_at: int | None = None

    def columns(self) -> tuple:
        """The row's :data:`COLUMNS` values, typed as they are stored."""
        return (int(self.frame), int(self.iteration), float(self.imbalance), float(self.error),
                float(self.step_norm), float(self.step_length), str(self.worst_equation),
                str(self.event), str(self.strategy))


class _Rows:
    """What records rows: ``append(row)``; :meth:`add` builds the :class:`Row`."""

    def append(self, row: Row) -> None:
        raise NotImplementedError

    def add(self, frame, iteration, imbalance, error, step_norm=np.nan, step_length=np.nan,
            worst_equation="", event="newton", pos=None, rot=None, mkeam=None,
            measured_at=None):
        """Record a row given by its fields (the driver-level rows: sub-steps, FIM_D, MKEAM)."""
        self.append(Row(frame, iteration, imbalance, error, step_norm, step_length,
                        worst_equation, event, pos=pos, rot=rot, mkeam=mkeam,
                        measured_at=measured_at))

    def stage(self, name: str) -> "Staged":
        """A view that labels every row recorded through it ``name`` (a fallback stage)."""
        return Staged(self, name)


class History(_Rows):
    """Append-only table of solver iterations (every frame, every method)."""

    MAX_POSE_VALUES = 5_000_000     # float values (12 per body per stored pose)

    def __init__(self):
        self.rows: list[tuple] = []
        self._poses: dict[int, tuple] = {}     # history row -> (pos, rot), subsampled
        self._last_pose: tuple | None = None   # (row, pos, rot) of the newest pose, always kept
        self._n_posed = 0                      # pose-bearing rows seen
        self.pose_stride = 1
        self._mkeam: dict[int, tuple] = {}     # history row -> its MKEAM columns
        self._measured: dict[int, int] = {}    # history row -> output frame measuring it

    def append(self, row: Row) -> None:
        """Record ``row`` (its pose, if any, subsampled as the module says)."""
        self.rows.append(row.columns())
        if row.mkeam is not None:
            self._mkeam[len(self.rows) - 1] = tuple(row.mkeam)
        if row.measured_at is not None:
            self._measured[len(self.rows) - 1] = int(row.measured_at)
        if row.pos is not None and row.rot is not None:
            self._add_pose(len(self.rows) - 1, row.pos, row.rot)

    def _add_pose(self, row, pos, rot):
        p = np.array(pos, dtype=float, copy=True).reshape(-1, 3)
        r = np.array(rot, dtype=float, copy=True).reshape(-1, 3, 3)
        self._last_pose = (row, p, r)
        k = self._n_posed
        self._n_posed += 1
        if k % self.pose_stride:
            return
        self._poses[row] = (k, p, r)
        per = 12 * max(len(p), 1)
        while len(self._poses) > 1 and len(self._poses) * per > self.MAX_POSE_VALUES:
            self.pose_stride *= 2
            self._poses = {rw: v for rw, v in self._poses.items() if v[0] % self.pose_stride == 0}

    def __len__(self):
        return len(self.rows)

    def poses(self):
        """The recorded poses: ``(rows, position (R, B, 3), orientation (R, B, 3, 3))``, one
        per history row when every pose is kept (a row without a pose repeats the previous
        one, NaN before the first), else only the kept rows (``rows`` names them); None when
        no row carried a pose."""
        if self._last_pose is None:
            return None
        poses = {rw: (p, r) for rw, (_, p, r) in self._poses.items()}
        lr, lp, lrot = self._last_pose
        poses[lr] = (lp, lrot)
        B = lp.shape[0]
        if self.pose_stride == 1:
            rows = list(range(len(self.rows)))
            P = np.full((len(rows), B, 3), np.nan)
            R = np.full((len(rows), B, 3, 3), np.nan)
            cur = None
            for i in rows:
                if i in poses and poses[i][0].shape[0] == B:
                    cur = poses[i]
                if cur is not None:
                    P[i], R[i] = cur
        else:
            rows = sorted(poses)
            P = np.stack([poses[i][0] for i in rows])
            R = np.stack([poses[i][1] for i in rows])
        return np.asarray(rows, dtype=np.int64), P, R

    def drop_frames_after(self, k: int) -> None:
        """Output frames after ``k`` were dropped (a path cut at a singular configuration):
        rows recorded ``measured_at`` them keep what they recorded."""
        self._measured = {i: f for i, f in self._measured.items() if f <= k}

    def columns(self, measures=None) -> dict:
        """The table: one array per :data:`COLUMNS` name (int, float or str, as declared).
        ``measures``: per output frame ``(imbalance, constraint error, worst equation)`` as
        its output evaluation measured it (None where it was not): the rows recorded
        ``measured_at`` a frame show those."""
        rows = self.rows
        if measures is not None and self._measured:
            rows = list(rows)
            for i, k in self._measured.items():
                if k < len(measures) and measures[k] is not None:
                    imb, cerr, worst = measures[k]
                    r = rows[i]
                    rows[i] = r[:2] + (float(imb), float(cerr)) + r[4:6] + (str(worst),) + r[7:]
        cols = list(zip(*rows)) if rows else [[] for _ in COLUMNS]
        out = {}
        for name, col in zip(COLUMNS, cols):
            if name in ("frame", "iteration"):
                out[name] = np.asarray(col, dtype=np.int64)
            elif name in ("worst_equation", "event", "strategy"):
                out[name] = np.asarray(col, dtype=str) if len(col) else np.zeros(0, dtype=str)
            else:
                out[name] = np.asarray(col, dtype=float)
        return out


    def mkeam_columns(self) -> dict:
        """One array per :data:`MKEAM_COLUMNS` name over every row (NaN, and -1 integrator
        steps, on the rows that are not MKEAM iterations)."""
        n = len(self.rows)
        out = {k: np.full(n, np.nan) for k in MKEAM_COLUMNS[:-1]}
        out["integrator_steps"] = np.full(n, -1, dtype=np.int64)
        for row, vals in self._mkeam.items():
            for k, v in zip(MKEAM_COLUMNS, vals):
                out[k][row] = v
        return out


class Staged(_Rows):
    """A view of a :class:`History` whose rows get the strategy ``name`` (a fallback stage):
    ``rows`` and ``len`` are the underlying history's."""

    def __init__(self, history: History, name: str):
        self.base = history.base if isinstance(history, Staged) else history
        self.name = name

    @property
    def rows(self):
        return self.base.rows

    def __len__(self):
        return len(self.base)

    def append(self, row: Row) -> None:
        self.base.append(replace(row, strategy=self.name))

    def stage(self, name: str) -> "Staged":
        return Staged(self.base, name)


class Buffer(_Rows):
    """Rows collected in order (``rows``) for a solver's step to hand to the loop: the nested
    loops of the step append here, the step returns ``tuple(buffer.rows)``."""

    def __init__(self):
        self.rows: list[Row] = []

    def __len__(self):
        return len(self.rows)

    def append(self, row: Row) -> None:
        self.rows.append(row)
