"""I/O failures and interrupts end cleanly: a full disk or an unwritable output directory is a
usage/I-O error (exit 2) naming the path with nothing half-written; Ctrl-C and SIGTERM end with
one line and exit 130 (never a traceback); temporary files a killed run left are removed by the
next write into that directory."""
from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

import poise.app.api
from poise.core.atomic import OutputError, atomic_output, remove_stale_temps, temp_name
from poise.results import hdf5
from poise_cli.main import cli

from support.paths import ROOT, TESTS
from support.results import make_result
from support.tmpfs import tmpfs


POISE = Path(sys.executable).with_name("poise")
DECK = ROOT / "decks" / "pendulum_multiturn.xml"


def _files(d: Path) -> list[str]:
    return sorted(p.name for p in d.iterdir())


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


# ----------------------------------------------------------------------------- full disk
def test_enospc_mid_write_is_an_output_error_and_leaves_nothing(tmp_path, monkeypatch):
    def full(result, path):
        with open(path, "wb") as f:
            f.write(b"\0" * 100)
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(hdf5, "_write_file", full)
    out = tmp_path / "r.h5"
    with pytest.raises(OutputError, match="No space left on device") as e:
        hdf5.write_results(make_result(), str(out))
    assert str(out) in str(e.value)
    assert _files(tmp_path) == []


def test_hdf5_errno_error_is_an_output_error(tmp_path, monkeypatch):
    def failing(result, path):
        Path(path).write_bytes(b"x")
        raise RuntimeError("Can't decrement id ref count (file write failed: errno = 28, "
                           "error message = 'No space left on device')")
    monkeypatch.setattr(hdf5, "_write_file", failing)
    with pytest.raises(OutputError, match="No space left on device"):
        hdf5.write_results(make_result(), str(tmp_path / "r.h5"))
    assert _files(tmp_path) == []


def test_solve_on_full_disk_is_exit_2(tmp_path, monkeypatch):
    monkeypatch.setattr(poise.app.api, "run_deck", lambda *a, **k: make_result())

    def full(result, path):
        Path(path).write_bytes(b"partial")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(hdf5, "_write_file", full)
    out = tmp_path / "o.h5"
    r = CliRunner().invoke(cli, ["solve", str(DECK), "-o", str(out), "--json"])
    assert r.exit_code == 2
    assert "No space left on device" in r.stderr and str(out) in r.stderr
    assert "Traceback" not in r.stderr
    info = json.loads(r.stdout)
    assert info["exit_code"] == 2 and info["status"] == "io_error"
    assert _files(tmp_path) == []


@pytest.fixture
def small_tmpfs(tmp_path):
    """A 64 KiB tmpfs (root only): a real full disk."""
    with tmpfs(tmp_path / "mnt", "size=64k") as mnt:
        yield mnt


def test_solve_on_a_real_full_disk(small_tmpfs):
    (small_tmpfs / "filler").write_bytes(b"\1" * 40_000)     # ~20 KiB left: too small
    out = small_tmpfs / "o.h5"
    p = subprocess.run([str(POISE), "solve", str(ROOT / "decks" / "chain_10.xml"), "-o",
                        str(out), "--json"], capture_output=True, text=True, timeout=60)
    assert p.returncode == 2, p.stderr
    assert "No space left on device" in p.stderr and str(out) in p.stderr
    assert "Traceback" not in p.stderr and "Exception ignored" not in p.stderr
    assert json.loads(p.stdout)["status"] == "io_error"
    assert _files(small_tmpfs) == ["filler"]


# ----------------------------------------------------------------------------- out dirs
def test_solve_refuses_an_unusable_output_directory(tmp_path):
    afile = tmp_path / "f"
    afile.write_text("x")
    r = CliRunner().invoke(cli, ["solve", str(DECK), "-o", str(afile / "sub" / "o.h5")])
    assert r.exit_code == 2 and "does not exist" in r.output


