"""Unstable and neutral equilibria are said where the user looks, from one summary.

* stability modes are stored as numbers (``modes/*``): the unit direction of a known mode
  (closed form) within tolerance, sign-normalised (largest component positive, no -0);
* ``poise solve`` (stderr line and ``--json``), ``poise show`` (text and ``--json``) and the
  ``batch`` / ``sweep`` rows report the same summary (``poise.results.summary``): the worst frame
  of a quasi-static run whose stability changes at a known time (where it ends: a bifurcation),
  named by frame and time.

Every number is compared as a number (parsed JSON, datasets), never as formatted text.
"""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from poise.app.api import run_deck
from poise.results.data import AnalysisResult, RunResult
from poise.results.summary import summarize, summarize_run

from poise.gen.deck import Deck

POISE = str(Path(sys.executable).parent / "poise")
L = 400.0                                   # pendulum length [mm]
AXIS = np.array([-3.0, 0.0, -4.0]) / 5.0    # hinge axis, horizontal, off the global axes
K0 = 1000.0                                 # N/m: slider stiffness k(t) = K0 (1 - 2 t)


def _frame(z):
    """Rotation matrix whose third column is the unit vector ``z``."""
    z = np.asarray(z, float) / np.linalg.norm(z)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def tilted_inverted_pendulum():
    """A link standing upright (CG straight above the pivot, gravity -Y) on a REVOLUTE joint
    whose axis is AXIS: an equilibrium (no gravity torque), unstable by a rotation about AXIS."""
    d = Deck()
    d.ground()
    R = _frame(AXIS)
    d.marker(101, 1, (0, 0, 0), R)
    d.body(2, 20, (0, L / 2, 0), mass=2.0, inertia=(2.0 * L * L / 12, 10.0, 2.0 * L * L / 12))
    d.marker(21, 2, (0, 0, 0), R)
    d.joint(1, "REVOLUTE", 21, 101)
    return d


def ball_on_table():
    """A ball on a PLANAR joint (table normal +Y): neutral, 3 zero modes (x, z, spin)."""
    up = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])     # marker z along +Y
    d = Deck()
    d.ground()
    d.marker(101, 1, (0, 50, 0), up)
    d.body(2, 20, (120, 50, -30), mass=1.5, inertia=(1500, 1500, 1500))
    d.marker(21, 2, (120, 50, -30), up)
    d.joint(1, "PLANAR", 21, 101)
    return d


def softening_slider(tmp_path):
    """Block on a TRANSLATIONAL joint along X at x = 0, force fx = -K0 (1 - 2 TIME) x: x = 0 is
    the equilibrium of every frame, with stiffness k(t) = K0 (1 - 2 t): stable for t < 0.5,
    neutral at t = 0.5 (a bifurcation), unstable after. Quasi-static FIM_S over [0, 1], frames
    every 0.1."""
    ax = 'a00="0" a10="1" a20="0" a01="0" a11="0" a21="1" a02="1" a12="0" a22="0"'   # z = +X
    eye = 'a00="1" a10="0" a20="0" a01="0" a11="1" a21="0" a02="0" a12="0" a22="1"'
    txt = f"""<MotionSolve>
<Model>
<Param_Unit force_unit="NEWTON" mass_unit="KILOGRAM" length_unit="METER" time_unit="SECOND"/>
<Param_Static method="FIM_S" max_imbalance="1e-8" max_error="1e-8"/>
<Body_Rigid id="1" isground="TRUE" cg_id="10"/>
<Reference_Marker id="10" body_id="1" pos_x="0" pos_y="0" pos_z="0" {eye}/>
<Reference_Marker id="11" body_id="1" pos_x="0" pos_y="0" pos_z="0" {ax}/>
<Body_Rigid id="2" cg_id="20" mass="2.0" inertia_xx="1." inertia_yy="1." inertia_zz="1." inertia_xy="0." inertia_yz="0." inertia_xz="0."/>
<Reference_Marker id="20" body_id="2" pos_x="0" pos_y="0" pos_z="0" {eye}/>
<Reference_Marker id="21" body_id="2" pos_x="0" pos_y="0" pos_z="0" {ax}/>
<Constraint_Joint id="1" type="TRANSLATIONAL" i_marker_id="21" j_marker_id="11"/>
<Force_Vector_OneBody id="2" type="FORCEONLY" marker_id="20" fx_expression="-{K0}*(1-2*TIME)*DX(20,10)" fy_expression="0" fz_expression="0"/>
</Model>
<Command>
<Simulate analysis_type="Static" end_time="1.0" print_interval="0.1"/>
<Stop/>
</Command>
</MotionSolve>
"""
    p = tmp_path / "softening_slider.xml"
    p.write_text(txt)
    return str(p)


