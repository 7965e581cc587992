"""All-frames-at-once outputs (model/frame_batch.py, solvers/frames.py) equal the frame-by-frame
path entry by entry, on every example deck; expression batches tiled over frames evaluate each
instance at its own frame's time."""
from dataclasses import replace

import numpy as np
import pytest

from poise.deck.parser import load_deck
from poise.model.compile import compile_model
from poise.app.runner import plan
from poise.solvers.driver import Driver
from poise.results.layout import frame_datasets
from poise.solvers.frames import measure_frame, measure_frames
from poise.solvers.record import FrameSet
from poise.solvers.newton import FrameOutcome
from poise.solvers.status import Status

from support.paths import ROOT


DECKS = sorted(p for p in (ROOT / "decks").glob("*.xml")) + \
    sorted(p for p in (ROOT / "decks" / "bench").glob("*.xml") if "1000" not in p.name)
NOT_BATCHED = {"expr_reaction_load.xml"}          # forces read reactions: frame by frame
SKIP = {"expr_eval_error.xml"}                    # evaluation fails by design


def _frames(path, n=4, seed=0):
    spec = load_deck(path)
    model = compile_model(spec, user_code="run")   # the decks are ours
    drv = Driver(model, plan(spec, None)[0])
    st, _ = drv.run(model.initial_state())
    # what the frames are measured with: model, settings, active rows; the frames below are
    # off equilibrium on purpose; tolerances no frame misses keep them labelled converged
    # (certify), so the stability outputs are exercised too
    env = drv.env
    sa = (replace(env, settings=replace(env.settings, max_imbalance=1e30, max_error=1e30)),
          drv.redundancy)
    rng = np.random.default_rng(seed)
    frames = []
    for k in range(n):
        s = st.copy()
        s.t = 0.1 * k
        if k:      # off-equilibrium frames: every term of the residual and Jacobian is exercised
            s = model.retract(s, rng.normal(size=model.nq) * 1e-4 * model.L / model.q_scale)
            s.lam = st.lam * (1.0 + 0.1 * k)
        frames.append(s)
    outs = [FrameOutcome(Status.CONVERGED, 1, 0.0, 0.0, "ok") for _ in frames]
    return sa, frames, outs


def _per_frame(sa, frames, outs):
    return frame_datasets(FrameSet.concatenate([measure_frame(*sa, s, [o])
                                                for s, o in zip(frames, outs)]))


def _batched(sa, frames, outs):
    got = measure_frames(*sa, frames, outs)
    return None if got is None else frame_datasets(got)


@pytest.mark.parametrize("path", [p for p in DECKS if p.name not in SKIP | NOT_BATCHED],
                         ids=lambda p: p.name)
def test_batched_frames_equal_frame_by_frame(path):
    sa, frames, outs = _frames(path)
    got = _batched(sa, frames, outs)
    assert got is not None
    ref = _per_frame(sa, frames, outs)
    assert set(ref) <= set(got)
    degenerate = (ref["frames/n_negative"] + ref["frames/n_zero"]) > 1
    for key, r in ref.items():
        g = np.asarray(got[key])
        r = np.asarray(r)
        assert g.shape == r.shape, key
        if key == "frames/stability_modes":
            # eigenvectors of a repeated eigenvalue are any basis of its space
            g, r = g[~degenerate], r[~degenerate]
        elif key.startswith("modes/"):        # flat in frame order, n_modes per frame
            keep = np.repeat(~degenerate, ref["frames/n_modes"])
            g, r = g[keep], r[keep]
        if r.dtype.kind == "f":
            fin = np.isfinite(r)
            assert np.array_equal(fin, np.isfinite(g)), key
            assert np.array_equal(r[~fin], g[~fin], equal_nan=True), key
            scale = max(1.0, float(np.max(np.abs(r[fin])))) if fin.any() else 1.0
            assert np.max(np.abs(g[fin] - r[fin]), initial=0.0) <= 1e-9 * scale, key
        else:
            assert np.array_equal(g, r), key


def test_reaction_reading_forces_are_not_batched():
    sa, frames, outs = _frames(ROOT / "decks" / "expr_reaction_load.xml", n=2)
    assert measure_frames(*sa, frames, outs) is None


def test_time_dependent_expression_force_per_frame_time():
    """The ramp ``fx = -60 TIME`` on the slider evaluated for 3 frames in one call: the load
    output of each frame is its own time's value."""
    sa, frames, outs = _frames(ROOT / "decks" / "bench" / "slider_crank_qs.xml", n=3)
    for k, s in enumerate(frames):
        s.t = 0.25 * (k + 1)
    d = _batched(sa, frames, outs)
    k = list(d["forces/tag"]).index("Force_Vector_OneBody")
    fx = d["forces/force"][:, k, 0]
    assert np.allclose(fx, [-60.0 * 0.25, -60.0 * 0.5, -60.0 * 0.75], rtol=0, atol=1e-12)
