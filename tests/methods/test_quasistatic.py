"""Quasi-static runs (FIM_S sequences and FIM_D on SUNDIALS IDA) against closed-form paths."""
import importlib.util
import os

import numpy as np
import pytest

from poise.app.api import run_deck
from poise.deck.schema import element_schema

from support.paths import DECKS


# decks with TIME expressions in forces / Post_Request need the expression forces
needs_expr = pytest.mark.skipif(
    importlib.util.find_spec("poise.elements.expr_forces") is None
    or not element_schema("Post_Request").supported,
    reason="expression-valued forces not available in this tree")


def _deck(name):
    return os.path.join(DECKS, name)


def _run(path, method, **kw):
    res = run_deck(path, {"method": method}, **kw)
    return res


def _variant(tmp_path, name, old, new):
    text = open(_deck(name)).read()
    assert old in text
    p = tmp_path / f"v_{abs(hash(new))}.xml"
    p.write_text(text.replace(old, new))
    return str(p)


@needs_expr
@pytest.mark.parametrize("method", ["FIM_S", "FIM_D"])
def test_spring_force_ramp(method):
    ar = _run(_deck("qs_spring_ramp.xml"), method).analyses[0]
    assert ar.status == "converged", ar.message
    t = ar.datasets["time"]
    np.testing.assert_allclose(t, np.linspace(0, 1, 21), atol=1e-12)
    x = ar.datasets["bodies/position"][:, 0, 0]
    np.testing.assert_allclose(x, 1.0 + 50 * t / 200.0, atol=1e-7)
    assert ar.method == method
    if method == "FIM_D":
        assert ar.attrs["ida_steps"] > 0 and ar.attrs["fim_s_fallbacks"] == 0
        assert len(ar.datasets["steps/time"]) == ar.attrs["ida_steps"]


def _slider_crank_exact(t):
    r, l = 100.0, 300.0
    th = np.pi / 2 + 2 * np.pi * t
    s, c = np.sin(th), np.cos(th)
    root = np.sqrt(l * l - r * r * s * s)
    xB = r * c + root
    A = np.stack([r * c, r * s, 0 * t], 1)
    B = np.stack([xB, 0 * t, 0 * t], 1)
    pos = np.stack([A / 2, (A + B) / 2, B], 1)
    # virtual work: V = (m_c + m_r) g (r/2) sin(th) + k/2 (600 - xB - 300)^2, g in N/kg
    g = 9.81
    dxB = -r * s - r * r * s * c / root
    dV = (0.5 + 1.0) * g * (r / 2) * c + 1.0 * (600 - xB - 300) * (-dxB)
    return pos, dV


@pytest.mark.parametrize("method", ["FIM_S", "FIM_D"])
def test_slider_crank_motion(method):
    ar = _run(_deck("qs_slider_crank_rev.xml"), method).analyses[0]
    assert ar.status == "converged", ar.message
    assert not ar.attrs["reactions_unique"]          # planar from 3-D revolutes: redundant
    t = ar.datasets["time"]
    assert len(t) == 51
    pos, dV = _slider_crank_exact(t)
    np.testing.assert_allclose(ar.datasets["bodies/position"], pos, atol=2e-5)
    T = ar.datasets["motions/torque"][:, 0]
    np.testing.assert_allclose(T[:, 2], dV, atol=1e-4 * np.abs(dV).max())
    np.testing.assert_allclose(T[:, :2], 0, atol=1e-6 * np.abs(dV).max())


@pytest.mark.slow
def test_slider_crank_methods_agree():
    a = _run(_deck("qs_slider_crank_rev.xml"), "FIM_S").analyses[0].datasets
    b = _run(_deck("qs_slider_crank_rev.xml"), "FIM_D").analyses[0].datasets
    np.testing.assert_allclose(a["bodies/position"], b["bodies/position"], atol=1e-5)
    np.testing.assert_allclose(a["motions/torque"], b["motions/torque"], atol=1e-3)


def _pendulum_error(ar):
    t = ar.datasets["time"]
    th = np.arctan2(20 * t, 9.81)
    exact = np.stack([np.sin(th), -np.cos(th)], 1)
    return np.abs(ar.datasets["bodies/position"][:, 0, :2] - exact).max(axis=1)


@needs_expr
@pytest.mark.parametrize("method", ["FIM_S", "FIM_D"])
def test_pendulum_load_ramp(method):
    ar = _run(_deck("qs_pendulum_ramp.xml"), method).analyses[0]
    assert ar.status == "converged", ar.message
    assert len(ar.datasets["time"]) == 101
    assert _pendulum_error(ar).max() < 1e-5
    ev = set(ar.datasets["iterations/event"])
    assert ("ida" in ev) == (method == "FIM_D")