def expected_direction(v):
    """The sign convention, written out: unit vector, largest-magnitude component positive."""
    v = np.asarray(v, float) / np.linalg.norm(v)
    return v if v[np.argmax(np.abs(v))] > 0 else -v


def _cli(*args):
    r = subprocess.run([POISE, *args], capture_output=True, text=True, timeout=120)
    assert "Traceback" not in r.stderr, r.stderr
    return r


# ------------------------------------------------------------------ numeric modes
def test_inverted_pendulum_mode_is_the_hinge_axis(tmp_path):
    a = run_deck(tilted_inverted_pendulum().write(tmp_path / "up.xml")).analyses[0]
    assert a.converged, a.message
    d = a.datasets
    np.testing.assert_allclose(d["bodies/position"][0, 0], [0, L / 2, 0], atol=1e-9)
    assert (d["frames/stability"][0], d["frames/n_negative"][0], d["frames/n_zero"][0]) == \
        ("unstable", 1, 0)
    assert d["frames/n_modes"][0] == 1
    assert (d["modes/class"].tolist(), d["modes/body"].tolist(), d["modes/kind"].tolist()) == \
        (["unstable"], [2], ["rotation"])
    u = d["modes/direction"][0]
    np.testing.assert_allclose(u, expected_direction(AXIS), atol=1e-8)      # (0.6, 0, 0.8)
    assert not np.any(np.signbit(u) & (u == 0.0))                            # no -0.0
    # one degree of freedom: the mode's Rayleigh quotient is the smallest eigenvalue (< 0)
    assert d["modes/eigenvalue"][0] < 0
    np.testing.assert_allclose(d["modes/eigenvalue"][0], d["frames/min_stiffness_eigenvalue"][0],
                               rtol=1e-9)


def test_sign_normalisation_rules():
    from poise.solvers.stability import Mode, sign_normalised
    np.testing.assert_array_equal(sign_normalised([0.0, -0.0, -2.0]), [0.0, 0.0, 1.0])
    assert not np.signbit(sign_normalised([-1e-300, -0.0, -3.0])).any()
    # a tie (within 1e-6): the first tied component is made positive
    np.testing.assert_allclose(sign_normalised([-1.0, 1.0 + 1e-12, 0.0]),
                               np.array([1.0, -1.0, 0.0]) / np.sqrt(2), rtol=1e-11)
    # the text is built from the numbers: no "-0.00" for a tiny negative component
    m = Mode("unstable", 3, "rotation", (-1e-17, 1e-17, 1.0), -2.0)
    assert "-" not in m.text() and m.text(short=True) == "body 3 rotation about z"


