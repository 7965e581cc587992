"""Clean failures: exit 1, file written, the message names the body/element and its deck line;
never a ``converged`` flag on a wrong answer."""
import numpy as np

from support.runner import h5
from poise.gen.deck import Deck, rot_y

ALONG_X = rot_y(np.pi / 2)          # marker z axis along global +X


def slider(x0, fx_expr, grav=None, static=None):
    """Point body on an INLINE jprim along global X, one expression force on it."""
    d = Deck(grav=grav, static=static)
    d.ground()
    d.marker(101, 1, (0, 0, 0), ALONG_X)
    bline = d.point(2, 20, (x0, 0, 0), mass=1.0)
    d.marker(21, 2, (x0, 0, 0), ALONG_X)
    d.jprim(1, "INLINE", 21, 101)
    fline = d.add(f'<Force_Vector_OneBody id="7" type="FORCEONLY" marker_id="21" ref_marker_id="0" '
                  f'fx_expression="{fx_expr}" fy_expression="0" fz_expression="0"/>')
    return d, bline, fline


def test_nan_along_the_path_names_element_and_line(runner):
    # SQRT(DX) is fine at the start (x = 50) but the force always pulls towards -X: every step
    # ends up past x = 0 where SQRT is evaluated negative. Before the fix the message was the
    # bare "an element produced NaN or Inf".
    d, _, fline = slider(50.0, "-SQRT(DX(21,101)) - 20")
    r, js, out = runner.cli(d, "nan.xml")
    assert r.returncode == 1, r.stderr
    msg = js["analyses"][0]["message"]
    assert f"nan.xml:{fline}: <Force_Vector_OneBody id=7> fx_expression" in msg
    assert "SQRT" in msg
    with h5(out) as f:
        a = f["analysis_000"]
        assert a["frames/status"].asstr()[0] == "nonfinite"
        assert not a["frames/converged"][0]
        ev = a["iterations/event"].asstr()[:]
        # the full history (Newton's steps, downhill ones included), no fallback
        assert len(ev) >= 2 and all(e.startswith("newton") for e in ev)
        assert np.all(np.isfinite(a["iterations/imbalance"][:]))


def test_zero_mass_body_unrestrained_direction(runner):
    """A massless body on a TRANSLATIONAL joint along X with nothing acting along X, next to a
    pendulum that needs Newton iterations (the massless body alone would already be balanced
    at the start: any X is an equilibrium)."""
    d = Deck()
    d.ground()
    d.marker(101, 1, (0, 0, 0), ALONG_X)
    d.body(2, 20, (100, 0, 0), mass=0.0, inertia=(0, 0, 0))
    d.marker(21, 2, (100, 0, 0), ALONG_X)
    d.joint(1, "TRANSLATIONAL", 21, 101)
    d.marker(102, 1, (0, 500, 0))
    d.body(3, 30, (200, 500, 0), mass=2.0, inertia=(10, 3e4, 3e4))
    d.marker(31, 3, (0, 500, 0))
    d.joint(2, "REVOLUTE", 31, 102)
    r, js, out = runner.cli(d, "massless.xml")
    assert r.returncode == 1, r.stderr
    msg = js["analyses"][0]["message"]
    assert "body 2 has zero mass" in msg
    assert "translation along X" in msg
    assert out.exists()


def test_stagnation_above_tolerance_is_failed_never_converged(runner):
    """A discontinuous force with no root (sign flip at x = 100 without passing through zero):
    the residual cannot drop below 10 N; max_num_iter must end in ``failed`` (exit 1)."""
    d, bline, _ = slider(40.0, "IF(DX(21,101) - 100: 10, 10, -10)",
                         static=dict(max_num_iter=15))
    r, js, out = runner.cli(d, "kink.xml", "--no-fallback")
    assert r.returncode == 1, r.stderr
    a = js["analyses"][0]
    assert a["status"] == "failed"
    # the worst residual row is mapped back to the body and its deck line
    assert f"kink.xml:{bline}: <Body_Point id=2> Fx" in a["message"]
    with h5(out) as f:
        g = f["analysis_000"]
        assert g["frames/status"].asstr()[0] == "max_iterations"
        assert not g["frames/converged"][0]
        assert g["frames/imbalance"][0] >= 10.0 - 1e-9
        assert g["frames/stability"].asstr()[0] == "unknown"