@needs_expr
@pytest.mark.slow
def test_dae_constr_tol_convergence(tmp_path):
    """A tighter ``dae_constr_tol`` makes IDA take more steps and land closer to the
    equilibrium (the size of the last correction of its points, the error estimate, falls);
    the frames written are corrected onto the equilibrium at every tolerance (their last
    correction applied): on the closed form to round-off."""
    steps, estimates = [], []
    for tol in ("1.0E-4", "1.0E-5", "1.0E-6", "1.0E-7"):
        p = _variant(tmp_path, "qs_pendulum_ramp.xml", 'dae_constr_tol="1.0E-6"',
                     f'dae_constr_tol="{tol}"')
        ar = _run(p, "FIM_D").analyses[0]
        assert ar.status == "converged" and ar.attrs["fim_s_fallbacks"] == 0
        assert _pendulum_error(ar).max() < 1e-9, tol
        steps.append(len(ar.datasets["steps/time"]))
        ida = np.asarray(ar.datasets["iterations/event"]) == "ida"
        estimates.append(float(np.max(np.asarray(ar.datasets["iterations/step_norm"])[ida])))
    assert all(b > a for a, b in zip(steps, steps[1:])), steps
    assert all(b <= a for a, b in zip(estimates, estimates[1:])), estimates
    assert estimates[-1] < 1e-2 * estimates[0], estimates


@needs_expr
def test_deck_11b_runs():
    res = run_deck(_deck("qs_slider_crank_11b.xml"), None)
    ar = res.analyses[0]
    assert ar.status == "converged", ar.message
    assert ar.method == "FIM_D" and ar.attrs["fim_s_fallbacks"] == 0
    assert len(ar.datasets["time"]) == 21
    ths = np.pi / 2 + 2 * np.pi * ar.datasets["time"]
    crank_cg = ar.datasets["bodies/position"][:, 0]
    np.testing.assert_allclose(crank_cg[:, :2], 50 * np.stack([np.cos(ths), np.sin(ths)], 1),
                               atol=1e-4)


@needs_expr
def test_sequence_continues_and_time_independence(tmp_path):
    p = _variant(tmp_path, "qs_spring_ramp.xml",
                 '<Simulate analysis_type="Static" end_time="1.0" print_interval="0.05"/>',
                 '<Simulate analysis_type="Static" end_time="0.5" num_steps="5"/>\n'
                 '    <Simulate analysis_type="Quasi-Static" end_time="1.0" print_interval="0.25"/>\n'
                 '    <Simulate analysis_type="Static"/>')
    res = _run(p, "FIM_S")
    a, b, c = res.analyses
    np.testing.assert_allclose(a.datasets["time"], np.linspace(0, 0.5, 6))
    np.testing.assert_allclose(b.datasets["time"], [0.5, 0.75, 1.0])
    np.testing.assert_allclose(b.datasets["bodies/position"][:, 0, 0], 1 + 50 * b.datasets["time"] / 200)
    assert c.analysis_type == "static"
    np.testing.assert_allclose(c.datasets["bodies/position"][0, 0, 0], 1.25, atol=1e-8)
    q = _variant(tmp_path, "qs_spring_ramp.xml", 'fx_expression="50*TIME"', 'fx_expression="50"')
    for m in ("FIM_S", "FIM_D"):
        ar = _run(q, m).analyses[0]
        assert ar.attrs["time_independent"] and "solved once" in ar.message
        np.testing.assert_allclose(ar.datasets["bodies/position"][:, 0, 0], 1.25, atol=1e-8)


@needs_expr
def test_mkeam_quasistatic_uses_fim_s():
    ar = _run(_deck("qs_spring_ramp.xml"), "MKEAM").analyses[0]
    assert ar.method == "FIM_S" and "MKEAM" in ar.message


@needs_expr
@pytest.mark.parametrize("method", ["FIM_S", "FIM_D"])
def test_print_array_output_times(tmp_path, method):
    """Output times from a Reference_Array of type PRINT: start, the array's times inside
    (start, end], end (times beyond end_time dropped)."""
    p = _variant(tmp_path, "qs_spring_ramp.xml",
                 '<Simulate analysis_type="Static" end_time="1.0" print_interval="0.05"/>',
                 '<Simulate analysis_type="Static" end_time="1.0" print_array_id="7"/>')
    text = open(p).read().replace(
        "  </Model>",
        '    <Reference_Array id="7" type="PRINT" num_element="4">0.1 0.35 0.5 2.0</Reference_Array>'
        "\n  </Model>")
    open(p, "w").write(text)
    ar = _run(p, method).analyses[0]
    assert ar.status == "converged", ar.message
    t = ar.datasets["time"]
    np.testing.assert_allclose(t, [0.0, 0.1, 0.35, 0.5, 1.0], atol=1e-12)
    np.testing.assert_allclose(ar.datasets["bodies/position"][:, 0, 0], 1.0 + 50 * t / 200.0,
                               atol=1e-7)
    assert ar.attrs["n_frames"] == 5