# ------------------------------------------------------------------ quasi-static summary
def test_quasistatic_summary_names_the_worst_frame(tmp_path):
    """k(t) = K0 (1 - 2 t) crosses zero at t = 0.5: the run follows the stable branch to that
    bifurcation and ends there (a singular configuration); its last frame is the state just
    past it, unstable, and the summary names it."""
    res = run_deck(softening_slider(tmp_path))
    a = res.analyses[0]
    assert a.status == "failed" and a.attrs["singular_kind"] == "bifurcation", a.message
    assert a.attrs["singular_time"] == pytest.approx(0.5, abs=1e-6)
    d = a.datasets
    t = d["time"]
    np.testing.assert_allclose(t[:6], np.linspace(0, 0.5, 6), atol=1e-12)
    assert len(t) == 7 and t[6] == pytest.approx(0.5, abs=1e-6) and t[6] > 0.5
    k = K0 * (1 - 2 * t[:6])
    np.testing.assert_allclose(d["bodies/position"][:, 0, 0], 0.0, atol=1e-12)
    assert list(d["frames/stability"]) == ["stable"] * 5 + ["neutral", "unstable"]
    assert list(d["frames/status"]) == ["converged"] * 6 + ["singular_configuration"]
    # stiffness along the slide [N/m] = k(t) (translation: length coordinates = metres)
    np.testing.assert_allclose(d["frames/min_stiffness_eigenvalue"][:5], k[:5], rtol=1e-8)
    # one mode per neutral or unstable frame, flat in frame order
    assert d["frames/n_modes"].tolist() == [0] * 5 + [1, 1]
    assert d["modes/class"].tolist() == ["neutral", "unstable"]
    assert d["modes/eigenvalue"][1] < 0
    np.testing.assert_allclose(d["modes/direction"], [[1, 0, 0]] * 2, atol=1e-12)

    s = summarize(a)
    assert (s.stability_class, s.stability_frame, s.n_negative, s.n_zero) == \
        ("unstable", 6, 1, 0)
    assert s.stability_time == pytest.approx(0.5, abs=1e-6)
    assert (s.unstable_frames, s.neutral_frames) == (1, 1)
    assert dict(s.stability_counts) == {"stable": 5, "neutral": 1, "unstable": 1}
    assert [(m.klass, m.body, m.kind) for m in s.modes] == [("unstable", 2, "translation")]
    np.testing.assert_allclose(s.modes[0].direction, [1, 0, 0], atol=1e-12)
    assert s.iterations == int(np.sum(d["frames/iterations"]))
    assert s.imbalance == pytest.approx(float(np.nanmax(d["frames/imbalance"])))
    assert s.frames == 7 and s.frame_status == "singular_configuration"
    assert s.singular["kind"] == "bifurcation"


def test_summary_worst_frame_definitions():
    """The definitions on a hand-made analysis: worst imbalance and error frames, the first
    failed frame's status, iterations summed, unknown ranks above neutral, the worst stability
    frame has the most negative modes."""
    ds = {"time": np.array([0.0, 0.5, 1.0, 1.5]),
          "frames/iterations": np.array([3, 7, 2, 4]),
          "frames/imbalance": np.array([1e-9, np.nan, 4e-3, 2e-3]),
          "frames/error": np.array([5e-9, 1e-10, 1e-12, 1e-11]),
          "frames/converged": np.array([True, False, True, False]),
          "frames/status": np.array(["converged", "nonfinite", "converged", "max_iterations"]),
          "frames/stability": np.array(["neutral", "unknown", "stable", "neutral"]),
          "frames/n_negative": np.array([0, -1, 0, 0]),
          "frames/n_zero": np.array([1, -1, 0, 2])}
    a = AnalysisResult(index=2, analysis_type="quasistatic", method="FIM_S", status="failed",
                       message="frame 1 failed", datasets=ds)
    s = summarize(a)
    assert (s.iterations, s.imbalance_frame, s.error_frame) == (16, 2, 0)
    assert s.imbalance == pytest.approx(4e-3) and s.imbalance_time == pytest.approx(1.0)
    assert s.error == pytest.approx(5e-9) and s.error_time == pytest.approx(0.0)
    assert (s.frame_status, s.frame_status_frame) == ("nonfinite", 1)
    assert (s.stability_class, s.stability_frame) == ("unknown", 1)
    ds["frames/stability"] = np.array(["neutral", "stable", "stable", "neutral"])
    s = summarize(a)
    assert (s.stability_class, s.stability_frame, s.n_zero) == ("neutral", 3, 2)
    # a run: worst over analyses
    b = AnalysisResult(index=0, analysis_type="static", method="FIM_S", status="converged",
                       datasets={"time": np.array([0.0]), "frames/imbalance": np.array([1e-2]),
                                 "frames/iterations": np.array([5]),
                                 "frames/stability": np.array(["stable"])})
    r = summarize_run(RunResult(deck="d", deck_sha256="", analyses=[b, a]))
    assert (r.iterations, r.imbalance_analysis, r.imbalance_frame) == (21, 0, 0)
    assert (r.stability_class, r.stability_analysis, r.stability_frame) == ("neutral", 2, 3)


# ------------------------------------------------------------------ where the user looks
def _analysis_fields(a):
    keys = ("status", "stability_class", "n_negative", "n_zero", "stability_frame",
            "imbalance_frame", "iterations", "frames")
    return {k: a[k] for k in keys}


