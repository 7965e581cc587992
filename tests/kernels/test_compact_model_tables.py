"""The compact stores of a compiled model give back exactly what was put in.

Large models keep per-element names in one string (``Texts``), row descriptions as columns
(``RowTable``), and build their sparse pattern block by block (``Assembler``): each is checked
here against the plain structure it replaces (tuples of strings, row dictionaries, one
``np.unique`` over all keys), value for value and type for type.
"""
from __future__ import annotations

import numpy as np
import pytest

from poise.elements.rows import KEYS, CoordNames, RowTable, Texts
from poise.model.assembly import Assembler


def test_texts_give_back_each_string():
    words = ["Link 1", "", "Gelenk ü", "関節", "x" * 300, ""]
    t = Texts(words)
    assert len(t) == len(words)
    assert [t[k] for k in range(len(t))] == words
    assert list(t) == words
    assert t[-3] == "関節" and t[1:4] == tuple(words[1:4])
    assert all(type(s) is str for s in t)
    assert np.asarray(t, dtype=str).tolist() == words
    with pytest.raises(IndexError):
        t[len(words)]
    assert len(Texts()) == 0 and list(Texts()) == []


def test_row_table_columns_keep_values_and_types():
    rows = [dict(zip(KEYS, (tag, ident, eq, line, "deck.xml", kind, "joints", owner, label,
                            f"deck.xml:{line}: <{tag} id={ident}>")))
            for tag, ident, eq, line, kind, owner, label in (
                ("Constraint_Joint", 7, "x", 12, "position", 0, "pin"),
                ("Constraint_Joint", 7, "y", 12, "position", 0, "pin"),
                ("Constraint_Joint", 2 ** 40, "z", 30, "orientation", 1, ""),
                ("Constraint_General", None, "f", 41, "expression", 2, "gen ü"))]
    t = RowTable.of(rows)
    assert isinstance(t, RowTable)
    got = list(t)
    assert got == rows
    assert [type(d["id"]) for d in got] == [int, int, int, type(None)]
    assert all(type(d["line"]) is int for d in got)


def test_coordinate_names_from_one_string():
    names = CoordNames(["a.xml:3: <Body_Rigid id=2>", "a.xml:9: <Body_Rigid id=3>"],
                       [0, 6], 9, extra=("Dd 1",))
    assert names[0] == "a.xml:3: <Body_Rigid id=2> Fx"
    assert names[8] == "a.xml:9: <Body_Rigid id=3> Fz"
    assert names[9] == "Dd 1" and len(names) == 10


@pytest.mark.parametrize("dense", [False, True])
def test_assembler_pattern_equals_one_unique_over_all_keys(dense):
    rng = np.random.default_rng(3)
    N = 40
    blocks = []
    for shape in ((50, 4), (7,), (30, 3, 3), (200,)):
        r = rng.integers(-1, N, shape)
        c = rng.integers(-1, N, shape)
        blocks.append((r, c))
    a = Assembler(N, (b for b in blocks), dense=dense)       # a generator of blocks
    rows = np.concatenate([r.ravel() for r, _ in blocks])
    cols = np.concatenate([c.ravel() for _, c in blocks])
    valid = (rows >= 0) & (cols >= 0)
    keys = rows[valid].astype(np.int64) * N + cols[valid]
    if dense:
        expect_slot = keys
    else:
        uniq, expect_slot = np.unique(keys, return_inverse=True)
        assert a.nnz == uniq.size
        assert np.array_equal(a.indices, uniq % N) and a.indices.dtype == np.int32
        assert np.array_equal(a.indptr, np.searchsorted(uniq // N, np.arange(N + 1)))
    expect = np.full(rows.size, a.nnz)
    expect[valid] = expect_slot
    assert np.array_equal(a.slot_all, expect) and a.slot_all.dtype == np.intp   # small: intp
    assert a.sizes == tuple(r.size for r, _ in blocks)
    # assembling puts each value at its entry (sums duplicates, drops invalid entries)
    vals = [rng.standard_normal(r.shape) for r, _ in blocks]
    M = a.assemble(vals)
    ref = np.zeros((N, N))
    np.add.at(ref, (rows[valid], cols[valid]), np.concatenate([v.ravel() for v in vals])[valid])
    got = M if dense else M.toarray()
    assert np.allclose(got, ref, rtol=0, atol=1e-12)
