"""Ctrl-C and SIGTERM end ``poise`` wherever it is: inside a Python user routine (which runs in
``except BaseException``, and may even catch the KeyboardInterrupt itself), or inside native
code that never returns to Python (a user routine stuck in C, a LAPACK call): exit 130,
``poise: interrupted``, no results file and no temporary file. The poise processes start with
SIGINT at its default (a background job of a script would inherit it ignored)."""
from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from support.paths import DATA

POISE = Path(sys.executable).with_name("poise")
RELIABILITY = DATA / "reliability" / "decks"
DECK = "user_slow_routine_sigint.xml"          # ~7 s: a spring routine sleeping 50 ms a call


def _default_sigint():
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _start(deck: Path, out: Path) -> subprocess.Popen:
    return subprocess.Popen([str(POISE), "solve", str(deck), "-o", str(out),
                             "--allow-user-code"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=deck.parent,
                            preexec_fn=_default_sigint)


def _wait_for(path: Path, proc: subprocess.Popen, limit: float = 60.0) -> None:
    """Until the user routine has run (it writes ``path``): the signal lands inside it."""
    end = time.monotonic() + limit
    while not path.exists():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < end, "the user routine never ran"
        time.sleep(0.02)


def _deck_with(tmp_path: Path, routine: str) -> Path:
    """The reliability deck with its slow routine replaced by ``routine`` (source of
    ``sfosub_slow``), which first touches ``started``."""
    d = tmp_path / "deck"
    d.mkdir()
    shutil.copy(RELIABILITY / DECK, d / DECK)
    src = (RELIABILITY / "user_slow_routines.py").read_text()
    head, _, tail = src.partition("def sfosub_slow(")
    tail = tail[tail.index("\ndef ", 1):]                  # the functions after sfosub_slow
    (d / "user_slow_routines.py").write_text(
        head + f"import pathlib as _pl\n_STARTED = _pl.Path({str(d / 'started')!r})\n\n"
        + routine + "\n" + tail)
    return d / DECK


def _assert_interrupted(proc, out: Path):
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert stderr.strip().splitlines()[-1] == "poise: interrupted", stderr
    assert "Traceback" not in stderr and "raised KeyboardInterrupt" not in stderr, stderr
    assert not out.exists()
    assert [p.name for p in out.parent.iterdir() if p.name.startswith(".o.h5.tmp")] == []


SLOW = '''
def sfosub_slow(id, time, par, q):
    _STARTED.touch()
    _t.sleep(0.05)
    return sfosub_spring(id, time, par, q)
'''

SWALLOWS = '''
def sfosub_slow(id, time, par, q):
    """Catches everything, KeyboardInterrupt included, and carries on."""
    _STARTED.touch()
    for _ in range(5):
        try:
            _t.sleep(0.02)
        except BaseException:
            pass
    return sfosub_spring(id, time, par, q)
'''

STUCK_IN_C = '''
import hashlib as _hl

def sfosub_slow(id, time, par, q):
    """Minutes inside C (no bytecode runs, so no Python signal handler can)."""
    _STARTED.touch()
    _hl.pbkdf2_hmac("sha256", b"x", b"y", 10**9)
    return sfosub_spring(id, time, par, q)
'''


def _interrupt_inside(tmp_path, routine: str, sig) -> None:
    deck = _deck_with(tmp_path, routine)
    out = deck.parent / "o.h5"
    proc = _start(deck, out)
    _wait_for(deck.parent / "started", proc)
    time.sleep(0.3)
    proc.send_signal(sig)
    _assert_interrupted(proc, out)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
@pytest.mark.parametrize("routine", [SLOW, SWALLOWS], ids=["slow", "swallows"])
def test_a_signal_during_a_user_routine_interrupts_the_run(tmp_path, sig, routine):
    _interrupt_inside(tmp_path, routine, sig)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_while_native_code_holds_the_process(tmp_path, sig):
    """The watchdog ends it (otherwise: minutes in C, then exit 0)."""
    _interrupt_inside(tmp_path, STUCK_IN_C, sig)


@pytest.mark.slow
def test_the_reliability_script_sees_every_signal_honoured(tmp_path):
    """sig_user.py itself (SIGINT and SIGTERM at 1, 3 and 5 s into the slow solve)."""
    for name in (DECK, "user_slow_routines.py", "sig_user.py"):
        shutil.copy(RELIABILITY / name, tmp_path / name)
    p = subprocess.run([sys.executable, "sig_user.py", str(POISE)], cwd=tmp_path,
                       capture_output=True, text=True, timeout=600,
                       preexec_fn=_default_sigint)
    lines = p.stdout.strip().splitlines()
    assert len(lines) == 6, p.stdout + p.stderr
    for ln in lines:
        assert "exit 130, results file absent: poise: interrupted" in ln, p.stdout


def test_an_overflowing_curve_is_a_located_deck_error():
    """cvcv_huge_curve_hang.xml: a curve x = 1e308 cos(U) made an SVD of inf that never
    returned (and ignored SIGTERM): now exit 3 at the curve's expression."""
    p = subprocess.run([str(POISE), "check", "cvcv_huge_curve_hang.xml"],
                       capture_output=True, text=True, timeout=120, cwd=RELIABILITY)
    assert p.returncode == 3, p.stderr
    first = p.stderr.splitlines()[0]
    assert first.startswith("cvcv_huge_curve_hang.xml:16: <Reference_ParamCurve id=1> "
                            "x_expression: the geometry overflows"), p.stderr
    assert "1e+308" in first and "U = 0" in first
    assert "poise: invalid deck: 1 problem" in p.stderr     # not also "not a ParamCurve"


_UNRAISABLE = """
import signal, time
from poise_cli import watchdog
watchdog.start()
signal.signal(signal.SIGINT, signal.default_int_handler)
class Lock:          # like importlib's module-lock cleanup: a callback Python cannot raise from
    def __del__(self):
        signal.raise_signal(signal.SIGINT)
try:
    Lock()
    end = time.monotonic() + 30
    while time.monotonic() < end:       # the command going on
        time.sleep(0.001)
    print("ran on")
except KeyboardInterrupt:
    print("interrupted")
"""


def test_an_interrupt_inside_a_callback_is_not_lost():
    """A Ctrl-C whose KeyboardInterrupt lands in a ``__del__`` or weakref callback is not
    printed as "Exception ignored ... Traceback" and lost: the console script's hook delivers it
    to the main thread again, which unwinds."""
    p = subprocess.run([sys.executable, "-c", _UNRAISABLE], capture_output=True, text=True,
                       timeout=60, preexec_fn=_default_sigint)
    assert p.stdout.strip() == "interrupted", p.stdout + p.stderr
    assert "Traceback" not in p.stderr and "ignored" not in p.stderr, p.stderr


def test_an_interrupt_another_exception_replaced_is_still_an_interrupt(monkeypatch, capsys):
    """Ctrl-C landing inside a Cython module's import comes out as ``ImportError: Failed to
    import 'zlib.decompress'``, the KeyboardInterrupt not chained: the command's handler has
    remembered the signal, so the run ends as interrupted (exit 130), not an internal error."""
    import poise_cli
    from poise_cli import errors, main
    wrapped = ImportError("Failed to import 'zlib.decompress'")
    monkeypatch.setattr(poise_cli, "signalled", False)
    assert errors.report_exception(wrapped)[0] == errors.EXIT_INTERNAL    # no signal: a bug
    with pytest.raises(KeyboardInterrupt):
        main._interrupt(signal.SIGINT, None)
    assert poise_cli.signalled is True
    code, info = errors.report_exception(wrapped)
    assert code == errors.EXIT_INTERRUPTED == 130 and info["status"] == "interrupted"
    assert capsys.readouterr().err.splitlines()[-1] == "poise: interrupted"
