"""FIM_D (SUNDIALS IDA): the sparse linear-solver path with the analytic Jacobian, and the
per-step table read from IDA's own counters (order, Newton iterations, failures)."""
import importlib.util
import os

import h5py
import numpy as np
import pytest

import poise.solvers.fim_d as fd
from poise.app.api import run_deck
from poise.deck.schema import element_schema
from poise.gen.chain import build_chain_deck

from support.paths import DECKS


needs_expr = pytest.mark.skipif(
    importlib.util.find_spec("poise.elements.expr_forces") is None
    or not element_schema("Post_Request").supported,
    reason="expression-valued forces not available in this tree")

HARMONIC = {k: sum(1.0 / i for i in range(1, k + 1)) for k in range(1, 6)}


def _qs_chain(tmp_path, n, load=200.0, dt=0.25, static='method="FIM_D"'):
    """Revolute hanging chain (decks/gen_chain.py) with a load ramped from 0 at link n//3's end
    pin (x and y components ``load * TIME`` N), quasi-static over [0, 1]."""
    txt = build_chain_deck(n)
    txt = txt.replace('<Param_Static method="FIM_S"', f"<Param_Static {static}")
    k = n // 3
    force = (f'    <Force_Vector_OneBody id="{n + 10}" type="FORCEONLY" marker_id="{10 * k + 3}" '
             f'fx_expression="{load}*TIME" fy_expression="{load}*TIME" fz_expression="0"/>\n')
    txt = txt.replace("  </Model>", force + "  </Model>")
    txt = txt.replace('<Simulate analysis_type="Static"/>',
                      f'<Simulate analysis_type="Static" end_time="1.0" print_interval="{dt}"/>')
    p = tmp_path / f"qs_chain_{n}.xml"
    p.write_text(txt)
    return str(p)


def _bushing_3d(tmp_path):
    """The bushing block with a 3-D load ramped in time at an offset point: the block rotates
    about all three axes (every entry of J_l(w) matters)."""
    txt = open(os.path.join(DECKS, "bushing_block.xml")).read()
    old = 'fx_expression="30.0" fy_expression="-80.0" fz_expression="0."'
    assert old in txt
    txt = txt.replace(old, 'fx_expression="150*TIME" fy_expression="-400*TIME" '
                           'fz_expression="300*TIME"')
    old = 'pos_x="250.0" pos_y="-200.0" pos_z="50.0"'
    assert old in txt
    txt = txt.replace(old, 'pos_x="250.0" pos_y="-120.0" pos_z="90.0"')
    txt = txt.replace('<Param_Static method="FIM_S"', '<Param_Static method="FIM_D" stability="0"')
    txt = txt.replace('<Simulate analysis_type="Static"/>',
                      '<Simulate analysis_type="Static" end_time="1.0" print_interval="0.1"/>')
    p = tmp_path / "qs_bushing_3d.xml"
    p.write_text(txt)
    return str(p)


def _events(path):
    with h5py.File(path, "r") as f:
        return [e.decode() if isinstance(e, bytes) else str(e)
                for e in f["analysis_000/iterations/event"][()]]


def _check_steps(ar, max_order=5):
    d = ar.datasets
    n = ar.attrs["ida_steps"]
    assert n > 0
    for k in ("time", "step_size", "order", "nonlinear_iterations", "error_test_failures",
              "convergence_failures", "jacobian_evaluations", "rebase"):
        assert len(d[f"steps/{k}"]) == n, k
    order = np.asarray(d["steps/order"])
    assert order.dtype.kind == "i"
    assert order.min() >= 1 and order.max() <= max_order, order
    assert np.all(np.asarray(d["steps/nonlinear_iterations"]) >= 1)
    assert np.all(np.asarray(d["steps/error_test_failures"]) >= 0)
    assert np.all(np.asarray(d["steps/convergence_failures"]) >= 0)
    h, t = np.asarray(d["steps/step_size"]), np.asarray(d["steps/time"])
    assert np.all(h > 0) and np.all(np.diff(t) > 0)
    return order


