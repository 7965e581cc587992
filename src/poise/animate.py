"""Stick-figure animation of a results file (``poise animate``).

Each moving body is drawn as its CG (dot) joined by lines to the joint points on it (the origins
of the joints' I and J markers, from ``/model/markers/*`` and ``/model/joints/*_marker``);
ground joint points are triangles. The drawing plane is the pair of global axes along which the
figure moves/extends most.

Frames: for a static MKEAM analysis, one per MKEAM iterate (``mkeam/iterate_position``: the
start and every restart) followed by the final equilibrium; otherwise one per output frame
(a quasi-static run: one per output time; a FIM_S static run: its single frame).
"""
from __future__ import annotations

import shutil

import numpy as np

from poise.errors import UsageError


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
    return pos, rot, labels


def _stick_segments(res, pos, rot):
    """Per frame: CG points (B,3), segments [(P, Q)], ground points."""
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
    for m in jm:
        if m in mk:
            b = mbody[mk[m]]
            links.append((col.get(b, -1), mk[m]))
    links = list(dict.fromkeys(links))

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


def animate_results(path: str, out: str, analysis: int | None = None, frame: int | None = None,
                    fps: int = 4, dpi: int = 80) -> dict:
    """Write the animation (``.gif`` via Pillow, ``.mp4`` via ffmpeg) or, with ``.png``, one
    frame. ``frame`` selects a single frame (negative counts from the end).

    Returns ``{"output", "frames", "width", "height", "plane"}``.
    """
    low = out.lower()
    if not low.endswith((".gif", ".mp4", ".png")):
        raise UsageError(f"--out {out!r}: expected a .gif, .mp4 or .png file")
    if low.endswith(".mp4") and shutil.which("ffmpeg") is None:
        raise UsageError("--out *.mp4 needs ffmpeg on PATH (not found); write a .gif instead")
    from poise.plot import _agg, pick_analysis
    from poise.results.hdf5 import read_results
    res = read_results(path)
    a = pick_analysis(res, analysis)
    pos, rot, labels = _frames(a)
    if pos.ndim != 3 or not len(pos) or not pos.shape[1]:
        raise UsageError(f"{path}: analysis {a.index} has no body positions to draw")
    idx = list(range(len(pos)))
    if frame is not None:
        if not -len(idx) <= frame < len(idx):
            raise UsageError(f"--frame {frame}: the animation has {len(idx)} frames "
                             f"(0..{len(idx) - 1})")
        idx = [idx[frame]]
    if low.endswith(".png") and len(idx) > 1:
        idx = [idx[-1]]
    draw = _stick_segments(res, pos, rot)
    # drawing plane: the two global axes with the largest extent over all frames
    pts = [pos.reshape(-1, 3)]
    for f in idx:
        _, segs, g = draw(f)
        pts += [np.asarray([q for _, q in segs]).reshape(-1, 3), g]
    allp = np.concatenate(pts)
    ext = np.nanmax(allp, axis=0) - np.nanmin(allp, axis=0)
    ax2 = sorted(np.argsort(-ext, kind="stable")[:2].tolist())
    names = "XYZ"
    lo, hi = np.nanmin(allp[:, ax2], axis=0), np.nanmax(allp[:, ax2], axis=0)
    pad = 0.08 * max(float(np.max(hi - lo)), 1e-9)
    plt = _agg()
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.set_xlabel(f"global {names[ax2[0]]}")
    ax.set_ylabel(f"global {names[ax2[1]]}")
    ax.grid(True, lw=0.3)
    lines = []
    cg, = ax.plot([], [], "o", color="C0", ms=6, zorder=3)
    gr, = ax.plot([], [], "^", color="k", ms=8, zorder=2)
    title = ax.set_title("")

    def render(f):
        for ln in lines:
            ln.remove()
        lines.clear()
        P, segs, g = draw(f)
        for p, q in segs:
            lines.extend(ax.plot([p[ax2[0]], q[ax2[0]]], [p[ax2[1]], q[ax2[1]]], "-", color="C1",
                                 lw=2))
        cg.set_data(P[:, ax2[0]], P[:, ax2[1]])
        gr.set_data(g[:, ax2[0]] if len(g) else [], g[:, ax2[1]] if len(g) else [])
        title.set_text(f"analysis {a.index} ({a.method}): {labels[f]}  [{f + 1}/{len(pos)}]")
        return [cg, gr, title, *lines]

    if low.endswith(".png"):
        render(idx[0])
        fig.savefig(out, dpi=dpi)
    else:
        from matplotlib.animation import FFMpegWriter, FuncAnimation, PillowWriter
        anim = FuncAnimation(fig, render, frames=idx, blit=False)
        writer = PillowWriter(fps=fps) if low.endswith(".gif") else FFMpegWriter(fps=fps)
        anim.save(out, writer=writer, dpi=dpi)
    w, h = (fig.get_size_inches() * dpi).round().astype(int).tolist()
    plt.close(fig)
    return {"output": out, "frames": len(idx), "width": w, "height": h,
            "plane": names[ax2[0]] + names[ax2[1]]}
