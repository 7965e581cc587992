"""Evaluation and factorisation through reused buffers give bitwise what fresh arrays give.

Large models keep per-solve buffers in the workspace (the assembler's pooled data buffers, its
column-ordered CSC layout, the families' residual scatter); each must give
exactly the values of the plain computation, and a matrix still referred to must never see
its data overwritten by a later assembly.
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from poise.core.readonly import slot_names
from poise.model.assembly import POOL_ABOVE, Assembler, Few, Scatter, Zeros
from poise.model.workspace import Workspace
from support.builders import perturbed_chain
from poise.solvers.data import SolveData
from poise.solvers.linalg import Factor, _layout_nonzeros, stored_nonzeros


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """A 400-link chain (its KKT pattern above POOL_ABOVE entries) and a perturbed state."""
    model, st = perturbed_chain(tmp_path_factory.mktemp("chain"), 400, 3)
    assert model.assembler.nnz > POOL_ABOVE
    return model, st



def scatter_add(n, idx, vals):
    """The fresh-array scatter the evaluation used before :class:`Scatter` (the reference)."""
    idx = np.asarray(idx).ravel()
    vals = np.asarray(vals, float).ravel()
    v = idx >= 0
    return np.bincount(idx[v], weights=vals[v], minlength=n)

def _bits(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


def test_a_kept_workspace_gives_the_bits_of_fresh_evaluations(chain):
    model, st = chain
    ws = Workspace()
    for _ in range(3):                          # the second and third reuse every buffer
        ev = model.evaluate(st, need_jac=True, eps_mass=1e-3, workspace=ws)
        fresh = model.evaluate(st, need_jac=True, eps_mass=1e-3)
        assert _bits(ev.r, fresh.r) and _bits(ev.phi, fresh.phi)
        assert _bits(ev.J.data, fresh.J.data)
        assert np.array_equal(ev.J.indices, fresh.J.indices)


def test_pooled_assembly_sums_like_bincount_and_spares_live_matrices(chain, monkeypatch):
    model, st = chain
    data = SolveData(np.ones(model.nc, bool))
    st2 = model.retract(st, 1e-3 * np.ones(model.nq))
    J1 = data.jacobian(model, data.evaluate(model, st, "defer", eps=1e-3))
    kept = J1.data.copy()
    later = [data.jacobian(model, data.evaluate(model, s, "defer", eps=1e-3))
             for s in (st2, st, st2)]
    assert _bits(J1.data, kept)                 # J1 alive: its buffer was not reused
    assert all(not np.shares_memory(J1.data, J.data) for J in later)
    asm = model.assembler
    vals = []
    orig = Assembler.assemble

    def grab(self, values, workspace=None):
        vals.extend(v.dense() if isinstance(v, Zeros) else np.asarray(v, float).ravel()
                    for v in values)
        return orig(self, values, workspace)

    monkeypatch.setattr(Assembler, "assemble", grab)
    import poise.model.assembly as assembly
    monkeypatch.setattr(assembly, "_CHUNK", 1000)            # each block summed in chunks
    J = data.jacobian(model, data.evaluate(model, st, "defer", eps=1e-3))
    ref = np.bincount(asm.slot_all, weights=np.concatenate(vals), minlength=asm.nnz + 1)
    assert _bits(J.data, ref[:asm.nnz]) and _bits(J.data, kept)


def test_scatter_is_scatter_add_with_its_index_kept():
    rng = np.random.default_rng(0)
    for size in (50, 2 * POOL_ABOVE):
        idx = rng.integers(-1, 700, size)
        vals = rng.standard_normal(size)
        sc = Scatter(700, idx)
        out = rng.standard_normal(700)
        ref = out + scatter_add(700, idx, vals)
        for _ in range(2):
            got = out.copy()
            sc.add(got, vals)
            assert _bits(got, ref)


def test_the_csc_layout_is_the_column_ordered_matrix_and_factorises_alike(chain):
    model, st = chain
    ws = Workspace()
    J = model.evaluate(st, need_jac=True, eps_mass=1e-3, workspace=ws).J
    order = J.poise_column_order()
    assert order is model.assembler.ordered() and not order.flags.writeable   # the model's, kept
    lay = J.poise_csc_layout()                   # made at the first factorisation, kept
    assert J.poise_csc_layout() is lay
    assert lay.fits(J) and not lay.fits(sp.csr_matrix(J.toarray()))
    A = lay.matrix(J)
    B = J.tocsc()[:, order]
    assert _bits(A.data, B.data) and np.array_equal(A.indices, B.indices)
    assert np.array_equal(A.indptr, B.indptr)
    b = J @ np.linspace(-1.0, 1.0, J.shape[0])
    x_layout = Factor(J).solve(b)                # through the layout
    plain = sp.csr_matrix(J)
    plain.poise_column_order = lambda: order     # no layout: CSC conversion + selection
    assert _bits(x_layout, Factor(plain).solve(b))


def test_the_layout_of_the_nonzeros_gives_the_stored_nonzeros_while_the_zeros_stay(chain):
    model, st = chain
    ws = Workspace()
    J1 = model.evaluate(st, need_jac=True, workspace=ws).J
    lay = J1.poise_csc_layout()
    st2 = model.retract(st, 1e-3 * np.ones(model.nq))
    J2 = model.evaluate(st2, need_jac=True, workspace=ws).J
    J3 = model.evaluate(st2, need_jac=True, eps_mass=1e-3, workspace=ws).J   # other zeros
    assert np.array_equal(J1.data != 0, J2.data != 0)
    assert not np.array_equal(J1.data != 0, J3.data != 0)
    assert (J1.data == 0).sum() > J1.nnz // 20          # stored zeros to leave out
    subs = []
    for J in (J1, J2, J3, J1):
        want = stored_nonzeros(lay.matrix(J))
        got = _layout_nonzeros(lay, J)
        assert want.nnz < J.nnz and _bits(got.data, want.data)
        assert _bits(got.indices, want.indices) and _bits(got.indptr, want.indptr)
        subs.append(lay.kept)
    # made at the first, kept at the second (the same zeros), made anew at a change of zeros
    assert subs[1] is subs[0] and subs[2] is not subs[1] and subs[3] is not subs[2]


def quotient_order(asm, groups):
    """The column order from the quotient pattern made by sparse products ``E^T S E`` (the
    reference for :meth:`Assembler.column_order`'s merged rows)."""
    import scipy.sparse.linalg as spla
    grp = np.asarray(groups, np.int64)
    G, N = int(grp.max()) + 1, asm.N
    E = sp.csr_matrix((np.ones(N), (np.arange(N), grp)), shape=(N, G))
    S = sp.csr_matrix((np.ones(asm.nnz), asm.indices, asm.indptr), shape=(N, N))
    Q = (E.T @ S @ E).tocsc()
    Q.data[:] = 1.0
    Q = (Q + sp.identity(G, format="csc") * (G + 1.0)).tocsc()
    pc = spla.splu(Q, permc_spec="COLAMD", panel_size=1).perm_c
    return np.argsort(pc[grp], kind="stable")


def test_the_column_order_is_that_of_the_quotient_pattern_whatever_the_group_labels(chain):
    model, _ = chain
    asm = model.assembler
    assert np.all(np.diff(asm.groups) >= 0)        # the model's groups: rows in group order
    assert np.array_equal(asm.column_order(), quotient_order(asm, asm.groups))
    rng = np.random.default_rng(5)
    G = int(np.max(asm.groups)) + 1
    for grp in (rng.permutation(G)[asm.groups],                # contiguous, labels shuffled
                rng.integers(0, G // 3, asm.N)):              # interleaved rows
        other = object.__new__(Assembler)
        for name in slot_names(Assembler):
            setattr(other, name, getattr(asm, name))
        other.groups = grp
        assert np.array_equal(other.column_order(), quotient_order(asm, grp))


def test_large_patterns_keep_int32_indices_and_assemble_alike(chain, monkeypatch):
    import poise.model.assembly as assembly
    model, st = chain
    asm = model.assembler
    assert asm.slot_all.dtype == np.int32        # pooled pattern: half the index memory
    ws = Workspace()
    J = model.evaluate(st, need_jac=True, eps_mass=1e-3, workspace=ws).J
    fresh = model.evaluate(st, need_jac=True, eps_mass=1e-3).J    # bincount, no pool
    assert _bits(J.data, fresh.data)
    lay = J.poise_csc_layout()
    assert lay.take.dtype == np.int32
    whole = lay.matrix(J).data.copy()
    monkeypatch.setattr(assembly, "_CHUNK", 1000)                # gathered in many chunks
    assert _bits(lay.matrix(J).data, whole)
    assert _bits(whole, J.tocsc()[:, J.poise_column_order()].data)


def test_a_matrix_no_longer_referred_to_lends_its_buffer_to_the_next(chain):
    model, st = chain
    data = SolveData(np.ones(model.nc, bool))
    J = data.jacobian(model, data.evaluate(model, st, "defer", eps=1e-3))
    where = J.data.__array_interface__["data"][0]
    first = J.data.copy()
    del J
    J = data.jacobian(model, data.evaluate(model, st, "defer", eps=1e-3))
    assert J.data.__array_interface__["data"][0] == where       # reused, not a fresh array
    assert _bits(J.data, first)
    model.assembler.release(data.workspace)                      # dropped: J keeps its own
    assert _bits(J.data, first)


@pytest.mark.parametrize("n", [40, 2 * POOL_ABOVE])
def test_zero_and_few_blocks_sum_like_their_dense_values(n):
    # blocks of zeros (some -0.0) skipped, a block that is zero but at a few entries added
    # there only: the same bits as the dense blocks, in the bincount and the pooled paths
    rng = np.random.default_rng(3)
    N = 30 if n < POOL_ABOVE else 300         # a pattern of POOL_ABOVE entries or more: pooled
    blocks = [(rng.integers(-1, N, n), rng.integers(0, N, n)) for _ in range(4)]
    asm = Assembler(N, list(blocks))
    assert (asm.nnz >= POOL_ABOVE) == (n >= POOL_ABOVE)
    dense = [rng.standard_normal(n), -np.zeros(n), rng.standard_normal(n), np.zeros(n)]
    dense[0][::7] = -0.0
    idx = np.array([1, 5, n - 1])
    dense[3][idx] = [2.0, -0.0, -3.5]
    got = asm.assemble([dense[0], Zeros(n), dense[2], Few(n, idx, dense[3][idx])],
                       Workspace())
    ref = asm.assemble(dense, Workspace())
    assert _bits(got.data, ref.data)
    assert not np.any(np.signbit(got.data) & (got.data == 0.0))      # never -0.0