@needs_expr
def test_sparse_fim_d_above_old_dense_limit(tmp_path, monkeypatch):
    """A chain of 510 links (N = 5665 unknowns; the former dense limit was 1500; more than
    3000 coordinates, so the per-frame stability classification stays cheap) is integrated by
    IDA with the sparse solver: no FIM_S fallback in the results file, every frame within 1e-6
    (relative) of FIM_S, BDF orders in [1, 5]."""
    from poise.results.hdf5 import write_results
    path = _qs_chain(tmp_path, 510)
    sizes = []
    real = fd.SparseJacobian.__init__

    def init(self, model):
        sizes.append(model.N)
        real(self, model)

    monkeypatch.setattr(fd.SparseJacobian, "__init__", init)
    res = {}
    for m in ("FIM_D", "FIM_S"):
        r = run_deck(path, {"method": m}, quiet=True)
        write_results(r, str(tmp_path / f"{m}.h5"))
        res[m] = r
    assert sizes == [6 * 510 + 5 * 511]
    a, b = res["FIM_D"].analyses[0], res["FIM_S"].analyses[0]
    assert a.status == b.status == "converged", (a.message, b.message)
    assert a.method == "FIM_D" and a.attrs["ida_linear_solver"] == "sparse"
    assert a.attrs["fim_s_fallbacks"] == 0
    ev = _events(str(tmp_path / "FIM_D.h5"))
    assert "fallback_fim_s" not in ev
    assert ev.count("ida") == len(a.datasets["time"]) - 2      # interior frames: IDA's
    assert ev.count("final_fim_s") >= 1
    pa, pb = a.datasets["bodies/position"], b.datasets["bodies/position"]
    F = len(pb)
    assert F == 5
    err = np.abs(pa - pb).reshape(F, -1).max(axis=1)
    scale = np.abs(pb).reshape(F, -1).max(axis=1)
    assert np.all(err <= 1e-6 * scale), err / scale
    # the load moved the chain: the comparison is not trivially between rest states
    assert np.abs(pb[-1] - pb[0]).max() > 1.0
    _check_steps(a)


@needs_expr
@pytest.mark.parametrize("n, max_steps", [(8, 120), (20, 90)])
def test_chain_steps_bounded_and_match_fim_s(tmp_path, n, max_steps):
    """Hanging chain, load at link n//3 ramped to 2.5x (n=8) / 1x (n=20) the chain's weight: the
    links swing by more than a radian (one rebase). Measured IDA steps (tol 1e-6): 157 / 109
    before consistent, curvature-sized (re)starts and the 0.03 corrector coefficient, 104 / 75
    after; the bound leaves ~15 % margin. No start ramps any more (IDA's own first step took
    14 order-1 steps over 2 starts), no fallback, and every one of the 21 frames (19 of them
    IDA interpolants) matches FIM_S within the DAE tolerance (1e-6 of the model length)."""
    path = _qs_chain(tmp_path, n, dt=0.05)
    res = {m: run_deck(path, {"method": m}, quiet=True) for m in ("FIM_D", "FIM_S")}
    a, b = res["FIM_D"].analyses[0], res["FIM_S"].analyses[0]
    assert a.status == b.status == "converged", (a.message, b.message)
    assert a.attrs["dae_tol"] == 1e-6 and a.attrs["fim_s_fallbacks"] == 0
    order = _check_steps(a)
    starts = int(np.sum(a.datasets["steps/rebase"]))
    assert starts >= 2                                  # the chain rotated past REBASE_ANGLE
    assert a.attrs["ida_steps"] <= max_steps, a.attrs["ida_steps"]
    assert np.sum(order == 1) <= 2 * starts, order
    L = float(res["FIM_D"].model_datasets["length_scale"])
    pa, pb = a.datasets["bodies/position"], b.datasets["bodies/position"]
    assert len(pb) == 21
    assert np.abs(pa - pb).max() <= 1e-6 * L, np.abs(pa - pb).max() / L
    assert np.abs(pb[-1] - pb[0]).max() > 0.5 * L       # the path is not trivial


