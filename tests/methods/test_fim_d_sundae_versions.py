"""FIM_D runs only on the scikit-sundae releases whose solver internals it reads (poise.solvers.ida:
SUPPORTED, pinned the same way in pyproject.toml); another release is a clear usage error (exit
2, the pip command to run), never a run with other numbers."""
from __future__ import annotations

import re

import numpy as np
import pytest
from click.testing import CliRunner

from poise.app.api import run_deck
from poise.solvers import ida
from poise_cli.main import cli

from support.paths import DECKS, ROOT

DECK = str(DECKS / "qs_pendulum_ramp.xml")          # a quasi-static FIM_D deck


@pytest.mark.parametrize("version", ["1.1.0", "1.1.3", "1.2.0", "1.2.1.dev0"])
def test_supported_releases(version):
    ida.check_supported(version)


@pytest.mark.parametrize("version", ["1.0.4", "1.3.0", "2.0.0", "unknown", ""])
def test_other_releases_are_refused_with_the_pip_command(version):
    with pytest.raises(ida.UnsupportedSundae) as e:
        ida.check_supported(version)
    msg = str(e.value)
    assert f"but {version} is installed" in msg and ida.PIN in msg
    assert e.value.exit_code == 2


def test_pyproject_pins_the_supported_range():
    text = (ROOT / "pyproject.toml").read_text()
    pins = re.findall(r'"(scikit-sundae[^"]*)"', text)
    assert pins == [ida.PIN]


def test_the_installed_release_is_read_through(tmp_path):
    """On the installed (supported) release the step order and IDA's counters are read and the
    corrector coefficient is set: nothing in the analysis message says otherwise."""
    res = run_deck(DECK)
    a = res.analyses[-1]
    assert a.status == "converged" and a.method == "FIM_D"
    order = np.asarray(a.datasets["steps/order"])
    assert order.size and order.min() >= 1 and order.max() <= 5
    assert (np.asarray(a.datasets["steps/convergence_failures"]) >= 0).all()
    assert "not available" not in a.message and "corrector coefficient" not in a.message


def test_an_unsupported_release_stops_fim_d_with_a_clear_message(monkeypatch, tmp_path):
    import sksundae
    monkeypatch.setattr(sksundae, "__version__", "1.3.0")
    with pytest.raises(ida.UnsupportedSundae):
        run_deck(DECK)
    r = CliRunner().invoke(cli, ["solve", DECK, "-o", str(tmp_path / "r.h5"), "--json"])
    assert r.exit_code == 2
    assert "FIM_D needs scikit-sundae 1.1 or 1.2" in r.stderr and ida.PIN in r.stderr
    assert not (tmp_path / "r.h5").exists()
    # FIM_S does not need SUNDIALS: the same deck still solves
    r = CliRunner().invoke(cli, ["solve", DECK, "-o", str(tmp_path / "s.h5"), "--method",
                                 "FIM_S", "-q"])
    assert r.exit_code == 0, r.output
