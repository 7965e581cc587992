"""Wall time per solver phase of the current run (what each results file records in ``/timings``).

The runner calls :func:`reset` before solving and :func:`snapshot` after; the instrumented
places add their elapsed time with :func:`add`:

* ``evaluate`` — element kernels and the residual (``Model.evaluate``, batched frame outputs);
* ``assemble`` — KKT Jacobian assembly (``Model.jacobian``: local tangents + scatter);
* ``factorise`` — LU factorisations (``solvers.linalg.Factor``).

Phases are exclusive (none is timed inside another), so ``solve - (evaluate + assemble +
factorise)`` is the rest: linear solves, line search, retraction, IDA/RATTLE bookkeeping,
outputs. The clock is per thread (sweeps may solve in threads).

Imports are a phase of their own: poise imports what a deck needs when it first needs it (SciPy
for a sparse system, SUNDIALS for FIM_D), so the first solve in a process would otherwise carry
0.1-0.3 s that no later solve pays. Inside :func:`counting_imports` every module import is timed
(a finder at the front of ``sys.meta_path`` wraps the loaders) and :func:`now` is a clock that
stops while a module is imported: every interval measured with it, the phases above included,
excludes import time, which :func:`import_seconds` reports instead.
"""
from __future__ import annotations

import contextlib
import sys
import threading
import time

PHASES = ("evaluate", "assemble", "factorise")

class _Local(threading.local):
    """This thread's import total and phase times (the class values until it sets its own:
    read as plain attributes, the solvers read the clock a few dozen times per small solve)."""

    imports = 0.0
    acc = None
    depth = 0
    finding = False


_local = _Local()
_clock = time.perf_counter


def now() -> float:
    """Seconds on a per-thread clock that does not advance while a module is being imported
    (inside :func:`counting_imports`); differences of it are wall times without imports."""
    return _clock() - _local.imports


def import_seconds() -> float:
    """Seconds this thread has spent importing modules inside :func:`counting_imports` (a
    running total: take differences)."""
    return _local.imports


def _acc() -> dict:
    acc = _local.acc
    if acc is None:
        acc = _local.acc = dict.fromkeys(PHASES, 0.0)
    return acc


def reset() -> None:
    """Start a run: all phases at zero."""
    _local.acc = dict.fromkeys(PHASES, 0.0)


def add(phase: str, seconds: float) -> None:
    """Add ``seconds`` of wall time to ``phase``."""
    acc = _local.acc
    if acc is None:
        acc = _acc()
    acc[phase] = acc.get(phase, 0.0) + seconds


def snapshot() -> dict:
    """Copy of the accumulated times [s] per phase."""
    return dict(_acc())


# ------------------------------------------------------------------------------ import clock
@contextlib.contextmanager
def _timed():
    """Time the block as import work of this thread; nested imports count once (outermost)."""
    depth = _local.depth
    _local.depth = depth + 1
    t0 = _clock()
    try:
        yield
    finally:
        _local.depth = depth
        if depth == 0:
            _local.imports = _local.imports + (_clock() - t0)


class _TimedLoader:
    """A module's own loader, its ``create_module``/``exec_module`` timed; the module gets its
    own loader back once executed (``__loader__``, ``__spec__.loader``)."""

    def __init__(self, loader):
        self._loader = loader

    def __getattr__(self, name):         # get_resource_reader, get_source, is_package, ...
        return getattr(self._loader, name)

    def create_module(self, spec):
        create = getattr(self._loader, "create_module", None)
        if create is None:
            return None
        with _timed():
            return create(spec)

    def exec_module(self, module):
        try:
            with _timed():
                self._loader.exec_module(module)
        finally:
            if getattr(module, "__loader__", None) is self:
                module.__loader__ = self._loader
            spec = getattr(module, "__spec__", None)
            if spec is not None and spec.loader is self:
                spec.loader = self._loader


class _ImportClock:
    """``sys.meta_path`` finder: asks the finders after it for the spec (timing the search)
    and wraps the loader it returns in a :class:`_TimedLoader`."""

    def find_spec(self, name, path, target=None):
        if _local.finding:
            return None
        _local.finding = True
        try:
            with _timed():
                spec = None
                for finder in list(sys.meta_path):
                    find = getattr(finder, "find_spec", None)
                    if finder is self or find is None:
                        continue
                    spec = find(name, path, target)
                    if spec is not None:
                        break
        finally:
            _local.finding = False
        if spec is not None and hasattr(spec.loader, "exec_module") \
                and not isinstance(spec.loader, _TimedLoader):
            spec.loader = _TimedLoader(spec.loader)
        return spec

    def invalidate_caches(self):
        pass


_finder = _ImportClock()
_users = 0
_users_lock = threading.Lock()


@contextlib.contextmanager
def counting_imports():
    """Inside the block, module imports (of any thread) are timed as that thread's import phase
    and left out of :func:`now`. Re-entrant; the finder leaves ``sys.meta_path`` with the last
    user."""
    global _users
    with _users_lock:
        if _users == 0 and _finder not in sys.meta_path:
            sys.meta_path.insert(0, _finder)
        _users += 1
    try:
        yield
    finally:
        with _users_lock:
            _users -= 1
            if _users == 0:
                with contextlib.suppress(ValueError):
                    sys.meta_path.remove(_finder)
