"""Optional extras: without matplotlib / dask the commands that need them
exit 2 with the pip command to run; the solver itself needs neither.

The missing package is simulated with ``sys.modules[name] = None`` (``import name`` then raises
ImportError), in-process for the commands and in a subprocess for a whole lean ``poise solve``.
"""
from __future__ import annotations

import subprocess
import sys

import pytest
from click.testing import CliRunner

from poise_cli.main import cli

from support.paths import DECKS


NO_PLOT = ("matplotlib",)
NO_DASK = ("dask", "distributed")


def _without(monkeypatch, names):
    for n in names:
        monkeypatch.setitem(sys.modules, n, None)


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    p = tmp_path_factory.mktemp("ex") / "p.h5"
    r = CliRunner().invoke(cli, ["solve", str(DECKS / "pendulum_multiturn.xml"), "-o", str(p),
                                 "-q", "--method", "FIM_S"])
    assert r.exit_code == 0, r.output
    return p


def _usage_with_pip(r, extra):
    assert r.exit_code == 2, r.output
    assert f"pip install 'poise[{extra}]'" in r.stderr
    assert "Traceback" not in r.output


@pytest.mark.parametrize("cmd", ["plot", "animate"])
def test_pictures_without_matplotlib(cmd, results, tmp_path, monkeypatch):
    _without(monkeypatch, NO_PLOT)
    r = CliRunner().invoke(cli, [cmd, str(results), "-o", str(tmp_path / "x.png")])
    _usage_with_pip(r, "plot")
    assert not (tmp_path / "x.png").exists()


def test_sweep_without_dask(tmp_path, monkeypatch):
    _without(monkeypatch, NO_DASK)
    r = CliRunner().invoke(cli, ["sweep", str(DECKS / "pendulum_multiturn.xml"), "--set",
                                 "Param_Static.max_num_iter=10,20", "--out-dir",
                                 str(tmp_path / "s")])
    _usage_with_pip(r, "sweep")


def test_lean_solve_in_a_subprocess(tmp_path):
    """A whole ``poise solve`` with matplotlib and dask unimportable."""
    code = ("import sys\n"
            "for n in ('matplotlib', 'dask', 'distributed'): sys.modules[n] = None\n"
            "from poise_cli.main import cli\n"
            "cli(sys.argv[1:], prog_name='poise')\n")
    out = tmp_path / "p.h5"
    p = subprocess.run([sys.executable, "-c", code, "solve", str(DECKS / "pendulum_multiturn.xml"),
                        "-o", str(out), "-q", "--method", "FIM_S"],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert out.exists()


def test_batch_without_dask_runs_on_a_local_process_pool(tmp_path, monkeypatch):
    import json
    _without(monkeypatch, NO_DASK)
    r = CliRunner().invoke(cli, ["batch", str(DECKS / "pendulum_multiturn.xml"),
                                 str(DECKS / "double_pendulum.xml"), "-j", "2", "--out-dir",
                                 str(tmp_path), "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["counts"] == {"converged": 2}
    assert "dask" not in sys.modules or sys.modules["dask"] is None
