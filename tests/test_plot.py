"""poise plot / poise animate: files written, decoded, pixel sizes checked."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import matplotlib.image as mpimg
import pytest
from click.testing import CliRunner
from PIL import Image

from poise_cli.main import cli

DECKS = Path(__file__).resolve().parents[1] / "decks"


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    d = tmp_path_factory.mktemp("res")
    out = {}
    for name in ("pendulum_multiturn", "mkeam_pendulum_multiturn", "qs_slider_crank_rev"):
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
    assert img.shape[:2] == (info["height"], info["width"]) == (320, 800)
    r = _inv("plot", results["mkeam_pendulum_multiturn"], "--out", png, "--json")
    info = json.loads(r.stdout)
    assert info["panels"] == ["convergence", "kinetic_energy"]
    assert mpimg.imread(png).shape[:2] == (640, 800)
    r = _inv("plot", results["qs_slider_crank_rev"], "--out", png, "--json", "--bodies", "2,3",
             "--joints", "1")
    info = json.loads(r.stdout)
    assert info["panels"] == ["convergence", "bodies/position", "joints/force"]
    with Image.open(png) as im:
        assert im.size == (800, 960)
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