def test_cli_solve_show_batch_say_unstable(tmp_path):
    deck = tilted_inverted_pendulum().write(tmp_path / "up.xml")
    out = tmp_path / "up.h5"
    r = _cli("solve", deck, "-o", str(out), "--json")
    assert r.returncode == 0, r.stderr
    a = json.loads(r.stdout)["analyses"][0]
    assert (a["status"], a["stability_class"], a["n_negative"], a["n_zero"]) == \
        ("converged", "unstable", 1, 0)
    (m,) = a["modes"]
    assert (m["class"], m["body"], m["kind"]) == ("unstable", 2, "rotation")
    np.testing.assert_allclose(m["direction"], expected_direction(AXIS), atol=1e-8)
    assert m["eigenvalue"] < 0
    line = next(x for x in r.stderr.splitlines() if x.startswith("analysis 0:"))
    assert "converged to an UNSTABLE equilibrium (1 negative mode: body 2 rotation" in line

    s = _cli("show", str(out), "--json")
    assert s.returncode == 0, s.stderr
    b = json.loads(s.stdout)["analyses"][0]
    assert _analysis_fields(b) == _analysis_fields(a)
    assert b["modes"][0]["body"] == 2
    np.testing.assert_allclose(b["modes"][0]["direction"], m["direction"], rtol=0, atol=0)
    txt = _cli("show", str(out)).stdout
    assert "converged to an UNSTABLE equilibrium" in txt

    bt = _cli("batch", deck, "--out-dir", str(tmp_path / "b"), "-j", "1", "--json")
    assert bt.returncode == 0, bt.stderr
    (row,) = json.loads(bt.stdout)["rows"]
    assert (row["status"], row["stability_class"], row["n_negative"], row["stability_frame"],
            row["stability_analysis"]) == ("converged", "unstable", 1, 0, 0)
    np.testing.assert_allclose(row["modes"][0]["direction"], m["direction"], atol=1e-12)
    assert "UNSTABLE" in bt.stderr
    csv = (tmp_path / "b" / "summary.csv").read_text().splitlines()
    head = csv[0].split(",")
    assert "stability_class" in head and "modes" in head


def test_cli_neutral_and_quasistatic(tmp_path):
    deck = ball_on_table().write(tmp_path / "ball.xml")
    r = _cli("solve", deck, "-o", str(tmp_path / "ball.h5"), "--json")
    assert r.returncode == 0, r.stderr
    a = json.loads(r.stdout)["analyses"][0]
    assert (a["stability_class"], a["n_negative"], a["n_zero"]) == ("neutral", 0, 3)
    assert {m["body"] for m in a["modes"]} == {2} and len(a["modes"]) == 3
    line = next(x for x in r.stderr.splitlines() if x.startswith("analysis 0:"))
    assert "converged to a NEUTRAL equilibrium (3 zero modes:" in line

    qs = softening_slider(tmp_path)
    out = tmp_path / "qs.h5"
    r = _cli("solve", qs, "-o", str(out), "--json")
    assert r.returncode == 1, r.stderr          # the path ends at the bifurcation at t = 0.5
    a = json.loads(r.stdout)["analyses"][0]
    assert (a["stability_class"], a["stability_frame"], a["frames"]) == ("unstable", 6, 7)
    assert a["stability_time"] == pytest.approx(0.5, abs=1e-6)
    assert a["stability_counts"] == {"stable": 5, "neutral": 1, "unstable": 1}
    assert a["singular"]["time"] == pytest.approx(0.5, abs=1e-6)
    line = next(x for x in r.stderr.splitlines() if x.startswith("analysis 0:"))
    assert "singular configuration at t = 0.5: at a bifurcation" in line
    b = json.loads(_cli("show", str(out), "--json").stdout)["analyses"][0]
    assert _analysis_fields(b) == _analysis_fields(a)
    assert b["stability_counts"] == a["stability_counts"]


def test_sweep_row_carries_the_summary(tmp_path):
    import json

    from poise.app.chunks import FrameLayout, SweepJob, make_template, solve_chunk
    deck = tilted_inverted_pendulum().write(tmp_path / "up.xml")
    job = SweepJob(Path(deck).read_bytes(), str(deck), (), {}, (), FrameLayout((0.0,), (0,)))
    rec, = solve_chunk(make_template(job, {}), [(0, {})])
    assert (rec.status, rec.stability, rec.n_negative) == ("converged", "unstable", 1)
    np.testing.assert_allclose(json.loads(rec.modes)[0]["direction"], expected_direction(AXIS),
                               atol=1e-8)
