"""Compliance matrix (GTCMAT, Param_Static compliance_delta) against closed forms.

Block (i, j) of ``frames/compliance``: displacement (3 translations, 3 small rotations, global)
of marker i per unit force / torque at marker j, of the constrained system.
"""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

import poise

IDENT = 'a00="1" a10="0" a20="0" a01="0" a11="1" a21="0" a02="0" a12="0" a22="1"'
INERTIA = ('inertia_xx="0.01" inertia_yy="0.01" inertia_zz="0.01" inertia_xy="0" '
           'inertia_yz="0" inertia_xz="0"')


def deck(body: str, param: str = "", sim: str = 'analysis_type="Static"') -> str:
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<MotionSolve>
  <Model>
    <Param_Static method="FIM_S" max_imbalance="1.0E-8" max_error="1.0E-10" {param}/>
    <Body_Rigid id="1" isground="TRUE" cg_id="10"/>
    <Reference_Marker id="10" body_id="1" pos_x="0" pos_y="0" pos_z="0" {IDENT}/>
{body}
  </Model>
  <Command>
    <Simulate {sim}/>
    <Stop/>
  </Command>
</MotionSolve>
"""


def marker(mid, body, x, y, z):
    return (f'    <Reference_Marker id="{mid}" body_id="{body}" pos_x="{x}" pos_y="{y}" '
            f'pos_z="{z}" {IDENT}/>\n')


K_SPRING = 400.0


def spring_mass(redundant=False) -> str:
    """Body 2 on a translational joint along Z, spring k to ground (free length = 1)."""
    b = marker(20, 2, 0, 0, 1) + marker(21, 2, 0, 0, 1) + marker(11, 1, 0, 0, 0)
    b += marker(12, 1, 0, 0, 0)
    b += f'    <Body_Rigid id="2" cg_id="20" mass="2.0" {INERTIA}/>\n'
    b += '    <Constraint_Joint id="1" type="TRANSLATIONAL" i_marker_id="21" j_marker_id="11"/>\n'
    if redundant:
        b += ('    <Constraint_Joint id="2" type="TRANSLATIONAL" i_marker_id="20" '
              'j_marker_id="12"/>\n')
    b += (f'    <Force_SpringDamper id="1" type="TRANSLATIONAL" i_marker_id="20" j_marker_id="11" '
          f'stiffness="{K_SPRING}" damping="0" length="1.0" preload="0"/>\n')
    return b


M_BOB, ELL, GRAV = 2.0, 0.5, 9.81


def pendulum(up=False, gravity=True, redundant=False) -> str:
    """Revolute joint (axis Z) at the origin, bob (mass M_BOB, CG) at distance ELL below
    (``up``: above) it; gravity -Y."""
    y = ELL if up else -ELL
    b = marker(20, 2, 0, y, 0) + marker(21, 2, 0, 0, 0) + marker(11, 1, 0, 0, 0)
    b += f'    <Body_Rigid id="2" cg_id="20" mass="{M_BOB}" {INERTIA}/>\n'
    b += '    <Constraint_Joint id="1" type="REVOLUTE" i_marker_id="21" j_marker_id="11"/>\n'
    if redundant:
        b += marker(22, 2, 0, 0, 0) + marker(12, 1, 0, 0, 0)
        b += ('    <Constraint_Joint id="2" type="REVOLUTE" i_marker_id="22" '
              'j_marker_id="12"/>\n')
    if gravity:
        b += f'    <Force_Gravity grav_x="0" grav_y="{-GRAV}" grav_z="0"/>\n'
    return b


def solve_text(tmp_path, text, name="d.xml", **kw):
    p = tmp_path / name
    p.write_text(text)
    r = poise.solve(str(p), **kw)
    a = r.analyses[0]
    assert a.status == "converged", a.message
    return a


def test_spring_mass_axis_is_one_over_k_rest_constrained(tmp_path):
    a = solve_text(tmp_path, deck(spring_mass()), compliance_markers="auto")
    assert list(a.datasets["compliance/marker_id"]) == [20]
    C = a.datasets["frames/compliance"]
    assert C.shape == (1, 6, 6)
    expect = np.zeros((6, 6))
    expect[2, 2] = 1.0 / K_SPRING
    np.testing.assert_allclose(C[0], expect, atol=1e-9)
    assert a.datasets["frames/compliance_flag"][0] == "ok"
    assert str(a.datasets["compliance/method"]) == "exact"


def test_spring_mass_redundant_joint_same_compliance(tmp_path):
    a = solve_text(tmp_path, deck(spring_mass(redundant=True)), compliance_markers="all")
    assert len(a.datasets["redundant/id"]) > 0          # the second joint is redundant
    C = a.datasets["frames/compliance"][0]
    expect = np.zeros((6, 6))
    expect[2, 2] = 1.0 / K_SPRING
    np.testing.assert_allclose(C, expect, atol=1e-9)


def pendulum_expected(up=False):
    """Bob block from the 1-DOF hinge angle theta (bob at y = -l, or +l when ``up``):
    stiffness k = +-m g l; a force Fx at the bob has a moment about the hinge:
    down: x = l theta, Mz = l Fx; up: x = -l theta, Mz = -l Fx; theta = (Mz + Tz) / k."""
    mg = M_BOB * GRAV
    s = -1.0 if up else 1.0               # x = s l theta, Mz = s l Fx
    k = s * mg * ELL
    E = np.zeros((6, 6))
    E[0, 0] = (s * ELL) * (s * ELL) / k   # dx/dFx
    E[5, 5] = 1.0 / k                     # dtheta/dTz
    E[0, 5] = s * ELL / k                 # dx/dTz
    E[5, 0] = s * ELL / k                 # dtheta/dFx
    return E


def test_pendulum_lateral_compliance_geometric_stiffness(tmp_path):
    a = solve_text(tmp_path, deck(pendulum(), 'compliance_markers="20"'))
    C = a.datasets["frames/compliance"][0]
    np.testing.assert_allclose(C, pendulum_expected(), rtol=1e-8, atol=1e-10)


def test_pendulum_marker_off_the_cg_lever_arms(tmp_path):
    """Marker 23 at 2l below the hinge on the bob's body (lever l from its CG): a hinge
    rotation theta moves it by 2 l theta and a force there has moment 2 l F."""
    body = pendulum() + marker(23, 2, 0, -2 * ELL, 0)
    a = solve_text(tmp_path, deck(body, 'compliance_markers="20 23"'))
    C = a.datasets["frames/compliance"][0]
    k = M_BOB * GRAV * ELL                         # hinge stiffness
    arm = np.array([ELL, 2 * ELL])                 # x = arm theta, Mz = arm Fx
    for i in range(2):
        for j in range(2):
            blk = C[6 * i:6 * i + 6, 6 * j:6 * j + 6]
            assert blk[0, 0] == pytest.approx(arm[i] * arm[j] / k, rel=1e-8)
            assert blk[0, 5] == pytest.approx(arm[i] / k, rel=1e-8)      # x_i per Tz_j
            assert blk[5, 0] == pytest.approx(arm[j] / k, rel=1e-8)      # theta per Fx_j
            assert blk[5, 5] == pytest.approx(1.0 / k, rel=1e-8)
            assert np.abs(blk[1:5, 1:5]).max() < 1e-12
    fd = solve_text(tmp_path, deck(body, 'compliance_markers="20 23" compliance_method="FD"'))
    assert np.max(np.abs(fd.datasets["frames/compliance"][0] - C)) <= 1e-3 * np.abs(C).max()


def test_pendulum_redundant_hinge_same_compliance(tmp_path):
    a = solve_text(tmp_path, deck(pendulum(redundant=True)), compliance_markers="all")
    assert len(a.datasets["redundant/id"]) > 0
    ids = list(a.datasets["compliance/marker_id"])
    C = a.datasets["frames/compliance"][0]
    k = ids.index(20)
    np.testing.assert_allclose(C[6 * k:6 * k + 6, 6 * k:6 * k + 6], pendulum_expected(),
                               rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize("make", [lambda: spring_mass(), lambda: pendulum()])
def test_exact_and_fd_agree(tmp_path, make):
    text = deck(make())
    ex = solve_text(tmp_path, text, compliance_markers="all")
    fd = solve_text(tmp_path, text, compliance_markers="all", compliance_method="fd")
    assert str(fd.datasets["compliance/method"]) == "fd"
    assert fd.attrs["compliance_delta"] == pytest.approx(1e-3)
    Ce, Cf = ex.datasets["frames/compliance"][0], fd.datasets["frames/compliance"][0]
    # forward difference with delta = 1e-3: error O(delta) relative to the largest entry
    assert np.max(np.abs(Ce - Cf)) <= 1e-3 * np.max(np.abs(Ce))


def test_cantilever_beam_tip_compliance(tmp_path):
    """Force_Beam (Timoshenko, shear factor ASY) from ground to a tip body, unloaded."""
    L, E, G, A, izz, asy = 0.3, 2.1e11, 8.1e10, 2e-3, 4.1667e-7, 1.2
    b = marker(20, 2, L, 0, 0) + marker(21, 2, L, 0, 0) + marker(12, 1, 0, 0, 0)
    b += f'    <Body_Rigid id="2" cg_id="20" mass="1.0" {INERTIA}/>\n'
    b += (f'    <Force_Beam id="2" i_marker_id="21" j_marker_id="12" length="{L}" E="{E}" '
          f'G="{G}" area="{A}" ixx="5.0E-7" iyy="2.6667E-7" izz="{izz}" ASY="{asy}" ASZ="1.1" '
          'cratio="0"/>\n')
    a = solve_text(tmp_path, deck(b, 'compliance_markers="21"'))
    C = a.datasets["frames/compliance"][0]
    EI = E * izz
    assert C[1, 1] == pytest.approx(L ** 3 / (3 * EI) + asy * L / (G * A), rel=1e-6)
    assert C[5, 5] == pytest.approx(L / EI, rel=1e-6)
    assert C[1, 5] == pytest.approx(L ** 2 / (2 * EI), rel=1e-6)
    assert C[5, 1] == pytest.approx(L ** 2 / (2 * EI), rel=1e-6)
    assert C[0, 0] == pytest.approx(L / (E * A), rel=1e-6)            # axial


def test_unstable_equilibrium_written_with_flag(tmp_path):
    a = solve_text(tmp_path, deck(pendulum(up=True), 'compliance_markers="20"'))
    assert a.datasets["frames/stability"][0] == "unstable"
    assert a.datasets["frames/compliance_flag"][0] == "unstable"
    np.testing.assert_allclose(a.datasets["frames/compliance"][0], pendulum_expected(up=True),
                               rtol=1e-8, atol=1e-10)


def test_free_mechanism_direction_is_nan(tmp_path):
    """No gravity: the hinge rotation is free; lateral and about-Z entries are NaN, the axial
    (along the rod) and the constrained directions stay 0."""
    a = solve_text(tmp_path, deck(pendulum(gravity=False), 'compliance_markers="20"'))
    assert a.datasets["frames/compliance_flag"][0] == "singular"
    assert "1 frame singular" in a.attrs["compliance_note"]
    C = a.datasets["frames/compliance"][0]
    assert np.isnan(C[0, 0]) and np.isnan(C[5, 5]) and np.isnan(C[0, 5])
    assert C[1, 1] == pytest.approx(0.0, abs=1e-12)                  # along the rod
    assert C[2, 2] == pytest.approx(0.0, abs=1e-12)                  # out of plane
    assert C[1, 2] == pytest.approx(0.0, abs=1e-12)


def test_quasistatic_every_frame(tmp_path):
    a = solve_text(tmp_path, deck(spring_mass(),
                                  sim='analysis_type="Static" end_time="1.0" print_interval="0.25"'),
                   compliance_markers="all")
    C = a.datasets["frames/compliance"]
    assert C.shape == (5, 6, 6)
    np.testing.assert_allclose(C[:, 2, 2], 1.0 / K_SPRING, rtol=1e-9)


@pytest.mark.parametrize("method", ["FIM_S", "FIM_D"])
def test_quasistatic_pendulum_frames_geometric_stiffness(tmp_path, method):
    """Batched frames (stacked Jacobians) give the 1-DOF closed form at every frame."""
    text = deck(pendulum(), 'compliance_markers="20"',
                sim='analysis_type="Static" end_time="1.0" print_interval="0.5"')
    a = solve_text(tmp_path, text, method=method)
    C = a.datasets["frames/compliance"]
    assert C.shape == (3, 6, 6)
    for k in range(3):
        np.testing.assert_allclose(C[k], pendulum_expected(), rtol=1e-7, atol=1e-10)


def test_deck_attributes_select_fd(tmp_path):
    a = solve_text(tmp_path, deck(spring_mass(), 'compliance_method="FD" compliance_delta="1e-4" '
                                                  'compliance_markers="20, 11"'))
    assert str(a.datasets["compliance/method"]) == "fd"
    assert a.attrs["compliance_delta"] == pytest.approx(1e-4)
    assert list(a.datasets["compliance/marker_id"]) == [20, 11]
    C = a.datasets["frames/compliance"][0]
    assert C[2, 2] == pytest.approx(1.0 / K_SPRING, rel=1e-6)
    np.testing.assert_allclose(C[6:], 0.0, atol=1e-12)


def test_none_by_default_and_bad_marker(tmp_path):
    """The matrix is computed on request only (as MotionSolve's GTCMAT): not by default."""
    a = solve_text(tmp_path, deck(spring_mass()))
    assert "frames/compliance" not in a.datasets and "compliance/marker_id" not in a.datasets
    assert "not requested" in a.attrs["compliance_note"]
    a = solve_text(tmp_path, deck(spring_mass()), compliance_markers="none")
    assert "frames/compliance" not in a.datasets
    p = tmp_path / "bad.xml"
    p.write_text(deck(spring_mass(), 'compliance_markers="999"'))
    from poise.core.errors import DeckError
    with pytest.raises(DeckError, match="marker id 999") as e:
        poise.solve(str(p))
    assert "bad.xml:4:" in str(e.value)                       # located at the Param_Static
    p.write_text(deck(spring_mass(), 'compliance_markers="ten"'))
    with pytest.raises(DeckError, match="'ten' is not a marker id") as e:
        poise.solve(str(p))
    assert "bad.xml:4:" in str(e.value)
    from poise.core.errors import UsageError
    with pytest.raises(UsageError, match="marker id 998"):
        poise.solve(str(tmp_path / "d.xml"), compliance_markers=[20, 998])


def many_bodies(n) -> str:
    b = ""
    for k in range(n):
        bid = 100 + k
        b += marker(10 * bid, bid, k, 0, 0) + marker(10 * bid + 1, 1, k, 0, 0)
        b += f'    <Body_Rigid id="{bid}" cg_id="{10 * bid}" mass="1.0" {INERTIA}/>\n'
        b += (f'    <Constraint_Joint id="{bid}" type="FIXED" i_marker_id="{10 * bid}" '
              f'j_marker_id="{10 * bid + 1}"/>\n')
    return b


def test_more_than_100_bodies_skipped_with_note(tmp_path):
    text = deck(many_bodies(101))
    a = solve_text(tmp_path, text, compliance_markers="auto")
    assert "frames/compliance" not in a.datasets
    assert "skipped" in a.attrs["compliance_note"] and "all" in a.attrs["compliance_note"]
    b = solve_text(tmp_path, text, compliance_markers="1000 1010")
    C = b.datasets["frames/compliance"][0]
    assert C.shape == (12, 12)
    np.testing.assert_allclose(C, 0.0, atol=1e-12)                  # welded to ground


def test_auto_skips_above_entry_budget(tmp_path, monkeypatch):
    from poise.solvers import compliance
    monkeypatch.setattr(compliance, "AUTO_MAX_ENTRIES", 100)     # 5 frames x 36 > 100
    text = deck(spring_mass(), sim='analysis_type="Static" end_time="1.0" print_interval="0.25"')
    a = solve_text(tmp_path, text, compliance_markers="auto")
    assert "frames/compliance" not in a.datasets
    assert "skipped" in a.attrs["compliance_note"]
    b = solve_text(tmp_path, text, compliance_markers="20")           # explicit: written
    np.testing.assert_allclose(b.datasets["frames/compliance"][:, 2, 2], 1.0 / K_SPRING,
                               rtol=1e-9)


def test_cli_option_writes_datasets(tmp_path):
    h5py = pytest.importorskip("h5py")
    p = tmp_path / "pend.xml"
    p.write_text(deck(pendulum()))
    out = tmp_path / "pend.h5"
    env = dict(os.environ)
    cmd = [sys.executable, "-m", "poise_cli", "solve", str(p), "-o", str(out), "-q",
           "--compliance-markers", "20,10", "--compliance-method", "fd"]
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=60)
    assert res.returncode == 0, res.stderr
    with h5py.File(out, "r") as f:
        g = f["analysis_000"]
        assert list(g["compliance/marker_id"][()]) == [20, 10]
        assert g["compliance/method"].asstr()[()] == "fd"
        C = g["frames/compliance"][()]
        assert C.shape == (1, 12, 12)
        np.testing.assert_allclose(C[0, :6, :6], pendulum_expected(), rtol=2e-3, atol=1e-4)
        np.testing.assert_allclose(C[0, 6:, :], 0.0, atol=1e-12)   # ground marker: no motion
        assert "length/force" in g.attrs["compliance_units"]
    for arg, code in (("x", 2), ("999", 2)):
        bad = subprocess.run(cmd[:-4] + ["--compliance-markers", arg], capture_output=True,
                             text=True, env=env, timeout=60)
        assert bad.returncode == code, bad.stderr
        assert "Traceback" not in bad.stderr
    q = tmp_path / "bad.xml"
    q.write_text(deck(pendulum(), 'compliance_markers="20 777" compliance_method="FD"'))
    bad = subprocess.run([sys.executable, "-m", "poise_cli", "solve", str(q), "-o",
                          str(tmp_path / "b.h5"), "-q"], capture_output=True, text=True,
                         env=env, timeout=60)
    assert bad.returncode == 3 and f"{q}:4:" in bad.stderr and "777" in bad.stderr


