"""The solve's allocator setting (poise.core.memory.kept_heap): big freed arrays stay in the
heap inside the block, the heap is handed back and glibc's defaults restored after it, and it
changes nothing for small models, off glibc or when the environment sets the thresholds."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from poise.core import memory

BIG = 256 << 20        # bytes: far above glibc's largest mmap threshold (32 MB)


@pytest.fixture
def calls(monkeypatch):
    """glibc's mallopt and malloc_trim replaced by recorders (as if glibc were there)."""
    log = []
    monkeypatch.setattr(memory, "_trim", lambda pad: log.append(("trim", pad)) or 1)
    monkeypatch.setattr(memory, "_mallopt", lambda p, v: log.append((p, v)) or 1)
    monkeypatch.setattr(memory, "_free", lambda: memory.MAPPED_TRIM)     # enough to trim
    for name in memory._USER_SETTINGS + ("GLIBC_TUNABLES",):
        monkeypatch.delenv(name, raising=False)
    return log


def test_small_models_and_user_settings_change_nothing(calls, monkeypatch):
    with memory.kept_heap(memory.KEEP_LARGE - 1):
        with memory.mapped(memory.MAPPED_LARGE):
            pass
    monkeypatch.setenv("MALLOC_MMAP_MAX_", "0")
    with memory.kept_heap(memory.KEEP_LARGE):
        pass
    monkeypatch.delenv("MALLOC_MMAP_MAX_")
    monkeypatch.setenv("GLIBC_TUNABLES", "glibc.malloc.trim_threshold=1")
    with memory.kept_heap(memory.KEEP_LARGE):
        pass
    assert calls == []


def test_settings_restored_once_by_the_last_one_out(calls):
    with memory.kept_heap(memory.KEEP_LARGE):
        assert calls == [(memory._M_MMAP_MAX, 0),
                         (memory._M_TRIM_THRESHOLD, memory._KEEP_TRIM_THRESHOLD)]
        with memory.kept_heap(memory.KEEP_LARGE):
            with memory.mapped(memory.MAPPED_LARGE - 1):
                pass
            with memory.mapped(memory.MAPPED_LARGE):
                assert calls[2:] == [("trim", 0), (memory._M_MMAP_MAX, memory._DEFAULT_MMAP_MAX)]
            assert calls[-1] == (memory._M_MMAP_MAX, 0)
        assert len(calls) == 5 and memory._kept["users"] == 1
    assert calls[5:] == [(memory._M_MMAP_MAX, memory._DEFAULT_MMAP_MAX),
                         (memory._M_TRIM_THRESHOLD, memory._DEFAULT_TRIM_THRESHOLD), ("trim", 0)]
    assert memory._kept["users"] == 0


def test_no_trim_between_stages_inside(calls, monkeypatch):
    """Inside a kept heap a stage's release (SOLVE_LARGE) keeps the pages for the next stage;
    outside it, and for a large stage's release (LARGE, e.g. the parsed deck), glibc trims."""
    monkeypatch.setattr(memory, "glibc", lambda: True)
    with memory.kept_heap(memory.KEEP_LARGE):
        del calls[:]
        assert not memory.release_stage(1 << 40)
        assert calls == []
        assert memory.release(1 << 40)
        assert calls == [("trim", 0)]
    del calls[:]
    assert memory.release_stage(1 << 40)
    assert calls == [("trim", 0)]


def test_factorisation_trims_only_a_large_free_heap(calls, monkeypatch):
    """Before a factorisation the heap is trimmed only when it holds MAPPED_TRIM free bytes
    (less is what the next iteration reuses); without mallinfo2 it is always trimmed."""
    free = [memory.MAPPED_TRIM - 1]
    monkeypatch.setattr(memory, "_free", lambda: free[0])
    with memory.kept_heap(memory.KEEP_LARGE):
        del calls[:]
        with memory.mapped(memory.MAPPED_LARGE):
            assert calls == [(memory._M_MMAP_MAX, memory._DEFAULT_MMAP_MAX)]
        free[0] = memory.MAPPED_TRIM
        del calls[:]
        with memory.mapped(memory.MAPPED_LARGE):
            assert calls[0] == ("trim", 0)
        monkeypatch.setattr(memory, "_free", None)
        del calls[:]
        with memory.mapped(memory.MAPPED_LARGE):
            assert calls[0] == ("trim", 0)


def test_restored_even_when_the_solve_raises(calls):
    with pytest.raises(ZeroDivisionError):
        with memory.kept_heap(memory.KEEP_LARGE):
            raise ZeroDivisionError
    assert calls[-3:-1] == [(memory._M_MMAP_MAX, memory._DEFAULT_MMAP_MAX),
                            (memory._M_TRIM_THRESHOLD, memory._DEFAULT_TRIM_THRESHOLD)]
    assert memory._kept["users"] == 0


def test_no_op_off_glibc(monkeypatch):
    monkeypatch.setattr(sys, "platform", "darwin")
    monkeypatch.setattr(memory, "_trim", None)        # looked up again (and not found)
    monkeypatch.setattr(memory, "_mallopt", None)
    with memory.kept_heap(memory.KEEP_LARGE):
        assert memory._kept["users"] == 0
    assert memory._trim is False and not memory.release(1 << 40)


#: run in a fresh interpreter without the environment's malloc settings (Dask's sets
#: MALLOC_TRIM_THRESHOLD_ for its workers, and a test session that ran it inherits that)
_KEPT_AND_HANDED_BACK = """
import numpy as np

from poise.core import memory

BIG = 256 << 20


def resident():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096


def touched_and_freed():
    a = np.ones(BIG // 8)
    assert a[-1] == 1.0
    del a


memory.release(1 << 40)
before = resident()
grown = []
with memory.kept_heap(memory.KEEP_LARGE):
    touched_and_freed()
    grown.append(resident() - before)          # kept: free, but still resident
    with memory.mapped(memory.MAPPED_LARGE):   # a factorisation: handed back, then mapped
        grown.append(resident() - before)
        touched_and_freed()
        grown.append(resident() - before)
    touched_and_freed()
grown.append(resident() - before)              # trimmed
touched_and_freed()
grown.append(resident() - before)              # mapped and unmapped again: the defaults
print(" ".join(str(g) for g in grown))
"""


@pytest.mark.skipif(not memory.glibc(), reason="glibc's allocator")
def test_freed_pages_kept_inside_and_handed_back_after():
    """A freed 256 MB array stays resident inside the block (its pages are reused, not mapped
    afresh), goes back to the OS when the block ends, and after it glibc maps and unmaps such
    an array again (the defaults are back)."""
    env = {k: v for k, v in os.environ.items()
           if k not in memory._USER_SETTINGS and k != "GLIBC_TUNABLES"}
    out = subprocess.run([sys.executable, "-c", _KEPT_AND_HANDED_BACK], capture_output=True,
                         text=True, check=True, env=env).stdout
    kept, *rest = (int(g) for g in out.split())
    assert kept > BIG // 2
    assert all(g < BIG // 4 for g in rest), out
