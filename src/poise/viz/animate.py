"""Stick-figure animation of a results file (``poise animate``).

Each moving body is drawn as its CG (dot) joined by lines to every marker on it (joint points,
force points, a pendulum's tip: ``/model/markers/*``); ground joint points (``/model/joints/
*_marker``) are triangles. Axes are labelled with the deck's length unit. Bodies with ``Post_Graphic`` geometry (``/model/graphics/*``)
are drawn as that geometry instead of sticks: spheres as circles, boxes as the convex hull of
their 8 projected corners, planes as a line (their trace in the drawing plane); ground graphics
are drawn fixed. The drawing plane is the pair of global axes along which the figure
moves/extends most.

Frames: for a static MKEAM analysis, one per MKEAM iterate (``mkeam/iterate_position``: the
start and every restart) followed by the final equilibrium; for another static analysis (FIM_S,
fallback strategies) one per recorded iterate (``iterations/position``: assembly and Newton
iterates, every ``iterations_poses_stride``-th when subsampled); otherwise one per output frame
(a quasi-static run: one per output time; an older static file without iterate poses: its
single frame).
"""
from __future__ import annotations

import shutil

import numpy as np

from poise.core.atomic import atomic_output
from poise.core.errors import UsageError
from poise.core.extras import require
from poise.core.progress import Bar
from poise.results.hdf5 import read_results
from poise.viz.plot import agg_pyplot, pick_analysis, units_of


def _frames(a):
    d = a.datasets
    pos = np.asarray(d.get("bodies/position", np.zeros((0, 0, 3))), float)
    rot = np.asarray(d.get("bodies/orientation", np.zeros((0, 0, 3, 3))), float)
    labels = [f"t = {t:.4g}" for t in np.asarray(d.get("time", np.zeros(len(pos))), float)]
    if "mkeam/iterate_position" in d and a.analysis_type == "static":
        ip = np.asarray(d["mkeam/iterate_position"], float)
        io = np.asarray(d["mkeam/iterate_orientation"], float)
        labels = [f"MKEAM iterate {k}" for k in range(len(ip))] + ["final equilibrium"]
        pos, rot = np.concatenate([ip, pos[-1:]]), np.concatenate([io, rot[-1:]])
    elif "iterations/position" in d and a.analysis_type == "static":
        ip = np.asarray(d["iterations/position"], float)
        io = np.asarray(d["iterations/orientation"], float)
        rows = np.asarray(d.get("iterations/pose_row", np.arange(len(ip))), int)
        ev = np.asarray(d.get("iterations/event", []), dtype=str)
        it = np.asarray(d.get("iterations/iteration", []), int)
        keep = [k for k in range(len(ip)) if np.all(np.isfinite(ip[k]))]
        if keep and ip.shape[1:] == pos.shape[1:]:
            pos, rot = ip[keep], io[keep]
            labels = [f"{ev[rows[k]]} iteration {it[rows[k]]}" if rows[k] < len(ev)
                      else f"iterate {k}" for k in keep]
    return pos, rot, labels


def _graphics(res):
    """``[(kind, body column or -1, offset, axes, radius, half)]`` from ``/model/graphics``."""
    md = res.model_datasets
    if "graphics/id" not in md:
        return []
    bids = [int(x) for x in np.asarray(md.get("bodies/id", []))]
    col = {b: k for k, b in enumerate(bids)}
    out = []
    for k, kind in enumerate(np.asarray(md["graphics/type"], dtype=str)):
        b = int(md["graphics/body_id"][k])
        c = col.get(b, -1)
        if b != -1 and c < 0:
            continue
        out.append((str(kind), c, np.asarray(md["graphics/offset"][k], float),
                    np.asarray(md["graphics/axes"][k], float), float(md["graphics/radius"][k]),
                    np.asarray(md["graphics/half_length"][k], float)))
    return out


_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)


def _place(g, P, R):
    """Global centre and axes of graphic ``g`` at a frame."""
    _, c, off, A, _, _ = g
    if c < 0:
        return off, A
    return P[c] + R[c] @ off, R[c] @ A


def _graphic_points(g, P, R):
    """Points that bound graphic ``g`` (for the drawing plane and axis limits)."""
    kind, _, _, _, r, half = g
    ctr, A = _place(g, P, R)
    if kind == "sphere":
        return ctr + np.vstack([np.eye(3), -np.eye(3)]) * r
    if kind == "box":
        return ctr + _SIGNS * half @ A.T
    return ctr[None]