def test_every_ida_start_is_consistent(monkeypatch):
    """Each IDA run (the first and one per rebase: the crank turns 2 pi) starts at an
    equilibrium: the Newton correction at (t0, y0) is below 1e-3 in IDA's weighted norm.
    Without the polish a rebase restarted from IDA's last corrector, 0.03-1.2 tolerance units
    off here (4.5 with a 0.1 corrector coefficient, where IDA then failed at h_min)."""
    starts = []
    real = fd.run_ida

    def ida(chart, tsd, atol, t0, y0, yp0, first_step):
        starts.append((chart, t0, np.array(y0), np.array(atol), tsd.tol, first_step))
        return real(chart, tsd, atol, t0, y0, yp0, first_step)

    monkeypatch.setattr(fd, "run_ida", ida)
    ar = run_deck(os.path.join(DECKS, "qs_slider_crank_rev.xml"), {"method": "FIM_D"},
                  quiet=True).analyses[0]
    assert ar.status == "converged" and ar.attrs["fim_s_fallbacks"] == 0
    assert len(starts) >= 6
    for chart, t0, y0, atol, tol, h0 in starts:
        F = chart.F(chart.state(y0, t0))
        dy = np.linalg.solve(chart.jac(y0, t0), -F)
        w = 1.0 / (tol * np.abs(y0) + atol)
        assert np.sqrt(np.mean((dy * w) ** 2)) <= 1e-3, t0
        assert h0 > 0
    # every start sizes its first step from the path (the deck writes no h0_max)
    assert all(s[5] > 1e-6 for s in starts), [s[5] for s in starts]


def test_written_h0_max_caps_the_first_step_only(monkeypatch, tmp_path):
    """An h0_max written in the deck's Param_Transient is the first run's first step (IDA
    raises it to h_min); restarts (internal re-initialisations) size theirs from the path. The
    schema has no h0_max default (the reference's 1e-8 is marked unsure, and it cost
    slider_crank_qs_1000 10 of its 27 IDA steps)."""
    firsts = []
    real = fd.run_ida

    def ida(chart, tsd, atol, t0, y0, yp0, first_step):
        firsts.append(first_step)
        return real(chart, tsd, atol, t0, y0, yp0, first_step)

    monkeypatch.setattr(fd, "run_ida", ida)
    src = open(os.path.join(DECKS, "qs_slider_crank_rev.xml")).read()
    deck = tmp_path / "h0.xml"
    deck.write_text(src.replace('<Param_Transient dae_constr_tol="1.0E-8"/>',
                                '<Param_Transient dae_constr_tol="1.0E-8" h0_max="2.5E-5"/>'))
    ar = run_deck(str(deck), {"method": "FIM_D"}, quiet=True).analyses[0]
    assert ar.status == "converged"
    assert firsts[0] == 2.5e-5 and len(firsts) >= 6
    assert all(h > 1e-6 and h != 2.5e-5 for h in firsts[1:]), firsts


class _Capture:
    """Records the Jacobians handed to IDA (sparse path) with the chart that produced them."""

    def __init__(self, monkeypatch):
        self.calls, self.patterns = [], []
        real_jac, real_ida = fd.Chart.jacfn_sparse, fd.run_ida
        cap = self

        def jacfn_sparse(chart, t, y, yp, res, cj, JJ):
            real_jac(chart, t, y, yp, res, cj, JJ)
            cap.calls.append((chart, float(t), np.array(y), np.array(JJ)))

        def ida(chart, *a, **k):
            cap.patterns.append(chart.sparse.pattern())
            return real_ida(chart, *a, **k)

        monkeypatch.setattr(fd.Chart, "jacfn_sparse", jacfn_sparse)
        monkeypatch.setattr(fd, "run_ida", ida)


def _fd_jacobian(chart, t, y):
    """Central differences of IDA's residual ``resfn`` (yp does not enter: all algebraic)."""
    m = chart.model
    n = len(y)
    scale = np.ones(n)
    scale[:m.nq] = np.where(m.q_kind == 1, 1e-6, 1e-6 * m.L)
    scale[m.nq:] = 1e-6 * max(1.0, np.abs(y[m.nq:]).max(initial=0.0))
    J = np.empty((n, n))
    rp, rm = np.empty(n), np.empty(n)
    yp = np.zeros(n)
    for j in range(n):
        h = scale[j]
        yy = y.copy()
        yy[j] += h
        chart.resfn(t, yy, yp, rp)
        yy[j] -= 2 * h
        chart.resfn(t, yy, yp, rm)
        J[:, j] = (rp - rm) / (2 * h)
    # removed (redundant) constraint rows: their multipliers are held at 0 (the KKT Jacobian's
    # row and column of such a multiplier are the unit vector; Model.jacobian)
    off = m.nq + np.nonzero(~chart.cnt.mask(m))[0]
    assert np.all(y[off] == 0.0)
    J[:, off] = 0.0
    J[off, off] = 1.0
    return J