@pytest.mark.skipif(os.geteuid() == 0, reason="root can write anywhere")
def test_solve_refuses_a_read_only_directory(tmp_path):
    d = tmp_path / "ro"
    d.mkdir()
    d.chmod(0o500)
    try:
        r = CliRunner().invoke(cli, ["solve", str(DECK), "-o", str(d / "o.h5")])
    finally:
        d.chmod(0o700)
    assert r.exit_code == 2 and "not writable" in r.output


def test_batch_unwritable_out_dir_is_exit_2(tmp_path):
    afile = tmp_path / "f"
    afile.write_text("x")
    bad = afile / "out"
    p = subprocess.run([str(POISE), "batch", str(DECK), "--out-dir", str(bad), "--json"],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 2, p.stderr
    assert str(bad) in p.stderr and "Traceback" not in p.stderr
    info = json.loads(p.stdout)
    assert info["exit_code"] == 2 and info["status"] == "io_error"


def test_sweep_unwritable_out_dir_is_exit_2(tmp_path):
    afile = tmp_path / "f"
    afile.write_text("x")
    bad = afile / "out"
    r = CliRunner().invoke(cli, ["sweep", str(ROOT / "decks" / "fourbar_spring.xml"), "--set",
                                 "Force_SpringDamper[1].stiffness=1,2", "--out-dir", str(bad)])
    assert r.exit_code == 2 and str(bad) in r.stderr


# ----------------------------------------------------------------------------- temp files
def test_stale_temp_files_are_removed_by_the_next_write(tmp_path):
    dead = _dead_pid()
    target = tmp_path / "out.h5"
    mine = Path(temp_name(str(target))).name
    host = mine.split("@", 1)[1]
    stale = [f".out.h5.tmp-{dead}@{host}", f".other.h5.tmp-{dead}@{host}",
             f".out.h5.tmp-{dead}", f".plot.png.tmp-{dead}@{host}.png"]
    kept = [f".out.h5.tmp-{dead}@another-host", f".out.h5.tmp-{os.getppid()}@{host}",
            f".other.h5.tmp-{dead}", "keep.txt"]
    for n in stale + kept:
        (tmp_path / n).write_bytes(b"junk")
    hdf5.write_results(make_result(), str(target))
    assert _files(tmp_path) == sorted(kept + ["out.h5"])
    assert remove_stale_temps(str(tmp_path)) == []


def test_sigkilled_write_leaves_a_temp_the_next_run_removes(tmp_path):
    final = tmp_path / "killed.h5"
    script = textwrap.dedent(f"""
        import sys, time
        sys.path.insert(0, {str(TESTS)!r})
        from support.results import make_result
        from poise.results import hdf5
        real = hdf5._file_image
        def slow(result, name):
            print("mid-write", flush=True)
            time.sleep(60)
        hdf5._file_image = slow
        hdf5.write_results(make_result(), {str(final)!r})
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "mid-write"
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    left = _files(tmp_path)
    assert len(left) == 1 and left[0].startswith(".killed.h5.tmp-")
    p = subprocess.run([str(POISE), "solve", str(DECK), "-o", str(tmp_path / "next.h5"), "-q"],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    assert _files(tmp_path) == ["next.h5"]


def test_interrupt_during_the_write_removes_the_temp(tmp_path, monkeypatch):
    before = signal.getsignal(signal.SIGINT)     # whatever the suite inherited (nohup: SIG_IGN)
    real = hdf5._file_image

    def interrupted(result, name):
        os.kill(os.getpid(), signal.SIGINT)        # held until the writer returns
        return real(result, name)
    monkeypatch.setattr(hdf5, "_file_image", interrupted)
    with pytest.raises(KeyboardInterrupt):
        hdf5.write_results(make_result(), str(tmp_path / "r.h5"))
    assert _files(tmp_path) == []
    assert signal.getsignal(signal.SIGINT) is before        # restored as it was


def test_atomic_output_keeps_other_errors(tmp_path):
    with pytest.raises(ValueError, match="not an I/O error"):
        with atomic_output(tmp_path / "x.txt") as tmp:
            Path(tmp).write_text("x")
            raise ValueError("not an I/O error")
    assert _files(tmp_path) == []


# ----------------------------------------------------------------------------- interrupts
@pytest.fixture(scope="module")
def chain_deck(tmp_path_factory):
    from poise.gen.chain import build_chain_deck
    d = tmp_path_factory.mktemp("chain") / "chain.xml"
    d.write_text(build_chain_deck(2000, "revolute"))
    return d


def _wait_started(p, limit=30.0):
    """Wait until poise's own code runs in ``p`` (its start-up handler catches SIGTERM): an
    interrupt inside the interpreter's start-up, before any poise code, is Python's, not ours,
    and on a loaded machine a fixed delay can land there."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < limit and p.poll() is None:
        try:
            with open(f"/proc/{p.pid}/status") as f:
                caught = next(int(line.split()[1], 16) for line in f if line.startswith("SigCgt"))
        except (OSError, StopIteration):
            return
        if caught & (1 << (signal.SIGTERM - 1)):
            return
        time.sleep(0.005)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
@pytest.mark.parametrize("delay", [0.1, 0.6, 1.5])
def test_interrupted_solve_is_one_line_exit_130(tmp_path, chain_deck, sig, delay):
    out = tmp_path / "o.h5"
    p = subprocess.Popen([str(POISE), "solve", str(chain_deck), "-o", str(out), "-q"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    _wait_started(p)
    time.sleep(delay)
    p.send_signal(sig)
    stdout, stderr = p.communicate(timeout=60)
    assert "Traceback" not in stderr, stderr
    if p.returncode == 0:          # finished before the signal (a fast machine)
        assert _files(tmp_path) == ["o.h5"]
        return
    assert p.returncode == 130, stderr
    assert stderr.strip() == "poise: interrupted" and stdout == ""
    assert [n for n in _files(tmp_path) if n != "o.h5"] == []


def test_ctrl_c_on_a_batch_is_one_line(tmp_path, chain_deck):
    # Ctrl-C in a terminal signals the whole process group: the batch and its workers
    out = tmp_path / "b"
    p = subprocess.Popen([str(POISE), "batch", str(chain_deck), str(ROOT / "decks" / "chain_10.xml"),
                          "--out-dir", str(out), "-j", "2", "--json"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         start_new_session=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    _wait_started(p)
    time.sleep(1.0)
    os.killpg(p.pid, signal.SIGINT)
    stdout, stderr = p.communicate(timeout=60)
    assert "Traceback" not in stderr, stderr
    if p.returncode == 0:          # finished before the signal
        return
    assert p.returncode == 130, stderr
    assert stderr.count("poise: interrupted") == 1, stderr
    assert json.loads(stdout)["exit_code"] == 130


@pytest.fixture
def read_only_dir(tmp_path):
    """A read-only tmpfs (root only): a directory nobody, not even root, can write."""
    with tmpfs(tmp_path / "ro", "ro,size=64k") as mnt:
        yield mnt


def test_read_only_out_dirs_are_exit_2(read_only_dir):
    r = CliRunner().invoke(cli, ["solve", str(DECK), "-o", str(read_only_dir / "o.h5")])
    assert r.exit_code == 2 and "not writable" in r.output
    p = subprocess.run([str(POISE), "batch", str(DECK), "--out-dir", str(read_only_dir)],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and str(read_only_dir) in p.stderr and "not writable" in p.stderr
    assert "Traceback" not in p.stderr
    r = CliRunner().invoke(cli, ["sweep", str(ROOT / "decks" / "fourbar_spring.xml"), "--set",
                                 "Force_SpringDamper[1].stiffness=1,2", "--out-dir",
                                 str(read_only_dir / "sub")])
    assert r.exit_code == 2 and "cannot create the directory" in r.stderr
    assert os.listdir(read_only_dir) == []
