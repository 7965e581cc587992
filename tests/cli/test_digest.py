"""The results digest's two comparisons: bitwise, and of answers (``--answers``), which accepts
last-bit changes of float answers and changed histories but nothing else."""
from __future__ import annotations

import h5py
import numpy as np

from benchmarks.digest import ANSWER_RTOL, compare


def _write(d, name, *, pos, status="converged", its=(5,), n_negative=0, imbalance=1e-13):
    d.mkdir(exist_ok=True)
    (d / f"{name}.rc").write_text("0\n")
    with h5py.File(d / f"{name}.h5", "w") as f:
        a = f.create_group("analysis_000")
        a["bodies/position"] = np.asarray(pos, float)
        a["frames/status"] = np.array([status], dtype=h5py.string_dtype())
        a["frames/n_negative"] = np.array([n_negative])
        a["frames/iterations"] = np.array(its)
        a["frames/imbalance"] = np.array([imbalance])
        a["iterations/imbalance"] = np.linspace(1.0, 1e-13, int(sum(its)) + 1)
        f.create_group("counts").attrs["factorisations"] = int(sum(its))


POS = [[0.0, -1.0, 0.0], [2.5, -3.0, 1e-17]]


def test_last_bit_changes_are_the_same_answers_but_not_the_same_bits(tmp_path, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    _write(a, "deck", pos=POS)
    moved = np.asarray(POS) * (1 + 3e-15)
    moved[1, 2] = 4e-16                      # a value at round-off relative to the dataset's scale
    _write(b, "deck", pos=moved, its=(6,), imbalance=2e-14)
    assert compare(a, b) == 1                # bitwise: they differ
    assert compare(a, b, answers=True) == 0
    out = capsys.readouterr().out
    assert "iterations 5 -> 6" in out
    assert "0 answer differences, 1 with changed iteration counts, 1 with the same answers but " \
           "different bits" in out


def test_a_moved_answer_or_a_changed_verdict_is_an_answer_difference(tmp_path, capsys):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    _write(a, "deck", pos=POS)
    moved = np.asarray(POS).copy()
    moved[0, 1] += 20 * ANSWER_RTOL * 3.0
    _write(b, "deck", pos=moved)
    _write(c, "deck", pos=POS, n_negative=1)
    assert compare(a, b, answers=True) == 1
    out = capsys.readouterr().out
    assert "/analysis_000/bodies/position: largest difference" in out
    assert compare(a, c, answers=True) == 1
    assert "/analysis_000/frames/n_negative: values differ" in capsys.readouterr().out


def test_a_different_exit_code_is_an_answer_difference(tmp_path, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    _write(a, "deck", pos=POS)
    _write(b, "deck", pos=POS, status="failed")
    (b / "deck.rc").write_text("1\n")
    assert compare(a, b, answers=True) == 1
    assert "exit 0 != 1" in capsys.readouterr().out
