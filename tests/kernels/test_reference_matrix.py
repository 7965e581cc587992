"""``Reference_Matrix`` values (poise.deck.matrix): full forms in both orders, the sparse form,
and every malformed matrix a located deck error, also when nothing uses it."""
import numpy as np
import pytest

from poise.core.errors import DeckError
from poise.deck.parser import load_deck as parse_deck


M = np.arange(1.0, 13.0).reshape(3, 4)          # 3 x 4, M[i, j] = 4 i + j + 1

HEAD = """<MotionSolve><Model>
<Body_Rigid id="1" isground="TRUE" cg_id="10"/>
<Reference_Marker id="10" body_id="1"/>
"""
TAIL = "</Model><Command><Simulate analysis_type=\"Static\"/></Command></MotionSolve>\n"


def _deck(tmp_path, matrix):
    p = tmp_path / "m.xml"
    p.write_text(HEAD + matrix + "\n" + TAIL)
    return p


def _values(tmp_path, matrix):
    from poise.core.errors import ProblemCollector
    from poise.deck.matrix import matrix_values
    spec = parse_deck(str(_deck(tmp_path, matrix)))
    pc = ProblemCollector()
    out = matrix_values(spec.elements("Reference_Matrix")[0], pc)
    assert not pc.problems
    return out


def test_full_column_order_is_the_default(tmp_path):
    txt = " ".join(f"{v:g}" for v in M.T.ravel())
    got = _values(tmp_path, f'<Reference_Matrix id="1" nrow="3" ncol="4">{txt}</Reference_Matrix>')
    np.testing.assert_array_equal(got, M)


def test_full_row_order_with_commas_and_fortran_exponents(tmp_path):
    txt = ",\n".join(", ".join(f"{v:g}D0" for v in row) for row in M)
    got = _values(tmp_path, f'<Reference_Matrix id="1" nrow="3" ncol="4" isroworder="TRUE">'
                            f'{txt}</Reference_Matrix>')
    np.testing.assert_array_equal(got, M)


def test_sparse_triples(tmp_path):
    got = _values(tmp_path, '<Reference_Matrix id="1" nrow="3" ncol="4" issparse="TRUE" nval="3">'
                            '1 1 2.5  3 4 -1  2,3,7</Reference_Matrix>')
    want = np.zeros((3, 4))
    want[0, 0], want[2, 3], want[1, 2] = 2.5, -1.0, 7.0
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("matrix,msg", [
    ('<Reference_Matrix id="1" nrow="2" ncol="2">1 2 3</Reference_Matrix>',
     "text has 3 values; expected nrow x ncol = 4"),
    ('<Reference_Matrix id="1" nrow="2" ncol="2">1 2 x 4</Reference_Matrix>',
     "not a list of numbers"),
    ('<Reference_Matrix id="1" nrow="2" ncol="2" issparse="TRUE" nval="2">1 1 1</Reference_Matrix>',
     "nval=2 but the text has 1"),
    ('<Reference_Matrix id="1" nrow="2" ncol="2" issparse="TRUE">3 1 1</Reference_Matrix>',
     "outside the 2 x 2 matrix"),
    ('<Reference_Matrix id="1" nrow="2" ncol="2" issparse="TRUE">1 1 1 1 1 2</Reference_Matrix>',
     "repeats (1, 1)"),
    ('<Reference_Matrix id="1" nrow="2" ncol="2" issparse="TRUE">1.5 1 1</Reference_Matrix>',
     "must be integers"),
    ('<Reference_Matrix id="1" nrow="2" ncol="2" issparse="TRUE">1 1 1 2</Reference_Matrix>',
     "row col value triples"),
    ('<Reference_Matrix id="1" nrow="1" ncol="1">nan</Reference_Matrix>', "not a finite number"),
    ('<Reference_Matrix id="1" nrow="1" ncol="1" script_name="m.py">1</Reference_Matrix>',
     "user-subroutine matrices are not supported"),
    ('<Reference_Matrix id="1" nrow="0" ncol="2"></Reference_Matrix>', "'nrow' out of range"),
    ('<Reference_Matrix id="1" ncol="2">1 2</Reference_Matrix>', "'nrow'"),
])
def test_malformed_matrix_is_a_located_error_even_unused(tmp_path, matrix, msg):
    with pytest.raises(DeckError) as e:
        parse_deck(str(_deck(tmp_path, matrix)))
    assert "m.xml:4: <Reference_Matrix id=1>" in str(e.value)
    assert msg in str(e.value)


def test_curve_matrix_id_must_name_a_matrix(tmp_path):
    with pytest.raises(DeckError) as e:
        parse_deck(str(_deck(tmp_path, '<Reference_ParamCurve id="1" matrix_id="9"/>')))
    assert "<Reference_ParamCurve id=1>: attribute 'matrix_id' refers to a missing" in str(e.value)
