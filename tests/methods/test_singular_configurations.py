"""Quasi-static paths at singular configurations, against closed forms (tests/support/linkages):
a converged frame stays on its assembly branch (a slider driven to 0.4 mm short of the toggle
and back, a delta-like parallel robot driven next to its workspace boundary and back), and a
path that reaches a singular configuration fails there, located in time and named (the toggle
of a slider-crank, a slider driven beyond the reach of its linkage, the dead point of a
four-bar, the boundary of the delta robot, the limit point of a von Mises truss, the
bifurcation of a loaded column), a jump that persists (a load stepping past the limit point)
fails its frame, and --require-stable follows the stable branch (from an unstable start too),
both with FIM_S and FIM_D."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from poise.app.api import run_deck

from support.linkages import (
    COLUMN,
    DELTA,
    SC_L,
    SC_R,
    column,
    column_critical_time,
    crank_angle,
    delta,
    delta_boundary_angle,
    delta_height,
    fourbar,
    fourbar_dead_time,
    loaded_slide,
    slider_crank,
    VM,
    vonmises,
    vonmises_limit_time,
)

METHODS = ["FIM_S", "FIM_D"]
POISE = str(Path(sys.executable).parent / "poise")


def _solve(tmp_path, deck, name="deck.xml", **overrides):
    path = deck.write(tmp_path / name)
    res = run_deck(path, overrides=overrides)
    return res, res.analyses[0]


def _crank_angles(a):
    pos = np.asarray(a.datasets["bodies/position"])
    ids = list(np.asarray(a.datasets["bodies/id"]))
    A = 2.0 * pos[:, ids.index(2), :2]                # crank CG at mid-length
    return np.arctan2(A[:, 1], A[:, 0]), pos[:, ids.index(4), 0]


def _singular(a):
    assert a.status == "failed", a.message
    st = np.asarray(a.datasets["frames/status"])
    assert st[-1] == "singular_configuration", (st[-1], a.message)
    assert not np.asarray(a.datasets["frames/converged"])[-1]
    assert all(s == "converged" for s in st[:-1])
    return a.attrs


# ------------------------------------------------------------------ on the branch
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("drive,interval", [("300+99.6*SIN(PI*TIME)", 0.1),
                                            ("399.6-99.6*ABS(2*TIME-1)", 0.02)])
def test_slider_near_the_toggle_and_back_stays_on_its_branch(tmp_path, method, drive, interval):
    """0.4 mm short of the toggle (x = r + l = 400 mm) and back: every frame is on the upper
    branch, cos(theta) = (x^2 + r^2 - l^2) / (2 x r); the crank ends where it started."""
    res, a = _solve(tmp_path, slider_crank(drive, method, interval))
    assert res.exit_code == 0 and a.status == "converged", a.message
    theta, x = _crank_angles(a)
    assert x.max() == pytest.approx(399.6, abs=1e-6)
    np.testing.assert_allclose(theta, crank_angle(x), atol=1e-7)
    assert theta.min() > math.radians(4.4)                  # the closest approach: 4.44 deg
    assert theta[-1] == pytest.approx(theta[0], abs=1e-7)


@pytest.mark.parametrize("method", METHODS)
def test_delta_robot_next_to_its_boundary_and_back_keeps_its_assembly(tmp_path, method):
    """The arms swing from 90 deg to 1 deg short of the workspace boundary (forearms
    horizontal) and back: the platform height follows the lower assembly at every frame
    (closed form), nothing moves a mechanism size between frames, and it ends where it
    started."""
    amp = 90.0 - delta_boundary_angle() - 1.0
    res, a = _solve(tmp_path, delta(f"-{amp!r}D*SIN(PI*TIME)", method, interval=0.1))
    assert res.exit_code == 0 and a.status == "converged", a.message
    t = np.asarray(a.datasets["time"])
    pos = np.asarray(a.datasets["bodies/position"])
    ids = list(np.asarray(a.datasets["bodies/id"]))
    theta = np.radians(90.0 - amp * np.sin(np.pi * t))
    np.testing.assert_allclose(pos[:, ids.index(10), 2], delta_height(theta), atol=1e-6)
    size = 2 * (DELTA["rb"] + DELTA["a"])                  # 180 mm across
    assert np.linalg.norm(np.diff(pos, axis=0), axis=2).max() < 0.25 * size
    np.testing.assert_allclose(pos[-1], pos[0], atol=1e-6)


# ------------------------------------------------------------------ where the path ends
@pytest.mark.parametrize("method", METHODS)
def test_slider_driven_through_the_toggle_is_singular_at_the_closed_form_time(tmp_path, method):
    """x = 300 + 150 t reaches r + l = 400 mm at t = 2/3: singular there, the crank pin named
    as the joint that folds, the constraints of the loop in the self-stress."""
    res, a = _solve(tmp_path, slider_crank("300+150*TIME", method))
    assert res.exit_code == 1
    attrs = _singular(a)
    assert attrs["singular_kind"] == "dead_point"
    assert attrs["singular_time"] == pytest.approx(2.0 / 3.0, abs=1e-6)
    els = json.loads(attrs["singular_elements"])
    assert (els[0]["tag"], els[0]["id"], els[0]["label"], els[0].get("fold")) == \
        ("Constraint_Joint", 2, "Crank pin", True)
    assert {(e["tag"], e["id"]) for e in els} >= {("Constraint_Joint", 1),
                                                   ("Constraint_Joint", 3),
                                                   ("Motion_Joint", 1)}
    assert "singular configuration at t = 0.666667: Joint 2 (Crank pin) at a dead point" \
        in a.message
    # the last frame is the state where the branch ends: the crank next to theta = 0
    theta, x = _crank_angles(a)
    assert x[-1] == pytest.approx(SC_R + SC_L, abs=1e-3)
    assert abs(theta[-1]) < 2e-3
    np.testing.assert_allclose(theta[:-1], crank_angle(x[:-1]), atol=1e-7)


@pytest.mark.parametrize("method", METHODS)
def test_slider_beyond_reach_fails_as_a_singular_configuration(tmp_path, method):
    """x = 300 + 200 t: past r + l at t = 0.5 (an output time). The failure names the dead
    point, not the iteration budget, and the fallback chain is not run."""
    res, a = _solve(tmp_path, slider_crank("300+200*TIME", method))
    attrs = _singular(a)
    assert attrs["singular_time"] == pytest.approx(0.5, abs=1e-6)
    assert "max_num_iter" not in a.message and "MKEAM" not in a.message
    strategies = set(np.asarray(a.datasets["iterations/strategy"]).tolist())
    assert strategies == {"plain"}


@pytest.mark.parametrize("method", METHODS)
def test_fourbar_driven_to_its_dead_point(tmp_path, method):
    """Crank-rocker four-bar (a, b, c, d) = (40, 120, 80, 100) mm, all revolute (3 redundant
    equations), rocker driven down from 90 deg at 60 deg/s: the crank and coupler align at
    cos(phi) = ((a + b)^2 - d^2 - c^2) / (2 d c)."""
    res, a = _solve(tmp_path, fourbar(60.0, method))
    attrs = _singular(a)
    assert attrs["singular_time"] == pytest.approx(fourbar_dead_time(60.0), abs=1e-6)
    els = json.loads(attrs["singular_elements"])
    assert (els[0]["id"], els[0]["label"]) == (2, "Crank pin")
    assert len(np.asarray(a.datasets["redundant/id"])) == 3


@pytest.mark.parametrize("method", METHODS)
def test_delta_robot_driven_to_its_boundary(tmp_path, method):
    """The arms at -60 deg/s from 90 deg: the forearms are horizontal at
    cos(theta) = (l - rb + rp) / a; every frame before is on the closed form."""
    res, a = _solve(tmp_path, delta("-60D*TIME", method))
    attrs = _singular(a)
    t_star = (90.0 - delta_boundary_angle()) / 60.0
    assert attrs["singular_time"] == pytest.approx(t_star, abs=1e-6)
    assert attrs["singular_kind"] == "dead_point"
    t = np.asarray(a.datasets["time"])[:-1]
    pos = np.asarray(a.datasets["bodies/position"])
    np.testing.assert_allclose(pos[:-1, 0, 2], delta_height(np.radians(90.0 - 60.0 * t)),
                               atol=1e-6)


@pytest.mark.parametrize("method", METHODS)
def test_von_mises_truss_limit_point(tmp_path, method):
    res, a = _solve(tmp_path, vonmises(method))
    attrs = _singular(a)
    assert attrs["singular_kind"] == "limit_point"
    assert attrs["singular_time"] == pytest.approx(vonmises_limit_time(), abs=1e-6)
    assert "body 2 translation along y" in attrs["singular_mode"]


@pytest.mark.parametrize("method", METHODS)
def test_loaded_column_bifurcation(tmp_path, method):
    """The upright column stays an equilibrium for every load, but its stiffness k - P l
    changes sign at P = k / l: a bifurcation, located at the closed-form time."""
    res, a = _solve(tmp_path, column(method))
    attrs = _singular(a)
    assert attrs["singular_kind"] == "bifurcation"
    assert attrs["singular_time"] == pytest.approx(column_critical_time(), abs=1e-6)
    assert attrs["singular_mode"] == "body 2 rotation about z"
    t = np.asarray(a.datasets["time"])
    cls = np.asarray(a.datasets["frames/stability"])
    assert set(cls[t < column_critical_time() - 1e-6].tolist()) == {"stable"}


@pytest.mark.parametrize("method", METHODS)
def test_a_stiffness_that_jumps_is_no_singular_configuration(tmp_path, method):
    """The block's stiffness jumps from +1000 to -1000 N/m at t = 0.5 (an IF of TIME): the
    classification changes between frames, but no eigenvalue passes through zero, so the run
    goes on (unstable frames after 0.5, said as such)."""
    res, a = _solve(tmp_path, loaded_slide("-1000*IF(TIME-0.5: 1, 1, -1)*DX(200,100)", method))
    assert res.exit_code == 0 and a.status == "converged", a.message
    t = np.asarray(a.datasets["time"])
    assert list(np.asarray(a.datasets["frames/stability"])) == \
        ["stable" if x <= 0.5 + 1e-9 else "unstable" for x in t]
    assert "singular_time" not in a.attrs


@pytest.mark.parametrize("method", METHODS)
def test_a_load_that_jumps_past_the_limit_point_fails_the_frame(tmp_path, method):
    """The truss's load steps from 1 N to twice its limit load at t = 0.5: no equilibrium on
    the branch is left (only the snapped-through one, far away), so the frame after the step
    is a failed frame (``step_too_small``, exit 1), never a converged one; the frames before
    sit on the closed form P(y) = k y (L0 / sqrt(a^2 + y^2) - 1) = 1 N."""
    p_max = VM["c"] * vonmises_limit_time()
    text = vonmises(method).text()
    jumped = text.replace('fy_expression="-40.0*TIME"',
                          f'fy_expression="-IF(TIME-0.5: 1.0, 1.0, {2.0 * p_max!r})"')
    assert jumped != text
    path = tmp_path / "vm_step.xml"
    path.write_text(jumped)
    res = run_deck(str(path))
    a = res.analyses[0]
    assert res.exit_code == 1 and a.status == "failed"
    st = np.asarray(a.datasets["frames/status"])
    t = np.asarray(a.datasets["time"])
    assert st[-1] == "step_too_small" and t[-1] == pytest.approx(0.6)
    assert all(s == "converged" for s in st[:-1]) and t[-2] == pytest.approx(0.5)
    assert not np.asarray(a.datasets["frames/converged"])[-1]
    assert "not on the branch" in a.message or "path jumps" in a.message
    y = np.asarray(a.datasets["bodies/position"])[:-1, 0, 1]
    L0 = math.hypot(VM["a"], VM["h"])
    load = VM["k"] * y * (L0 / np.sqrt(VM["a"] ** 2 + y * y) - 1.0)
    np.testing.assert_allclose(load, 1.0, rtol=1e-6)
    assert np.all(y > 0.0)                                   # the upper branch


# ------------------------------------------------------------------ --require-stable
@pytest.mark.parametrize("method", METHODS)
def test_require_stable_ends_where_the_column_loses_stability(tmp_path, method):
    res, a = _solve(tmp_path, column(method), require_stable=True)
    assert res.exit_code == 1 and a.status == "failed"
    st = np.asarray(a.datasets["frames/status"])
    assert st[-1] == "unstable" and all(s == "converged" for s in st[:-1])
    assert a.attrs["singular_time"] == pytest.approx(column_critical_time(), abs=1e-6)
    assert "stability lost at t = 0.5" in a.message
    assert np.asarray(a.datasets["time"])[-1] == pytest.approx(column_critical_time(), abs=1e-6)


@pytest.mark.parametrize("method", METHODS)
def test_require_stable_on_a_stable_path_converges(tmp_path, method):
    """Below the critical load the column is stable at every frame: --require-stable passes
    (and is applied: every frame is classified stable)."""
    res, a = _solve(tmp_path, column(method, p=dict(l=500.0, k=1e5, c=100.0)),
                    require_stable=True)
    assert res.exit_code == 0, a.message
    assert set(np.asarray(a.datasets["frames/stability"]).tolist()) == {"stable"}


@pytest.mark.parametrize("method", METHODS)
def test_require_stable_from_an_unstable_start_follows_the_buckled_branch(tmp_path, method):
    """The column starts loaded past its critical load (P = 300 + 100 t N > k / l = 200 N): the
    upright start is unstable. Without --require-stable every frame is the upright equilibrium,
    said to be unstable (exit 0, nothing hidden); with it, frame 0 descends to the buckled
    equilibrium and the run follows that stable branch: theta / sin(theta) = P l / k, one side
    throughout."""
    from scipy.optimize import brentq

    text = column(method).text()
    loaded = text.replace('fy_expression="-400.0*TIME"', 'fy_expression="-(300+100*TIME)"')
    assert loaded != text
    path = tmp_path / "column_loaded.xml"
    path.write_text(loaded)
    res = run_deck(str(path))
    a = res.analyses[0]
    assert res.exit_code == 0, a.message
    assert set(np.asarray(a.datasets["frames/stability"]).tolist()) == {"unstable"}
    res = run_deck(str(path), overrides={"require_stable": True})
    a = res.analyses[0]
    assert res.exit_code == 0 and a.status == "converged", a.message
    assert set(np.asarray(a.datasets["frames/stability"]).tolist()) == {"stable"}
    t = np.asarray(a.datasets["time"])
    R = np.asarray(a.datasets["bodies/orientation"])[:, 0]
    theta = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    l, k = COLUMN["l"], COLUMN["k"]
    want = [brentq(lambda x, c=(300.0 + 100.0 * ti) * l / k: x / math.sin(x) - c, 1e-9, 3.1)
            for ti in t]
    assert np.all(np.sign(theta) == np.sign(theta[0]))
    np.testing.assert_allclose(np.abs(theta), want, atol=1e-6)


# ------------------------------------------------------------------ what a user sees
def test_cli_reports_the_singular_configuration(tmp_path):
    deck = slider_crank("300+150*TIME", "FIM_S").write(tmp_path / "sc.xml")
    out = tmp_path / "sc.h5"
    r = subprocess.run([POISE, "solve", deck, "-o", str(out), "--json"], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 1, r.stderr
    assert "singular configuration at t = 0.666667: Joint 2 (Crank pin) at a dead point" \
        in r.stderr
    an = json.loads(r.stdout)["analyses"][0]
    assert an["frame_status"] == "singular_configuration"
    sing = an["singular"]
    assert sing["kind"] == "dead_point" and sing["time"] == pytest.approx(2 / 3, abs=1e-6)
    assert [e["label"] for e in sing["elements"]][0] == "Crank pin"
    show = subprocess.run([POISE, "show", str(out), "--json"], capture_output=True, text=True,
                          timeout=120)
    assert json.loads(show.stdout)["analyses"][0]["singular"]["elements"] == sing["elements"]
    text = subprocess.run([POISE, "show", str(out)], capture_output=True, text=True,
                          timeout=120).stdout
    assert "singular configuration at t = 0.666667" in text
