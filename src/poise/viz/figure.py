"""What every poise picture does the same way, so that it reads at the size users get.

* Legends sit outside the data, right of their panel (:func:`legend_outside`), and the figure
  uses matplotlib's constrained layout, which makes room for them: a legend never covers a
  point and is never cut off the image.
* Log axes show exact zeros (an exact start, an error of 0 against the reference) at a floor
  one decade below the smallest positive value, as hollow down-triangles named in the legend
  (:class:`LogFloor`), not as a gap.
* Horizontal reference lines at the same height (``max_imbalance = max_error``) are drawn with
  interleaved dashes, each in its own colour, so both stay visible (:func:`reference_lines`).
* Tick labels never overlap: short ``%g`` labels, and after a trial draw the minor labels, then
  every other major label, are dropped until none touch (:func:`readable_ticks`).
"""
from __future__ import annotations

import math

import numpy as np

#: points of one dash in interleaved reference lines (a group of k lines: period k dashes)
DASH = 5.0


def new_figure(plt, width: float, heights: list[float]):
    """A constrained-layout figure with one column of panels of relative ``heights`` (inches
    per unit height: the figure is ``width`` x ``sum(heights)``)."""
    fig, axes = plt.subplots(len(heights), 1, figsize=(width, sum(heights)), squeeze=False,
                             gridspec_kw=dict(height_ratios=heights), layout="constrained")
    return fig, list(axes[:, 0])


def legend_outside(ax, fontsize: float = 8, handles=None, labels=None):
    """The legend of ``ax`` right of the axes, top-aligned, in as many columns as its panel
    height needs (None when there is nothing to name)."""
    if handles is None:
        handles, labels = ax.get_legend_handles_labels()
    if not handles:
        return None
    h_in = ax.get_position().height * ax.figure.get_figheight()
    rows = max(3, int(h_in * 72 / (1.45 * fontsize)) - 1)       # lines that fit the panel
    return ax.legend(handles, labels, loc="upper left", bbox_to_anchor=(1.015, 1.0),
                     borderaxespad=0.0, fontsize=fontsize, ncol=math.ceil(len(handles) / rows))


class LogFloor:
    """Draws series on a log y axis with exact zeros at a floor: one decade below the smallest
    positive value of the panel (``values``, also the reference lines), rounded down to a
    power of ten."""

    def __init__(self, *values):
        pos = [np.abs(np.asarray(v, float)) for v in values]
        pos = np.concatenate([p[np.isfinite(p) & (p > 0)] for p in pos] or [np.zeros(0)])
        self.level = 10.0 ** (math.floor(math.log10(pos.min())) - 1) if pos.size else 1e-16
        self.used = False

    def plot(self, ax, x, y, fmt: str, **kw):
        """``ax.semilogy(x, |y|, fmt)`` with zeros drawn at the floor and marked; NaN (not
        computed) stays a gap. Returns the line."""
        x = np.asarray(x, float)
        y = np.abs(np.asarray(y, float))
        zero = y == 0
        ln, = ax.semilogy(x, np.where(zero, self.level, y), fmt, **kw)
        if zero.any():
            self.used = True
            ax.semilogy(x[zero], np.full(zero.sum(), self.level), "v", ls="none", ms=7,
                        color=ln.get_color(), mfc="none", mew=1.2,
                        zorder=ln.get_zorder() + 0.1)      # color given: the cycle stays
        return ln

    def legend_entry(self, ax) -> None:
        """One legend entry saying where zeros are drawn (when there were any)."""
        if self.used:
            ax.plot([], [], "v", ls="none", ms=7, color="0.35", mfc="none", mew=1.2,
                    label=f"exactly 0 (drawn at {self.level:.0e})")