def _draw_graphic(ax, g, P, R, ax2, span):
    """Matplotlib artists for graphic ``g`` projected on the global axes ``ax2``."""
    from matplotlib.patches import Circle, Polygon
    kind, _, _, _, r, half = g
    ctr, A = _place(g, P, R)
    i, j = ax2
    if kind == "sphere":
        return [ax.add_patch(Circle((ctr[i], ctr[j]), r, fill=True, fc="C0", alpha=0.35,
                                    ec="C0", lw=1.5, zorder=2))]
    if kind == "box":
        q = (ctr + _SIGNS * half @ A.T)[:, [i, j]]
        try:
            from scipy.spatial import ConvexHull
            poly = q[ConvexHull(q).vertices]
        except Exception:   # degenerate (edge-on, zero size): draw the 12 edges
            arts = []
            for a_ in range(8):
                for b_ in range(a_ + 1, 8):
                    if np.sum(_SIGNS[a_] != _SIGNS[b_]) == 1:
                        arts += ax.plot(q[[a_, b_], 0], q[[a_, b_], 1], "-", color="C2", lw=1.5)
            return arts
        return [ax.add_patch(Polygon(poly, closed=True, fc="C2", alpha=0.35, ec="C2", lw=1.5,
                                     zorder=2))]
    # plane: its trace in the drawing plane, direction normal x viewing axis
    k = 3 - i - j
    d = np.cross(A[:, 2], np.eye(3)[k])[[i, j]]
    if np.linalg.norm(d) < 1e-12:
        return []      # the plane is the drawing plane itself: nothing to draw
    d = d / np.linalg.norm(d)
    c2 = ctr[[i, j]]
    p, q = c2 - span * d, c2 + span * d
    return ax.plot([p[0], q[0]], [p[1], q[1]], "-", color="0.3", lw=2.5, zorder=1)


def _stick_segments(res, pos, rot, skip=()):
    """Per frame: CG points (B,3), segments [(P, Q)], ground points (no sticks on the body
    columns in ``skip``)."""
    md = res.model_datasets
    bids = [int(x) for x in np.asarray(md.get("bodies/id", []))]
    col = {b: k for k, b in enumerate(bids)}
    mids = [int(x) for x in np.asarray(md.get("markers/id", []))]
    mbody = [int(x) for x in np.asarray(md.get("markers/body_id", []))]
    moff = np.asarray(md.get("markers/offset", np.zeros((0, 3))), float)
    mk = {m: k for k, m in enumerate(mids)}
    jm = [int(x) for x in np.asarray(md.get("joints/i_marker", []))] + \
        [int(x) for x in np.asarray(md.get("joints/j_marker", []))]
    links = []   # (body column or -1, marker index)
    for m in jm:                       # ground: joint points only
        if m in mk and col.get(mbody[mk[m]], -1) < 0:
            links.append((-1, mk[m]))
    for k, b in enumerate(mbody):      # moving bodies: every marker on them
        c = col.get(b, -1)
        if c >= 0 and np.linalg.norm(moff[k]) > 0:
            links.append((c, k))
    links = [lk for lk in dict.fromkeys(links) if lk[0] < 0 or lk[0] not in skip]

    def frame(f):
        P = pos[f]
        segs, ground = [], []
        for c, k in links:
            if c < 0:
                ground.append(moff[k])
            else:
                q = P[c] + rot[f, c] @ moff[k]
                segs.append((P[c], q))
        return P, segs, np.asarray(ground).reshape(-1, 3)

    return frame


#: frames drawn when neither ``every`` nor ``max_frames`` is given (a 1001-frame run: 200
#: pictures, not a 250 s GIF that takes a minute to render)
DEFAULT_MAX_FRAMES = 200


def pick_frames(n: int, every: int | None = None, max_frames: int | None = None) -> list[int]:
    """Every ``every``-th of ``n`` frames, then at most ``max_frames`` of those spread evenly;
    the last frame (the equilibrium) is always kept. Neither given: at most
    :data:`DEFAULT_MAX_FRAMES` spread evenly (``every=1`` alone: all frames)."""
    if every is None and max_frames is None:
        max_frames = DEFAULT_MAX_FRAMES
    every = 1 if every is None else every
    if every < 1 or (max_frames is not None and max_frames < 1):
        raise UsageError("--every and --max-frames must be at least 1")
    idx = list(range(0, n, every))
    if idx and idx[-1] != n - 1:
        idx.append(n - 1)
    if max_frames is not None and len(idx) > max_frames:
        keep = np.unique(np.round(np.linspace(0, len(idx) - 1, max_frames)).astype(int))
        idx = [idx[k] for k in keep]
    return idx


