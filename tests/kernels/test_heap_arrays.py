"""core.memory.heap_arrays: a large solve's big arrays stay in glibc's heap (no fresh mapping
per block, no automatic trim) and glibc gets its limits back afterwards; small solves and other
C libraries are left alone."""
from __future__ import annotations

import resource

import numpy as np
import pytest

from poise.core import memory


class _FakeLibc:
    def __init__(self):
        self.calls = []

    def mallopt(self, param, value):
        self.calls.append(("mallopt", param, value))
        return 1

    def malloc_trim(self, pad):
        self.calls.append(("trim", pad))
        return 1


def test_small_runs_and_other_c_libraries_are_left_alone(monkeypatch):
    fake = _FakeLibc()
    monkeypatch.setattr(memory, "_libc", fake)
    with memory.heap_arrays(memory.MMAP_MAX_THRESHOLD) as on:
        assert on is False
    assert fake.calls == []
    monkeypatch.setattr(memory, "_libc", False)            # not glibc
    with memory.heap_arrays(1 << 40) as on:
        assert on is False


def test_large_runs_keep_arrays_in_the_heap_and_restore_glibc_limits(monkeypatch):
    fake = _FakeLibc()
    monkeypatch.setattr(memory, "_libc", fake)
    with pytest.raises(RuntimeError):
        with memory.heap_arrays(memory.MMAP_MAX_THRESHOLD + 1) as on:
            assert on is True
            inside = list(fake.calls)
            raise RuntimeError("the solve failed")
    assert ("mallopt", memory._M_MMAP_MAX, 0) in inside
    assert ("mallopt", memory._M_TRIM_THRESHOLD, memory._KEEP) in inside
    after = fake.calls[len(inside):]                    # restored even when the block raised
    assert ("mallopt", memory._M_MMAP_MAX, memory._MMAPS_DEFAULT) in after
    assert ("mallopt", memory._M_MMAP_THRESHOLD, memory.MMAP_MAX_THRESHOLD) in after
    assert after[-1] == ("trim", 0)                     # the freed pages go back at the end
    assert 0 < memory._KEEP < 2 ** 31                   # mallopt takes an int


def test_stages_inside_keep_their_pages_and_nested_blocks_change_nothing(monkeypatch):
    """Inside the block :func:`memory.release` trims nothing (the next stage reuses the pages);
    a nested block leaves glibc's limits to the outer one; outside, release trims again."""
    fake = _FakeLibc()
    monkeypatch.setattr(memory, "_libc", fake)
    with memory.heap_arrays(1 << 30):
        n = len(fake.calls)
        assert memory.release(1 << 40, memory.SOLVE_LARGE) is False
        with memory.heap_arrays(1 << 30) as inner:
            assert inner is False
        assert len(fake.calls) == n                     # no trim, no mallopt
    assert memory.release(1 << 40, memory.SOLVE_LARGE) is True
    assert fake.calls[-1] == ("trim", 0)


def _faults_of_second(n):
    """Minor page faults while a fresh ``n``-float array is filled, one of that size freed
    just before (as one factorisation's storage after the last one's)."""
    a = np.ones(n)
    del a
    r0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    b = np.ones(n)
    r1 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    del b
    return r1 - r0


@pytest.mark.skipif(not memory._glibc(), reason="glibc's allocator only")
def test_a_freed_big_block_is_reused_without_new_pages():
    """Above glibc's largest mmap threshold a block freed and allocated again is mapped afresh
    (every page faulted in again); within ``heap_arrays`` it is reused from the heap."""
    n = 2 * memory.MMAP_MAX_THRESHOLD // 8               # 64 MB
    with memory.heap_arrays(8 * n):
        inside = _faults_of_second(n)
    outside = _faults_of_second(n)
    assert outside > 0
    assert inside <= outside // 4