@needs_expr
@pytest.mark.parametrize("case", ["chain", "bushing_3d"])
def test_sparse_jacobian_equals_finite_differences(tmp_path, monkeypatch, case):
    """Small models forced onto the sparse path: every CSC Jacobian handed to IDA (the KKT
    Jacobian times diag(I, J_l(w)) on the union pattern) equals central differences of the IDA
    residual, entries outside the pattern included; and the sparse run reproduces the dense
    one."""
    if case == "chain":
        path = _qs_chain(tmp_path, 8, load=1000.0, dt=0.25,
                         static='method="FIM_D" stability="0"')
    else:
        path = _bushing_3d(tmp_path)
    dense = run_deck(path, None, quiet=True).analyses[0]
    assert dense.attrs["ida_linear_solver"] == "dense"
    monkeypatch.setattr(fd, "SPARSE_MIN", 0)
    cap = _Capture(monkeypatch)
    ar = run_deck(path, None, quiet=True).analyses[0]
    assert ar.status == "converged" and ar.attrs["fim_s_fallbacks"] == 0, ar.message
    assert ar.attrs["ida_linear_solver"] == "sparse" and len(cap.calls) >= 3
    np.testing.assert_allclose(ar.datasets["bodies/position"], dense.datasets["bodies/position"],
                               rtol=0, atol=1e-9 * np.abs(dense.datasets["bodies/position"]).max())
    pattern = cap.patterns[0]
    # the last Jacobians are far from the reference (rotations of several degrees+)
    wmax = 0.0
    for chart, t, y, JJ in (cap.calls[len(cap.calls) // 2], cap.calls[-1]):
        m = chart.model
        w = np.linalg.norm(y[m.rot_idx].reshape(-1, 3), axis=1).max()
        wmax = max(wmax, w)
        A = chart.sparse.matrix(JJ).toarray()
        assert chart.sparse.nnz == pattern.nnz
        Jfd = _fd_jacobian(chart, t, y)
        s = np.abs(Jfd).max()
        np.testing.assert_allclose(A, Jfd, rtol=0, atol=2e-7 * s)
        # outside the pattern handed to IDA the residual does not depend on y
        outside = pattern.toarray() == 0
        assert np.abs(Jfd[outside]).max(initial=0.0) <= 2e-7 * s
    assert wmax > 0.05
    if case == "bushing_3d":
        w = y[m.rot_idx].reshape(-1, 3)[0]
        assert np.all(np.abs(w) > 1e-3), w          # rotated about all three axes


def _residual_calls(monkeypatch):
    calls = []
    real = fd.Chart.resfn

    def resfn(chart, t, y, yp, res):
        calls.append((float(t), np.array(y), np.array(yp)))
        return real(chart, t, y, yp, res)

    monkeypatch.setattr(fd.Chart, "resfn", resfn)
    return calls


def test_step_order_matches_bdf_coefficient(monkeypatch):
    """``steps/order`` (IDAGetLastOrder) checked independently: within one Newton solve IDA
    evaluates the residual at ``y = y_pred + e``, ``y' = y'_pred + c_j e`` with
    ``c_j h = sum_{i<=k} 1/i`` (fixed-leading-coefficient BDF of order k), so two residual calls
    at an accepted step's time give ``c_j`` and hence k. ``nonlinear_iterations``
    (IDAGetNumNonlinSolvIters) equals the number of residual evaluations of the step."""
    calls = _residual_calls(monkeypatch)
    ar = run_deck(os.path.join(DECKS, "qs_slider_crank_rev.xml"), {"method": "FIM_D"},
                  quiet=True).analyses[0]
    assert ar.status == "converged" and ar.attrs["fim_s_fallbacks"] == 0
    order = _check_steps(ar)
    assert order.max() >= 3                 # IDA raises the order on this smooth path
    d = ar.datasets
    t_steps, h = np.asarray(d["steps/time"]), np.asarray(d["steps/step_size"])
    by_t = {}
    for t, y, yp in calls:
        by_t.setdefault(t, []).append((y, yp))
    checked = 0
    for i, (t, k) in enumerate(zip(t_steps, order)):
        pts = by_t.get(float(t), [])
        if len(pts) < 2:
            continue
        (y1, p1), (y2, p2) = pts[0], pts[-1]
        dy = y2 - y1
        cj = float(np.dot(p2 - p1, dy) / np.dot(dy, dy))
        kk = min(HARMONIC, key=lambda q: abs(HARMONIC[q] - cj * h[i]))
        # c_j comes from the difference of two corrector iterates, which can be ~1e-10 of y
        # (tight convergence coefficient): ~1e-5 rounding. Harmonic numbers differ by >= 4 %.
        assert kk == k and abs(cj * h[i] - HARMONIC[k]) < 1e-3 * HARMONIC[k], \
            (i, k, kk, cj * h[i])
        checked += 1
    assert checked >= 5
    # Newton iterations: one residual evaluation each (steps with no failed attempt)
    nli = np.asarray(d["steps/nonlinear_iterations"])
    clean = (np.asarray(d["steps/error_test_failures"]) == 0) & \
        (np.asarray(d["steps/convergence_failures"]) == 0)
    n_at = np.array([len(by_t.get(float(t), [])) for t in t_steps])
    sel = clean & (n_at > 0)
    assert sel.sum() > 0.8 * len(t_steps)
    np.testing.assert_array_equal(nli[sel], n_at[sel])


def test_step_order_respects_max_order(tmp_path):
    text = open(os.path.join(DECKS, "qs_slider_crank_rev.xml")).read()
    old = '<Param_Transient dae_constr_tol="1.0E-8"/>'
    assert old in text
    text = text.replace(old, '<Param_Transient dae_constr_tol="1.0E-5" max_order="2"/>')
    p = tmp_path / "max2.xml"
    p.write_text(text)
    ar = run_deck(str(p), {"method": "FIM_D"}, quiet=True).analyses[0]
    assert ar.status == "converged"
    order = _check_steps(ar, max_order=2)
    assert order.max() == 2


def test_step_counters_unavailable(monkeypatch):
    """If IDA's memory cannot be located safely, the order is -1 (documented), the message says
    why, the corrector coefficient stays at IDA's default 0.33 (said in the message too), and
    the integration is otherwise unchanged: identical to a run with the counters readable and
    the coefficient set to 0.33, and within the tolerance of the default run."""
    deck = os.path.join(DECKS, "qs_slider_crank_rev.xml")
    default = run_deck(deck, {"method": "FIM_D"}, quiet=True).analyses[0]
    import poise.solvers.ida as ida     # IDA's settings live there (split from fim_d)
    monkeypatch.setattr(ida, "NONLIN_CONV_COEF", 0.33)
    ref = run_deck(deck, {"method": "FIM_D"}, quiet=True).analyses[0]
    assert "corrector coefficient" not in ref.message
    monkeypatch.setattr(ida, "NONLIN_CONV_COEF", 0.03)
    monkeypatch.setattr(fd.IdaStats, "_BASICSIZE", -1)
    ar = run_deck(deck, {"method": "FIM_D"}, quiet=True).analyses[0]
    assert ar.status == "converged"
    assert np.all(np.asarray(ar.datasets["steps/order"]) == -1)
    assert np.all(np.asarray(ar.datasets["steps/convergence_failures"]) == -1)
    assert "IDA step order not available: unknown scikit-sundae solver layout" in ar.message
    assert ("IDA corrector coefficient left at IDA's default 0.33 (not 0.03): unknown "
            "scikit-sundae solver layout") in ar.message
    np.testing.assert_allclose(ar.datasets["bodies/position"],
                               default.datasets["bodies/position"], rtol=0, atol=1e-5)
    assert ar.attrs["ida_steps"] == ref.attrs["ida_steps"]
    np.testing.assert_array_equal(ar.datasets["steps/time"], ref.datasets["steps/time"])
    np.testing.assert_array_equal(ar.datasets["steps/nonlinear_iterations"],
                                  ref.datasets["steps/nonlinear_iterations"])
    np.testing.assert_array_equal(ar.datasets["bodies/position"], ref.datasets["bodies/position"])