def _events(ar):
    d = ar.datasets
    return (list(np.asarray(d["iterations/event"]).astype(str)),
            list(np.asarray(d["iterations/frame"]).astype(int)),
            list(np.asarray(d["iterations/worst_equation"]).astype(str)))


@needs_expr
def test_fim_d_fallbacks_recorded(monkeypatch):
    """Every FIM_S fallback of FIM_D is an ``iterations`` row (event fallback_fim_s, the frame,
    the reason) and counted in the attributes and the message; the path stays correct."""
    import poise.solvers.fim_d as fd
    real = fd.run_ida
    calls = {"start": 0, "step": 0}

    class FailingOnce:
        def __init__(self, solver):
            self.solver = solver

        def step(self, *a, **k):
            if k.get("method") == "onestep":     # an IDA step (not an output interpolation)
                calls["step"] += 1
                if calls["step"] == 2:
                    raise RuntimeError("injected step failure")
            return self.solver.step(*a, **k)

    def fake_ida(*a, **k):
        calls["start"] += 1
        if calls["start"] == 1:
            raise RuntimeError("injected start failure")
        return FailingOnce(real(*a, **k))

    monkeypatch.setattr(fd, "run_ida", fake_ida)
    ar = _run(_deck("qs_spring_ramp.xml"), "FIM_D").analyses[0]
    assert ar.status == "converged", ar.message
    ev, fr, why = _events(ar)
    rows = [(f, w) for e, f, w in zip(ev, fr, why) if e == "fallback_fim_s"]
    assert len(rows) == ar.attrs["fim_s_fallbacks"] == 2
    assert "IDA could not start" in rows[0][1] and "injected start failure" in rows[0][1]
    assert rows[0][0] == 1
    assert "IDA failed after" in rows[1][1] and "injected step failure" in rows[1][1]
    assert "2 FIM_S fallbacks" in ar.message
    t = ar.datasets["time"]
    np.testing.assert_allclose(ar.datasets["bodies/position"][:, 0, 0], 1.0 + 50 * t / 200.0,
                               atol=1e-7)
    # no size limit any more: a model on IDA's sparse solver is integrated, no fallback
    monkeypatch.setattr(fd, "run_ida", real)
    monkeypatch.setattr(fd, "SPARSE_MIN", 0)
    ar = _run(_deck("qs_spring_ramp.xml"), "FIM_D").analyses[0]
    ev, fr, why = _events(ar)
    assert "fallback_fim_s" not in ev and "ida" in ev
    assert ar.status == "converged" and ar.attrs["ida_linear_solver"] == "sparse"
    np.testing.assert_allclose(ar.datasets["bodies/position"][:, 0, 0], 1.0 + 50 * t / 200.0,
                               atol=1e-7)


@needs_expr
@pytest.mark.parametrize("method", ["FIM_S", "FIM_D"])
def test_quiet_silences_progress_bar(monkeypatch, capsys, method):
    """``run_deck(quiet=True)`` (``poise solve --quiet``) turns the progress bar off even on a
    terminal; without it the solver reports its frames to the callback of poise.core.progress,
    whose bar follows the terminal / CI detection (tty here). (Was: the solvers' own bar class;
    one bar for all long work now.)"""
    import poise.core.progress as pm
    seen = []
    orig = pm.Bar.__init__

    def init(self, total, label, *a, **k):
        orig(self, total, label, *a, **k)
        seen.append((label, self.mode))

    monkeypatch.setattr(pm.Bar, "__init__", init)
    monkeypatch.delenv("CI", raising=False)
    monkeypatch.delenv("POISE_QUIET", raising=False)
    monkeypatch.setattr(pm.sys.stderr, "isatty", lambda: True, raising=False)
    run_deck(_deck("qs_spring_ramp.xml"), {"method": method}, quiet=True)
    assert seen == []
    run_deck(_deck("qs_spring_ramp.xml"), {"method": method})
    assert seen and all(lab == method and mode == "tty" for lab, mode in seen)
    assert pm.PROGRESS.get() is None
