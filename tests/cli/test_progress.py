"""One way to show progress: poise.core.progress.Bar on a terminal (a tqdm
bar with ETA, through its public API), plain lines off a terminal (CI: every 10 % / 10 s), nothing when quiet; the
solvers report frames and MKEAM iterations through the poise.core.progress callback."""
from __future__ import annotations

import io
import re

import pytest
from click.testing import CliRunner

from poise.core import progress as P
from poise.app.engine import NoWorkers
from poise.app.runner import run
from poise.core.progress import reporting
from poise_cli.main import cli

from support.paths import DECKS


class _Clock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self):
        return self.t


@pytest.fixture
def clock(monkeypatch):
    c = _Clock()
    monkeypatch.setattr(P.time, "monotonic", c)
    monkeypatch.delenv("POISE_QUIET", raising=False)
    monkeypatch.delenv("CI", raising=False)
    return c


class _Tty(io.StringIO):
    def isatty(self):
        return True


def test_plain_lines_every_10_percent_or_10_s(clock):
    s = io.StringIO()
    b = P.Bar(100, "sweep", "cases", stream=s, delay=0.0)
    assert b.mode == "plain"
    for k in range(1, 26):
        clock.t += 0.2
        b.update(k)
    lines = s.getvalue().splitlines()
    assert lines == ["poise: sweep 10/100 cases (10%), 2 s, ETA 18 s",
                     "poise: sweep 20/100 cases (20%), 4 s, ETA 16 s"]
    clock.t += 11                         # 10 s without a 10 % step: a line anyway
    b.update(26)
    assert s.getvalue().splitlines()[-1].startswith("poise: sweep 26/100 cases (26%), 16 s, ETA")
    b.close()                              # ended early: one last line
    assert s.getvalue().splitlines()[-1] == "poise: sweep 26/100 cases (26%), 16 s, done"


def test_plain_quick_work_says_nothing(clock):
    s = io.StringIO()
    b = P.Bar(50, "FIM_S", "frames", stream=s, delay=1.0)
    for k in range(1, 51):
        clock.t += 0.01
        b.update(k)
    b.close()
    assert s.getvalue() == ""


def test_quiet_and_env(clock, monkeypatch):
    assert P.choose_mode(False, _Tty()) == "off"
    assert P.choose_mode(None, _Tty()) == "tty"
    assert P.choose_mode(None, io.StringIO()) == "plain"
    monkeypatch.setenv("CI", "true")
    assert P.choose_mode(None, _Tty()) == "plain"
    monkeypatch.setenv("POISE_QUIET", "1")
    assert P.choose_mode(None, _Tty()) == "off"
    assert P.reporter(None) is False


def test_tty_bar_with_eta_erased_at_the_end(clock):
    s = _Tty()
    b = P.Bar(10, "FIM_S", "frames", stream=s, delay=0.0)
    assert b.mode == "tty"
    b.update(3)
    b.clear()                              # erased; the next update draws it again
    b.update(4)
    out = s.getvalue()
    last = out.split("\r")[-1]
    assert last.startswith("FIM_S:") and "4/10" in last and "40%" in last
    assert re.search(r"\[\d\d:\d\d<(\d\d:\d\d|\?)", last)      # elapsed < remaining (ETA)
    b.write("a line")
    assert "a line\n" in s.getvalue()
    b.close()
    assert s.getvalue().split("\r")[-1] == ""            # the bar is erased: nothing left
    assert s.getvalue().split("\r")[-2].strip() == ""


def test_the_last_line_says_how_the_work_ended(clock):
    s = io.StringIO()
    b = P.Bar(10, "sweep", "cases", stream=s, delay=0.0)
    b.update(3)
    b.close(P.ending(None))
    assert s.getvalue().splitlines()[-1] == "poise: sweep 3/10 cases (30%), 0 s, done"
    for exc, word in ((KeyboardInterrupt(), "interrupted"), (ValueError("x"), "failed"),
                      (NoWorkers("none"), "gave up")):
        s = io.StringIO()
        clock.t += 5
        with pytest.raises(type(exc)), P.Bar(10, "sweep", "cases", stream=s, delay=0.0) as b:
            b.update(2)
            clock.t += 12
            raise exc
        assert s.getvalue().splitlines()[-1] == f"poise: sweep 2/10 cases (20%), 12 s, {word}"
    s = _Tty()                             # on a terminal too: the bar erased, then the line
    b = P.Bar(10, "sweep", "cases", stream=s, delay=0.0)
    b.update(1)
    clock.t += 3
    b.close("gave up")
    assert s.getvalue().endswith("poise: sweep 1/10 cases (10%), 3 s, gave up\n")
    s = io.StringIO()                      # refused at once (a usage error): no line at all
    b = P.Bar(10, "sweep", "cases", stream=s, delay=0.0)
    b.close("failed")
    assert s.getvalue() == ""


def test_progress_uses_public_api_only():
    import inspect
    src = inspect.getsource(P)
    assert "click" not in src
    assert not re.search(r"_bar\._[a-z]", src)


def test_solvers_report_frames_and_mkeam_iterations():
    seen = []
    with reporting(lambda label, done, total: seen.append((label, done, total))):
        run(str(DECKS / "qs_spring_ramp.xml"), overrides={"method": "FIM_S"})
    fims = [x for x in seen if x[0] == "FIM_S"]
    assert fims[-1][1] is None and fims[-2][1] == fims[-2][2] > 2
    seen.clear()
    with reporting(lambda label, done, total: seen.append((label, done, total))):
        run(str(DECKS / "mkeam_pendulum_multiturn.xml"))
    mk = [x for x in seen if x[0] == "MKEAM"]
    assert mk and mk[0][1] == 0 and mk[-1][1] is None
    assert [d for _, d, _ in mk[:-1]] == list(range(len(mk) - 1))


def test_sweep_prints_progress_lines_off_a_terminal(tmp_path, monkeypatch):
    monkeypatch.delenv("POISE_QUIET", raising=False)
    args = ["sweep", str(DECKS / "pendulum_multiturn.xml"), "--set",
            "Force_SpringDamper[1].stiffness=10000,20000", "--workers", "1",
            "--out-dir", str(tmp_path / "s")]
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0, r.output
    assert "poise: sweep 1/2 cases (50%)" in r.stderr
    assert "poise: sweep 2/2 cases (100%)" in r.stderr
    r = CliRunner().invoke(cli, args + ["--quiet"])
    assert r.exit_code == 0 and r.stderr == ""
