"""poise plot / poise animate: files written, decoded, pixel sizes checked."""
from __future__ import annotations

import json
import shutil

import h5py
import matplotlib.image as mpimg
import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from poise_cli.main import cli

from support.paths import DECKS


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    d = tmp_path_factory.mktemp("res")
    out = {}
    for name in ("pendulum_multiturn", "mkeam_pendulum_multiturn", "qs_slider_crank_rev",
                 "contact_sphere_plane"):
        p = d / f"{name}.h5"
        r = CliRunner().invoke(cli, ["solve", str(DECKS / f"{name}.xml"), "-o", str(p), "-q"])
        assert r.exit_code == 0, r.output
        out[name] = p
    return out


def _inv(*args):
    return CliRunner().invoke(cli, [*map(str, args)])


def test_plot_png_sizes(results, tmp_path):
    png = tmp_path / "a.png"
    r = _inv("plot", results["pendulum_multiturn"], "--out", png, "--json")
    assert r.exit_code == 0, r.output
    info = json.loads(r.stdout)
    assert info["panels"] == ["convergence"]
    img = mpimg.imread(png)
    assert img.shape[:2] == (info["height"], info["width"]) == (320, 1000)
    r = _inv("plot", results["mkeam_pendulum_multiturn"], "--out", png, "--json")
    info = json.loads(r.stdout)
    assert info["panels"] == ["convergence", "kinetic_energy"]
    assert mpimg.imread(png).shape[:2] == (640, 1000)
    r = _inv("plot", results["qs_slider_crank_rev"], "--out", png, "--json", "--bodies", "2,3",
             "--joints", "1")
    info = json.loads(r.stdout)
    # quasi-static: per-frame convergence + a short iterations-per-frame panel (0.55 height)
    assert info["panels"] == ["convergence", "iterations", "bodies/position", "joints/force"]
    with Image.open(png) as im:
        assert im.size == (1000, 1136)
    # usage errors: unknown id, not a results file
    assert _inv("plot", results["qs_slider_crank_rev"], "--out", png, "--bodies", "99").exit_code == 2
    bad = tmp_path / "x.h5"
    bad.write_text("nope")
    assert _inv("plot", bad, "--out", png).exit_code == 2


def test_animate_gif_png_and_mp4(results, tmp_path):
    gif = tmp_path / "m.gif"
    r = _inv("animate", results["mkeam_pendulum_multiturn"], "--out", gif, "--json")
    assert r.exit_code == 0, r.output
    info = json.loads(r.stdout)
    with Image.open(gif) as im:
        assert im.size == (info["width"], info["height"]) == (480, 480)
        assert im.n_frames == info["frames"] >= 3   # MKEAM iterates + final equilibrium
    gif2 = tmp_path / "q.gif"
    r = _inv("animate", results["qs_slider_crank_rev"], "--out", gif2, "--json")
    info = json.loads(r.stdout)
    with Image.open(gif2) as im:
        assert im.n_frames == info["frames"] == 51 and im.size == (480, 480)
        im.seek(im.n_frames - 1)
        im.load()
    png = tmp_path / "f.png"
    r = _inv("animate", results["qs_slider_crank_rev"], "--out", png, "--frame", "10")
    assert r.exit_code == 0 and png.stat().st_size > 0
    assert mpimg.imread(png).shape[:2] == (480, 480)
    assert _inv("animate", results["qs_slider_crank_rev"], "--out", png,
                "--frame", "99").exit_code == 2
    mp4 = tmp_path / "a.mp4"
    r = _inv("animate", results["qs_slider_crank_rev"], "--out", mp4)
    if shutil.which("ffmpeg") is None:
        assert r.exit_code == 2 and "ffmpeg" in r.stderr
    else:
        assert r.exit_code == 0 and mp4.stat().st_size > 0


def test_fims_iterate_poses_one_frame_per_iterate(results, tmp_path):
    with h5py.File(results["pendulum_multiturn"], "r") as f:
        a = f["analysis_000"]
        assert a.attrs["method"] == "FIM_S"
        n = a["iterations/iteration"].shape[0]
        pos, rot = a["iterations/position"][()], a["iterations/orientation"][()]
        B = a["bodies/position"].shape[1]
        assert n >= 3 and pos.shape == (n, B, 3) and rot.shape == (n, B, 3, 3)
        assert list(a["iterations/pose_row"][()]) == list(range(n))
        assert int(a.attrs["iterations_poses_stride"]) == 1
        assert np.all(np.isfinite(pos))
        np.testing.assert_allclose(pos[-1], a["bodies/position"][-1], atol=1e-12)
        assert not np.allclose(pos[0], pos[-1])      # the iterates move
    gif = tmp_path / "it.gif"
    r = _inv("animate", results["pendulum_multiturn"], "--out", gif, "--json")
    assert r.exit_code == 0, r.output
    info = json.loads(r.stdout)
    with Image.open(gif) as im:
        assert im.n_frames == info["frames"] == n


def test_history_pose_rows_and_memory_bound():
    from poise.results.layout import history_datasets
    from poise.solvers.history import History
    h = History()
    h.add(0, 0, 1.0, 1.0, event="fallback: x")                  # no pose yet -> NaN
    h.add(0, 0, 1.0, 1.0, pos=np.zeros((2, 3)), rot=np.tile(np.eye(3), (2, 1, 1)))
    h.add(0, 1, 1.0, 1.0, event="fallback: y")                  # repeats the previous pose
    d = history_datasets(h)
    assert d["iterations/position"].shape == (3, 2, 3)
    assert np.isnan(d["iterations/position"][0]).all() and (d["iterations/position"][2] == 0).all()
    assert h.pose_stride == 1
    assert "iterations/position" not in history_datasets(History())   # no poses: none emitted
    h = History()
    h.MAX_POSE_VALUES = 12 * 2 * 10                             # room for 10 poses of 2 bodies
    for k in range(101):
        h.add(0, k, 0.0, 0.0, pos=np.full((2, 3), k), rot=np.tile(np.eye(3), (2, 1, 1)))
    d = history_datasets(h)
    k = h.pose_stride
    assert k > 1 and len(d["iterations/position"]) <= 11
    rows = d["iterations/pose_row"]
    assert rows[-1] == 100 and all(r % k == 0 for r in rows[:-1])
    np.testing.assert_array_equal(d["iterations/position"][:, 0, 0], rows)


def test_contact_deck_draws_post_graphics(results, tmp_path):
    from poise.viz.animate import animate_results
    p = results["contact_sphere_plane"]
    with h5py.File(p, "r") as f:
        g = f["model/graphics"]
        assert sorted(g["type"].asstr()[()]) == ["plane", "sphere"]
        k = list(g["type"].asstr()[()]).index("sphere")
        assert g["radius"][k] == 50.0 and g["body_id"][k] == 2
    gif = tmp_path / "c.gif"
    info = animate_results(str(p), str(gif))
    assert info["graphics"] == 2                 # sphere circle + floor line
    with Image.open(gif) as im:
        assert im.n_frames == info["frames"] >= 2
    a, b = tmp_path / "g.png", tmp_path / "s.png"
    assert animate_results(str(p), str(a))["graphics"] == 2
    assert animate_results(str(p), str(b), graphics=False)["graphics"] == 0
    ia, ib = mpimg.imread(a), mpimg.imread(b)
    assert ia.shape == ib.shape and np.abs(ia - ib).sum() > 1000   # the sphere is drawn
    r = _inv("animate", p, "--out", b, "--no-graphics", "--json")
    assert r.exit_code == 0 and json.loads(r.stdout)["graphics"] == 0