def animate_results(path: str, out: str, analysis: int | None = None, frame: int | None = None,
                    fps: int = 4, dpi: int = 80, graphics: bool = True,
                    every: int | None = None, max_frames: int | None = None,
                    progress: bool | None = None,
                    keep_figure: bool = False) -> dict:
    """Write the animation (``.gif`` via Pillow, ``.mp4`` via ffmpeg) or, with ``.png``, one
    frame. ``frame`` selects a single frame (negative counts from the end); ``every`` /
    ``max_frames`` thin the frames (:func:`pick_frames`; neither: at most 200 spread evenly,
    ``every=1``: all). ``graphics=False`` ignores
    ``/model/graphics`` (stick figure only). ``progress``: the frames bar
    (:mod:`poise.core.progress`; False: none).

    Returns ``{"output", "frames", "width", "height", "plane", "graphics"}`` (``graphics``: the
    number of Post_Graphic artists drawn in the last rendered frame); with ``keep_figure`` also
    ``"figure"``: the matplotlib Figure as last drawn (the caller closes it).
    """
    require("plot")             # exit 2 with the pip command in a lean install
    low = out.lower()
    if not low.endswith((".gif", ".mp4", ".png")):
        raise UsageError(f"--out {out!r}: expected a .gif, .mp4 or .png file")
    if low.endswith(".mp4") and shutil.which("ffmpeg") is None:
        raise UsageError("--out *.mp4 needs ffmpeg on PATH (not found); write a .gif instead")
    res = read_results(path)
    a = pick_analysis(res, analysis)
    pos, rot, labels = _frames(a)
    if pos.ndim != 3 or not len(pos) or not pos.shape[1]:
        raise UsageError(f"{path}: analysis {a.index} has no body positions to draw")
    idx = list(range(len(pos)))
    if frame is None:
        idx = pick_frames(len(pos), every, max_frames)
    else:
        if not -len(idx) <= frame < len(idx):
            raise UsageError(f"--frame {frame}: the animation has {len(idx)} frames "
                             f"(0..{len(idx) - 1})")
        idx = [idx[frame]]
    if low.endswith(".png") and len(idx) > 1:
        idx = [idx[-1]]
    gfx = _graphics(res) if graphics else []
    draw = _stick_segments(res, pos, rot, skip={g[1] for g in gfx if g[1] >= 0})
    # drawing plane: the two global axes with the largest extent over all frames
    pts = [pos.reshape(-1, 3)]
    for f in idx:
        _, segs, g = draw(f)
        pts += [np.asarray([q for _, q in segs]).reshape(-1, 3), g]
        pts += [_graphic_points(gr_, pos[f], rot[f]) for gr_ in gfx]
    allp = np.concatenate(pts)
    allp = allp[np.isfinite(allp).all(axis=1)]       # NaN/Inf positions are not drawn
    if not len(allp):
        raise UsageError(f"{path}: analysis {a.index} has no finite body positions to draw")
    ext = np.nanmax(allp, axis=0) - np.nanmin(allp, axis=0)
    ax2 = sorted(np.argsort(-ext, kind="stable")[:2].tolist())
    names = "XYZ"
    lo, hi = np.nanmin(allp[:, ax2], axis=0), np.nanmax(allp[:, ax2], axis=0)
    pad = 0.08 * max(float(np.max(hi - lo)), 1e-9)
    span = 2.0 * float(np.max(hi - lo)) + 20 * pad + float(np.max(np.abs(np.r_[lo, hi])))
    plt = agg_pyplot()
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    unit = units_of(res.units)["length"]
    ax.set_xlabel(f"global {names[ax2[0]]} [{unit}]")
    ax.set_ylabel(f"global {names[ax2[1]]} [{unit}]")
    ax.grid(True, lw=0.3)
    lines = []
    drawn = [0]
    cg, = ax.plot([], [], "o", color="C0", ms=6, zorder=3)
    gr, = ax.plot([], [], "^", color="k", ms=8, zorder=2)
    title = ax.set_title("")

    bar = Bar(len(idx), "animate", "frames", enabled=progress)
    rendered = set()

    def render(f):
        if f not in rendered:          # matplotlib draws the first frame twice
            rendered.add(f)
            bar.step()
        for ln in lines:
            ln.remove()
        lines.clear()
        P, segs, g = draw(f)
        arts = []
        for gr_ in gfx:
            arts += _draw_graphic(ax, gr_, pos[f], rot[f], ax2, span)
        drawn[0] = len(arts)
        lines.extend(arts)
        for p, q in segs:
            lines.extend(ax.plot([p[ax2[0]], q[ax2[0]]], [p[ax2[1]], q[ax2[1]]], "-", color="C1",
                                 lw=2))
        cg.set_data(P[:, ax2[0]], P[:, ax2[1]])
        gr.set_data(g[:, ax2[0]] if len(g) else [], g[:, ax2[1]] if len(g) else [])
        title.set_text(f"analysis {a.index} ({a.method}): {labels[f]}  [{f + 1}/{len(pos)}]")
        return [cg, gr, title, *lines]

    with bar, atomic_output(out, (path,), keep_suffix=True) as tmp:
        if low.endswith(".png"):
            render(idx[0])
            fig.savefig(tmp, dpi=dpi)
        else:
            from matplotlib.animation import FFMpegWriter, FuncAnimation, PillowWriter
            anim = FuncAnimation(fig, render, frames=idx, blit=False, cache_frame_data=False)
            writer = PillowWriter(fps=fps) if low.endswith(".gif") else FFMpegWriter(fps=fps)
            anim.save(tmp, writer=writer, dpi=dpi)
    w, h = (fig.get_size_inches() * dpi).round().astype(int).tolist()
    info = {"output": out, "frames": len(idx), "width": w, "height": h,
            "plane": names[ax2[0]] + names[ax2[1]], "graphics": drawn[0]}
    if keep_figure:
        info["figure"] = fig
    else:
        plt.close(fig)
    return info
