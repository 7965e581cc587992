"""``--require-stable`` on a 7-joint arm standing upright, at tight tolerances.

A serial arm of seven revolutes whose axes alternate along the link (roll) and across it (pitch,
global Z at the input), like an industrial 7-axis arm, standing straight up under gravity. The
upright pose is an equilibrium (Newton's answer): unstable in the three pitch joints, neutral
in the four rolls. The rest position downhill: link 1 (on the vertical roll joint 1) stays up,
links 2-7 hang straight down from its top. There the four rolls are exactly neutral, so the
descent's zero-shift Newton polish never applies and every step is judged by energy, down to
energy changes far below the multipliers' work on the trials' rounding-level violation. The
closed forms: every CG position and the rest potential energy.
"""
import numpy as np
import pytest

import poise.solvers.trials as trials

from poise.gen.deck import Deck, rot_x

G = 9.81
LINKS = [(340.0, 4.0), (400.0, 4.0), (400.0, 3.0), (400.0, 2.7), (260.0, 1.7), (120.0, 1.8),
         (126.0, 0.3)]                                      # (length mm, mass kg)
AXES = "YZYZYZY"                                            # Y: roll (along the link)
S = {"mm": 1.0, "m": 1e-3}


def upright_arm(units):
    d = Deck(units=units, static=dict(max_imbalance=1e-8, max_error=1e-10))
    d.ground()
    R = {"Y": rot_x(-np.pi / 2), "Z": np.eye(3)}            # joint z axis along Y or Z
    y, prev = 0.0, None
    for k, (a, m) in enumerate(LINKS):
        b, mk = 2 + k, 100 * (2 + k)
        base = np.array([0.0, y, 0.0])
        inertia = m * a * a / 12
        d.body(b, mk, base + [0.0, a / 2, 0.0], mass=m, inertia=(inertia, 1.0, inertia))
        d.marker(mk + 1, b, base, R[AXES[k]])
        d.marker(mk + 2, 1 if prev is None else prev, base, R[AXES[k]])
        d.marker(mk + 3, b, base + [0.0, a, 0.0])          # the link's far end
        d.joint(k + 1, "REVOLUTE", mk + 1, mk + 2)
        y, prev = y + a, b
    return d


def rest_heights():
    """CG heights [mm] at rest: link 1 upright, links 2-7 hanging from its top."""
    top = LINKS[0][0]
    ys, y = [top / 2], top
    for a, _ in LINKS[1:]:
        ys.append(y - a / 2)
        y -= a
    return np.array(ys)


def energy(y_mm):
    return float(sum(m * G * yy for (_, m), yy in zip(LINKS, y_mm)))      # N mm


@pytest.mark.parametrize("units", ["mm", "m"])
def test_upright_arm_descends_to_its_neutral_rest(runner, units):
    """Before: "no valid factorisation" (or the budget blamed) at imbalance 1e-3..3e-2 with the
    energy already right to 1e-8. Now: the rest pose to the tolerances, neutral with the
    four rolls as its zero modes (``--allow-neutral`` is the default)."""
    a = runner.api(upright_arm(units), f"arm_{units}.xml", require_stable=True)
    assert a.converged, a.message
    s = S[units]
    P = a.datasets["bodies/position"][0] / s                # mm
    want = np.column_stack([np.zeros(7), rest_heights(), np.zeros(7)])
    # 1e-8 N per force row allows ~1e-10 rad of tilt over the 1.4 m that hangs (~1e-6 mm)
    np.testing.assert_allclose(P, want, rtol=0, atol=1e-6)
    assert abs(energy(P[:, 1]) - energy(rest_heights())) <= 1e-8 * abs(energy(rest_heights()))
    d = a.datasets
    assert (str(d["frames/stability"][0]), int(d["frames/n_negative"][0]),
            int(d["frames/n_zero"][0])) == ("neutral", 0, 4)
    # every zero mode is a rotation about the vertical (the rolls)
    for kind, axis in zip(d["modes/kind"], d["modes/direction"]):
        assert str(kind) == "rotation"
        np.testing.assert_allclose(np.abs(axis), [0, 1, 0], atol=1e-6)
    assert "descended from the input" in a.message or "downhill" in a.message


def test_upright_arm_newton_alone_stays_upright_and_says_unstable(runner):
    """Closed form: the upright pose is an equilibrium; the three pitch joints each carry an
    inverted pendulum (unstable), the four rolls move no mass off their axes (neutral)."""
    a = runner.api(upright_arm("mm"), "arm_plain.xml")
    assert a.converged, a.message
    tops = np.cumsum([0.0] + [a_ for a_, _ in LINKS])[:-1]
    ys = tops + np.array([a_ for a_, _ in LINKS]) / 2
    np.testing.assert_allclose(a.datasets["bodies/position"][0],
                               np.column_stack([np.zeros(7), ys, np.zeros(7)]), atol=1e-9)
    d = a.datasets
    assert (str(d["frames/stability"][0]), int(d["frames/n_negative"][0]),
            int(d["frames/n_zero"][0])) == ("unstable", 3, 4)


def test_upright_arm_no_allow_neutral_names_the_neutral_modes(runner):
    r, js, out = runner.cli(upright_arm("mm"), "arm_nn.xml", "--require-stable",
                            "--no-allow-neutral")
    assert r.returncode == 1
    an = js["analyses"][0]
    assert an["stability_class"] == "neutral" and an["n_zero"] == 4
    assert "--no-allow-neutral" in an["message"] and "rotation about" in an["message"]


def test_a_stalled_descent_says_why_not_the_budget(runner, monkeypatch):
    """With the violation-aware energy test switched off, the descent stalls short of the
    tolerances as it used to: the failure says so (stalled, at what imbalance, the zero modes
    of the point reached), never that the iteration budget ran out when it did not."""
    monkeypatch.setattr(trials.LagrangeTest, "decrease", lambda self, dv, proj, lam: np.inf)
    a = runner.api(upright_arm("m"), "arm_stall.xml", require_stable=True)
    assert not a.converged
    msg = a.message
    assert "stalled at imbalance" in msg, msg
    assert "budget" not in msg, msg
    assert "zero-stiffness mode" in msg, msg
    assert a.datasets["frames/status"][0] == "unstable"
