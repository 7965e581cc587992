"""A sweep's size is checked before any case is made: more than ``--max-cases`` cases (default
100000) is a usage error (exit 2) naming the option, whatever the mode (``--random 1000000000``
or a huge grid were a MemoryError); ranges that overflow and malformed scheduler addresses are
usage errors too. Nothing is created in the output directory in those cases."""
from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from poise.core.errors import UsageError
from poise.app.cases import MAX_CASES, check_case_count, count_cases
from poise.app.sweep import run_sweep
from poise_cli.main import cli

from support.paths import ROOT


DECK = ROOT / "decks" / "fourbar_spring.xml"
K = "Force_SpringDamper[1].stiffness"
C = "Force_SpringDamper[1].damping"


def _sweep(tmp_path, sets, **kw):
    return run_sweep(str(DECK), sets, out_dir=str(tmp_path / "out"), **kw)


def test_random_billion_is_refused_before_making_cases(tmp_path):
    with pytest.raises(UsageError, match=r"1000000000 cases .*--max-cases 100000"):
        _sweep(tmp_path, [f"{K}=1:2:0.5"], mode="random", n=1_000_000_000)
    assert not (tmp_path / "out").exists()


def test_huge_grid_is_refused(tmp_path):
    with pytest.raises(UsageError, match=r"1002001 cases \(1001 x 1001 values\)"):
        _sweep(tmp_path, [f"{K}=0:1000:1", f"{C}=0:1000:1"])
    assert not (tmp_path / "out").exists()


def test_count_cases_matches_the_modes():
    from types import SimpleNamespace as P
    a, b = P(values=list(range(7)), key="a"), P(values=list(range(5)), key="b")
    assert count_cases([a, b], "grid") == 35
    assert count_cases([a, a], "zip") == 7
    assert count_cases([a, b], "random", n=12) == 12
    assert check_case_count([a, b], "grid", max_cases=35) == 35
    with pytest.raises(UsageError, match="--max-cases 34"):
        check_case_count([a, b], "grid", max_cases=34)
    assert check_case_count([a, b], "random", n=10**12, max_cases=None) == 10**12
    assert MAX_CASES == 100_000


@pytest.mark.parametrize("values", ["-1e308:1e308:1e300", "0:1e308:1e-300", "1:1e300:1"])
def test_overflowing_ranges_are_usage_errors(tmp_path, values):
    with pytest.raises(UsageError, match="more than 1000000 values"):
        _sweep(tmp_path, [f"{K}={values}"])


@pytest.mark.parametrize("address", ["foo:bar:baz", "tcp://", "::::", "tcp://host:99999"])
def test_malformed_scheduler_is_a_usage_error(tmp_path, address):
    with pytest.raises(UsageError, match="--scheduler"):
        _sweep(tmp_path, [f"{K}=1,2"], scheduler=address)
    assert not (tmp_path / "out").exists()


def test_cli_cap_is_exit_2_and_names_the_option(tmp_path):
    r = CliRunner().invoke(cli, ["sweep", str(DECK), "--set", f"{K}=1:2:0.5", "--random",
                                 "1000000000", "--out-dir", str(tmp_path / "o"), "--json"])
    assert r.exit_code == 2
    assert "--max-cases" in r.stderr
    info = json.loads(r.stdout)
    assert info["exit_code"] == 2 and info["status"] == "usage_error"


def test_cli_max_cases_option_lowers_the_cap(tmp_path):
    r = CliRunner().invoke(cli, ["sweep", str(DECK), "--set", f"{K}=1,2,3", "--max-cases", "2",
                                 "--out-dir", str(tmp_path / "o")])
    assert r.exit_code == 2 and "3 cases" in r.stderr and "--max-cases 2" in r.stderr
