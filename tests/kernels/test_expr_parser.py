"""Tokenizer / parser: numbers, degrees, precedence, syntax errors with exact columns."""
from __future__ import annotations

import math

import pytest

from poise.core.errors import DeckError
from poise.expr import ExprSyntaxError, compile_batch, parse
from poise.expr.tokens import make_template, tokenize

from support.expr import ev, FakeResolver, mkexpr


@pytest.mark.parametrize("text,value", [
    ("1.", 1.0), (".5", 0.5), ("1.E-3", 1e-3), ("1.5D0", 1.5), ("2e3", 2000.0),
    ("1.5d+2", 150.0), ("2.5E-1", 0.25), ("-9810.", -9810.0), ("7", 7.0),
    ("180D", math.pi), ("90d", math.pi / 2), ("1.5D0D", 1.5 * math.pi / 180),
    ("5D+3", 5000.0), ("5D-1", 0.5), ("10D+1", 100.0), ("10D +1", 10 * math.pi / 180 + 1),
    ("2*45D", math.pi / 2), ("(45D)", math.pi / 4), ("1.E+2", 100.0),
])
def test_numbers(text, value):
    res, _ = ev(text)
    assert res.value[0] == pytest.approx(value, rel=1e-15)


def test_degree_suffix_times_time():
    res, _ = ev("10D*TIME")
    assert res.value[0] == pytest.approx(10 * math.pi / 180 * 0.3)
    assert res.d_time[0] == pytest.approx(10 * math.pi / 180)


@pytest.mark.parametrize("text,value", [
    ("-2**2", -4.0), ("2**3**2", 512.0), ("2**-1", 0.5), ("-2**-2", -0.25),
    ("1+2*3", 7.0), ("(1+2)*3", 9.0), ("8/4/2", 1.0), ("2-3-4", -5.0), ("--3", 3.0),
    ("+3", 3.0), ("2*-3", -6.0), ("pi", math.pi), ("Dtor*180", math.pi),
    ("RTOD*PI", 180.0), ("sqrt(4)+Sin(0)", 2.0), ("time", 0.3), ("2**2*3", 12.0),
    ("-TIME**2", -0.09), ("(-2)**2", 4.0),
])
def test_precedence_and_constants(text, value):
    res, _ = ev(text)
    assert res.value[0] == pytest.approx(value, rel=1e-14)


def test_tokens_and_columns():
    toks = tokenize("abs(TIME) ** 2.5D0")
    assert [t.text for t in toks] == ["ABS", "(", "TIME", ")", "**", "2.5D0", ""]
    assert [t.col for t in toks] == [1, 4, 5, 9, 11, 14, 19]
    node = parse("1 + SIN(TIME)")
    assert node.col == 3 and node.right.col == 5 and node.right.args[0].col == 9


def test_template_keeps_identifiers():
    tmpl, vals = make_template("LOG10(2.5)+STEP5(TIME,0,0,1.E-3,90D)*DX(12)")
    assert tmpl == "LOG10(#)+STEP5(TIME,#,#,#,#)*DX(#)"
    assert vals == pytest.approx([2.5, 0, 0, 1e-3, math.pi / 2, 12])


@pytest.mark.parametrize("text,col,msg", [
    ("SIN(TIME", 9, "expected ')'"),
    ("1+*2", 3, "expected an operand, found '*'"),
    ("(1+2", 5, "expected ')'"),
    ("1+2)", 4, "unbalanced ')'"),
    ("", 1, "empty expression"),
    ("1 2", 3, "unexpected '2'"),
    ("2*", 3, "expected an operand, found end of expression"),
    ("IF(TIME, 1, 2, 3", 17, "expected ')'"),
    ("IF(TIME 1, 2, 3)", 9, "expected ':'"),
    ("SIN(1:2)", 6, "unexpected ':'"),
    ("1 $ 2", 3, "invalid character '$'"),
    ("STEP(TIME,0,0,1,,1)", 17, "expected an operand, found ','"),
    ("5DX", 2, "unexpected 'DX'"),
])
def test_syntax_errors(text, col, msg):
    with pytest.raises(ExprSyntaxError) as ei:
        parse(text)
    assert ei.value.col == col
    assert msg in ei.value.message
    with pytest.raises(DeckError) as ei2:
        compile_batch([mkexpr(text, attr="fx_expression")], FakeResolver())
    assert str(ei2.value) == (f"deck.xml:7: <Force_Scalar_TwoBody id=3> fx_expression col {col}: "
                              f"{ei.value.message}")