def test_batch_and_sweep_take_the_compliance_options(tmp_path, monkeypatch):
    """``--compliance-markers`` / ``--compliance-method`` on every command: a batch (local
    process pool) writes the matrix it asked for, and a sweep hands them to every case."""
    from click.testing import CliRunner

    import poise.app.sweep as sw
    from poise_cli.main import cli
    h5py = pytest.importorskip("h5py")
    p = tmp_path / "pend.xml"
    p.write_text(deck(pendulum()))
    for n in ("dask", "distributed"):
        monkeypatch.setitem(sys.modules, n, None)          # the local process pool: quick
    r = CliRunner().invoke(cli, ["batch", str(p), "--out-dir", str(tmp_path / "b"), "-q",
                                 "--compliance-markers", "20"])
    assert r.exit_code == 0, r.output
    with h5py.File(tmp_path / "b" / "pend.h5", "r") as f:
        C = f["analysis_000/frames/compliance"][0]
        np.testing.assert_allclose(C, pendulum_expected(), rtol=1e-7, atol=1e-10)
    seen = {}
    monkeypatch.setattr(sw, "run_sweep", lambda *a, **kw: seen.update(kw) or [])
    r = CliRunner().invoke(cli, ["sweep", str(p), "--set", "Param_Static.max_num_iter=20,30",
                                 "--out-dir", str(tmp_path / "s"), "-q",
                                 "--compliance-markers", "all", "--compliance-method", "FD"])
    assert seen["overrides"] == {"compliance_markers": "all", "compliance_method": "fd"}, \
        r.output