def reference_lines(ax, lines) -> list:
    """Horizontal lines ``[(y, label, style)]``, drawn in order; lines at the same height share
    one dash pattern with shifted phases, so their colours alternate along it instead of hiding
    each other. Returns the Line2D objects."""
    out = []
    for i, (y, label, style) in enumerate(lines):
        same = [j for j, other in enumerate(lines) if math.isclose(other[0], y, rel_tol=1e-9)]
        style = dict(style)
        if len(same) > 1:
            style["ls"] = (same.index(i) * DASH, (DASH, DASH * (len(same) - 1)))
        out.append(ax.axhline(y, label=label, **style))
    return out


def readable_ticks(fig, axes=None) -> None:
    """Make the tick labels of ``axes`` (default: all) not overlap at the figure's size. Log x
    axes get short ``%g`` labels (``0.02``, ``1``), minor ones only where fewer than two decades
    are labelled; then, after a trial draw, every other label of an axis whose labels touch is
    left blank (minor labels first), until none touch."""
    from matplotlib.ticker import FuncFormatter, NullFormatter
    axes = fig.axes if axes is None else axes
    for ax in axes:
        if ax.xaxis.get_scale() == "log":
            ax.xaxis.set_major_formatter(FuncFormatter(_short))
            ax.xaxis.set_minor_formatter(FuncFormatter(_short))
    fig.canvas.draw()
    for ax in axes:
        if ax.xaxis.get_scale() == "log" and len(_labels(ax.xaxis, minor=False)) >= 2:
            ax.xaxis.set_minor_formatter(NullFormatter())
    for _ in range(8):
        fig.canvas.draw()
        bad = [axis for ax in axes for axis in (ax.xaxis, ax.yaxis) if overlapping(axis)]
        if not bad:
            return
        for axis in bad:
            minor = bool(_labels(axis, minor=True))
            get = axis.get_minor_formatter if minor else axis.get_major_formatter
            put = axis.set_minor_formatter if minor else axis.set_major_formatter
            put(_every(get(), 2))


def _labels(axis, minor: bool) -> list:
    """The visible, non-empty tick labels of ``axis`` inside its view."""
    lo, hi = sorted(axis.get_view_interval())
    k = 0 if axis.axis_name == "x" else 1
    ts = axis.get_minorticklabels() if minor else axis.get_majorticklabels()
    return [t for t in ts if t.get_visible() and t.get_text()
            and lo - 1e-12 * abs(lo) <= t.get_position()[k] <= hi + 1e-12 * abs(hi)]


_EVERY = []


def _every(base, k: int):
    """A matplotlib Formatter giving ``base``'s labels, only every ``k``-th one (the rest
    blank); the class is made on first use (matplotlib is imported only by the pictures)."""
    if not _EVERY:
        from matplotlib.ticker import Formatter

        class Every(Formatter):
            def __init__(self, base, k: int):
                self.base, self.k = base, k

            def set_axis(self, axis):
                super().set_axis(axis)
                self.base.set_axis(axis)

            def format_ticks(self, values):
                labels = self.base.format_ticks(values)
                return [lb if i % self.k == 0 else "" for i, lb in enumerate(labels)]

            def __call__(self, x, pos=None):
                return self.base(x, pos)

            def get_offset(self):
                return self.base.get_offset()

        _EVERY.append(Every)
    if isinstance(base, _EVERY[0]):
        return _EVERY[0](base.base, base.k * k)
    return _EVERY[0](base, k)


def overlapping(axis, pad: float = 2.0) -> bool:
    """Whether two visible tick labels of ``axis`` (major and minor) touch (renderer extents,
    ``pad`` pixels apart at least)."""
    r = axis.axes.figure.canvas.get_renderer()
    boxes = [t.get_window_extent(r) for t in [*_labels(axis, False), *_labels(axis, True)]]
    boxes.sort(key=lambda b: (b.x0, b.y0))
    for i, a in enumerate(boxes):
        for b in boxes[i + 1:]:
            if (a.x0 - pad < b.x1 and b.x0 - pad < a.x1 and a.y0 - pad < b.y1
                    and b.y0 - pad < a.y1):
                return True
    return False


def _short(v, _pos=None) -> str:
    """``0.4``, ``2``, ``1e-05``: a tick value in few characters."""
    return f"{v:g}"