def test_exact_message_format():
    with pytest.raises(DeckError) as ei:
        compile_batch([mkexpr("SIN(TIME")], FakeResolver())
    assert str(ei.value) == "deck.xml:7: <Force_Scalar_TwoBody id=3> expr col 9: expected ')'"


@pytest.mark.parametrize("text,col,msg", [
    ("FOO(1)", 1, "unknown function 'FOO'; did you mean FORCOS?"),
    ("FLIBBERTIGIBBET(1)", 1, "unknown function 'FLIBBERTIGIBBET'"),
    ("SWEEP(TIME, 1, 0, 1, 1, 2, 0.1)", 1, "SWEEP is a MotionSolve function poise does not "
     "evaluate: a swept-sine excitation for dynamic analyses"),
    ("1 + BAR", 5, "unknown name 'BAR'"),
    ("SIN(1, 2)", 1, "SIN takes 1 arguments, got 2"),
    ("STEP(TIME,0,0,1)", 1, "STEP takes 5 arguments, got 4"),
    ("DX(99)", 4, "unknown marker id 99"),
    ("DX(1.5)", 4, "DX argument 1 must be an integer constant"),
    ("DM(1, TIME)", 7, "DM argument 2 must be an integer constant"),
    ("VARVAL(77)", 8, "unknown Reference_Variable id 77"),
    ("DIF(9)", 5, "unknown Control_Diff id 9"),
    ("AKISPL(TIME, 0, 9)", 17, "unknown Reference_Spline id 9"),
    ("AKISPL(TIME, 0, 1, 3)", 20, "AKISPL derivative order must be 0, 1 or 2"),
    ("ARYVAL(1, 4)", 11, "ARYVAL index 4 outside 1..3"),
    ("ARYVAL(5, 1)", 8, "unknown Reference_Array id 5"),
    ("2*GFORCE(1, 0, 2, 0)", 3, "GFORCE reactions are not supported"),
    ("VX(1, 42)", 7, "unknown marker id 42"),
])
def test_semantic_errors(text, col, msg):
    with pytest.raises(DeckError) as ei:
        compile_batch([mkexpr(text)], FakeResolver())
    assert str(ei.value) == f"deck.xml:7: <Force_Scalar_TwoBody id=3> expr col {col}: {msg}"


def test_all_problems_collected():
    exprs = [mkexpr("SIN(TIME", line=1), mkexpr("TIME", line=2), mkexpr("FOO(1)+BAR", line=3),
             mkexpr("DX(1,99)", line=4)]
    with pytest.raises(DeckError) as ei:
        compile_batch(exprs, FakeResolver())
    lines = str(ei.value).splitlines()
    assert lines == [
        "deck.xml:1: <Force_Scalar_TwoBody id=3> expr col 9: expected ')'",
        "deck.xml:3: <Force_Scalar_TwoBody id=3> expr col 1: unknown function 'FOO'; did you "
        "mean FORCOS?",
        "deck.xml:4: <Force_Scalar_TwoBody id=3> expr col 6: unknown marker id 99",
    ]


def test_recursive_variable_and_error_inside_variable():
    r = FakeResolver(explicit={101: "VARVAL(102) + 1", 102: "2*VARVAL(101)",
                               103: "SIN(TIME"})
    with pytest.raises(DeckError) as ei:
        compile_batch([mkexpr("VARVAL(101)")], r)
    assert "recursive VARVAL: 101 -> 102 -> 101" in str(ei.value)
    with pytest.raises(DeckError) as ei:
        compile_batch([mkexpr("1+VARVAL(103)")], r)
    s = str(ei.value)
    assert "deck.xml:203: <Reference_Variable id=103> expr col 9: expected ')'" in s
    assert "expr col 3: Reference_Variable id 103 is invalid" in s


def test_hash_is_not_a_valid_character():
    with pytest.raises(DeckError, match="col 3: invalid character '#'"):
        compile_batch([mkexpr("1 # 2")], FakeResolver())


def test_fake_resolver_roundtrip():
    res, b = ev("VARVAL(1) + 2")
    assert b.n == 1 and res.value[0] == 2.0
