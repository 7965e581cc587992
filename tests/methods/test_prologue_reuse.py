"""The static prologue's one evaluation: the redundancy test's (every row active) read with the
solve's active rows is, bit for bit, the evaluation made with those rows (dense and sparse
KKT), and a static solve's counters show the evaluations it saved."""
import numpy as np
import pytest
import scipy.sparse as sp

from poise.deck.parser import load_deck
from poise.gen.chain import build_chain_deck
from poise.model.compile import compile_model
from poise.solvers.redundancy import _transposed, detect_redundancy, without_rows


def _model(tmp_path, n):
    p = tmp_path / f"chain_{n}.xml"
    p.write_text(build_chain_deck(n, "revolute"))      # a closed planar loop of 3-D revolutes
    return compile_model(load_deck(str(p)))


def _dense(J):
    return J.toarray() if sp.issparse(J) else np.asarray(J)


@pytest.mark.parametrize("n", [12, 120])               # dense and sparse KKT
def test_all_rows_evaluation_read_with_active_rows_is_the_masked_evaluation(tmp_path, n):
    model = _model(tmp_path, n)
    assert model.assembler.dense == (n == 12)
    state = model.initial_state()
    state.pos = state.pos + 1e-3 * np.sin(np.arange(state.pos.size)).reshape(state.pos.shape)
    red = detect_redundancy(model, state)
    assert len(red) == 3                                # the loop's out-of-plane equations
    active = np.ones(model.nc, bool)
    active[red] = False
    ref = model.evaluate(state, need_jac=True, active=active)
    got = without_rows(model, model.evaluate(state, need_jac=True), active)
    np.testing.assert_array_equal(got.r, ref.r)
    np.testing.assert_array_equal(got.phi, ref.phi)
    assert np.any(got.phi == 0.0) and np.all(got.phi[red] == 0.0)
    np.testing.assert_array_equal(_dense(got.J), _dense(ref.J))
    if n == 120:             # the assembler's column order goes with the matrix (linalg.Factor)
        assert got.J.poise_column_order is not None
        np.testing.assert_array_equal(got.J.indices, ref.J.indices)
        # the removed rows' columns found in the rows they touch are every entry of them
        J, cols = ref.J, model.nq + red
        at = _transposed(J, cols)
        np.testing.assert_array_equal(np.sort(at), np.flatnonzero(np.isin(J.indices, cols)))
    assert _dense(got.J)[model.nq + red[0], model.nq + red[0]] == 1.0


def test_static_solve_evaluates_once_for_redundancy_assembly_and_multipliers(tmp_path,
                                                                           monkeypatch):
    import poise.solvers.context as context_mod
    import poise.solvers.quasistatic as qs_mod
    from poise.app.runner import plan
    from poise.solvers.driver import Driver
    p = tmp_path / "chain.xml"
    p.write_text(build_chain_deck(12, "revolute"))
    spec = load_deck(str(p))
    model = compile_model(spec)
    drv = Driver(model, plan(spec, None)[0])
    calls, reused, before_newton = [], [], []
    real = drv.data.evaluate
    monkeypatch.setattr(drv.data, "evaluate", lambda *a, **k: calls.append(a) or real(*a, **k))
    im = context_mod.initial_multipliers
    monkeypatch.setattr(context_mod, "initial_multipliers", lambda *a, ev=None, **k:
                        reused.append(ev is not None) or im(*a, ev=ev, **k))
    sf = qs_mod.solve_frame
    monkeypatch.setattr(qs_mod, "solve_frame", lambda *a, **k:
                        before_newton.append(len(calls)) or sf(*a, **k))
    state, rec = drv.run(model.initial_state())
    assert rec.status == "converged"
    assert len(drv.redundancy) == 3
    assert reused == [True]            # the multipliers used the prologue's evaluation
    assert before_newton == [1]        # redundancy, assembly, multipliers: one evaluation
    c = drv.data.as_dict()
    assert c["jacobians"] == c["factorizations"]   # one per Newton iteration + the prologue's


def test_weighted_kkt_is_the_block_matrix_of_its_four_blocks(tmp_path):
    from poise.solvers.reach import coord_weights, weighted_kkt
    model = _model(tmp_path, 120)
    state = model.initial_state()
    active = np.ones(model.nc, bool)
    active[detect_redundancy(model, state)] = False
    ev = model.evaluate(state, need_jac=True, active=active)
    J, nq, W = ev.J, model.nq, coord_weights(model)
    ref = sp.bmat([[sp.diags(W), J[:nq, nq:]], [J[nq:, :nq], J[nq:, nq:]]], format="csc")
    ref.sort_indices()
    K = weighted_kkt(model, ev, W)
    assert K.format == "csc" and K.poise_column_order is not None
    for a in ("indptr", "indices", "data"):              # the same matrix, stored zeros included
        np.testing.assert_array_equal(getattr(K, a), getattr(ref, a))
