"""A curve whose points come from a ``Reference_Matrix`` (``decks/elem_ptcv_matrix.xml``) against
the closed form, and the three inline matrix forms (column order, row order, sparse) solving to
the same answer.

A 1 kg point on a straight incline e = (0.8, 0.6, 0) through the origin (a spline through
collinear points is the line), pulled up the line by a spring k = 100 N/m (free length 1 m) from
the top end at s = 2 m: k (1 - s) = m g 0.6, s = 1 - 0.6 g / k.
"""
import re

import numpy as np
import pytest

from poise.app.api import run_deck

from support.paths import DECKS

G, K = 9.81, 100.0
E = np.array([0.8, 0.6, 0.0])
PTS = np.outer([0.0, 0.5, 1.0, 1.5, 2.0], E)                 # 5 x 3, one point per row


def _solve(tmp_path, matrix=None):
    text = (DECKS / "elem_ptcv_matrix.xml").read_text()
    if matrix is not None:
        text = re.sub(r"<Reference_Matrix .*?</Reference_Matrix>", matrix, text, flags=re.S)
    p = tmp_path / "d.xml"
    p.write_text(text)
    a = run_deck(str(p)).analyses[0]
    assert a.converged, a.message
    return a.datasets


def _row_order():
    vals = " ".join(f"{float(v)!r}" for v in PTS.ravel())
    return (f'<Reference_Matrix id="7" nrow="5" ncol="3" isroworder="TRUE">{vals}'
            '</Reference_Matrix>')


def _sparse():
    nz = [(i + 1, j + 1, PTS[i, j]) for i in range(5) for j in range(3) if PTS[i, j] != 0]
    vals = "  ".join(f"{i} {j} {float(v)!r}" for i, j, v in nz)
    return (f'<Reference_Matrix id="7" nrow="5" ncol="3" issparse="TRUE" nval="{len(nz)}">'
            f'{vals}</Reference_Matrix>')


def test_curve_from_matrix_closed_form(tmp_path):
    d = _solve(tmp_path)
    s = 1.0 - 0.6 * G / K
    np.testing.assert_allclose(d["bodies/position"][-1, 0], s * E, atol=1e-10)
    normal = [0.0, G, 0.0] - 0.6 * G * E               # -(gravity + spring), normal to e
    np.testing.assert_allclose(d["curves/force"][-1, 0], normal, atol=1e-8)
    assert abs(d["curves/force"][-1, 0] @ E) < 1e-9


@pytest.mark.parametrize("form", [_row_order, _sparse], ids=["row-order", "sparse"])
def test_matrix_forms_give_the_same_curve(tmp_path, form):
    a = _solve(tmp_path)
    b = _solve(tmp_path, form())
    np.testing.assert_allclose(b["bodies/position"], a["bodies/position"], rtol=0, atol=1e-14)
    np.testing.assert_allclose(b["curves/force"], a["curves/force"], rtol=0, atol=1e-12)


@pytest.mark.parametrize("matrix,msg", [
    ('<Reference_Matrix id="7" nrow="5" ncol="2">0 1 2 3 4 5 6 7 8 9</Reference_Matrix>',
     "has 2 columns; expected 3"),
])
def test_unusable_curve_matrix_is_located(tmp_path, matrix, msg):
    from poise.core.errors import DeckError
    with pytest.raises(DeckError) as e:
        _solve(tmp_path, matrix)
    assert "<Reference_ParamCurve id=1> matrix_id:" in str(e.value)
    assert msg in str(e.value)


def test_control_points_are_refused_not_misread(tmp_path):
    """is_curve_points="FALSE" (Adams CURVE without CURVE_POINTS: B-spline control points)
    would be silently misread as points on the curve: a located error instead."""
    from poise.core.errors import DeckError
    text = (DECKS / "elem_ptcv_matrix.xml").read_text().replace('is_curve_points="TRUE"',
                                                                'is_curve_points="FALSE"')
    p = tmp_path / "cp.xml"
    p.write_text(text)
    with pytest.raises(DeckError) as e:
        run_deck(str(p))
    assert "<Reference_ParamCurve id=1> is_curve_points:" in str(e.value)
    assert "control points" in str(e.value)
