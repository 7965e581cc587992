"""``poise animate``: stick-figure animation of the iterations / frames of a results file."""
from __future__ import annotations

import click

from poise.core.wording import plural
from poise_cli.options import debug_option, json_option, quiet_option
from poise_cli.picture import run_picture


@click.command(short_help="Animate a results file as a stick figure (GIF, MP4 or PNG).")
@click.argument("results", type=click.Path(exists=True, dir_okay=False, readable=True))
@click.option("-o", "--out", required=True, type=click.Path(dir_okay=False),
              help="Output .gif (Pillow), .mp4 (needs ffmpeg) or .png (one frame).")
@click.option("--analysis", type=int, default=None, help="Analysis index (default: the last).")
@click.option("--frame", type=int, default=None,
              help="Only this frame (negative: from the end).")
@click.option("--every", type=click.IntRange(min=1), default=None, metavar="N",
              help="Draw every N-th frame (the last frame is always drawn); --every 1 draws "
                   "all. Default: at most 200 frames spread evenly over the run.")
@click.option("--max-frames", type=click.IntRange(min=1), default=None, metavar="N",
              help="At most N frames, spread evenly over the run (after --every).")
@click.option("--fps", type=click.IntRange(min=1), default=4, show_default=True)
@click.option("--no-graphics", is_flag=True,
              help="Ignore Post_Graphic geometry: draw every body as a stick figure.")
@quiet_option
@json_option
@debug_option
def animate(results, out, analysis, frame, every, max_frames, fps, no_graphics, quiet, as_json,
            debug):
    """Draw each body of RESULTS as its Post_Graphic geometry (spheres, boxes, planes) where the
    deck has some, else as its CG joined to every marker on it (axes in the deck's length unit): one picture per MKEAM iterate of a
    static MKEAM solve (then the final equilibrium), per recorded Newton/assembly iterate of
    another static solve (FIM_S and its fallbacks), or per output frame (quasi-static runs: per
    output time)."""
    ctx = click.get_current_context()
    def make():
        # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
        from poise.viz.animate import animate_results
        return animate_results(results, out, analysis=analysis, frame=frame, fps=fps,
                               graphics=not no_graphics, every=every, max_frames=max_frames,
                               progress=False if quiet else None)

    run_picture(ctx, results, make, as_json, debug, quiet,
                lambda info: f"wrote {out} ({plural(info['frames'], 'frame')}, "
                             f"{info['width']}x{info['height']}, plane {info['plane']})")
