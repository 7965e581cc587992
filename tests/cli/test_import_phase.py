"""Imports are a phase of their own (poise.core.phases): the modules a run imports on first use
are timed as ``timings['import']`` and left out of parse/compile/solve and the solver phases.
Checked with a fake clock advanced by the imported modules themselves (no timing)."""
from __future__ import annotations

import importlib
import json
import subprocess
import sys
import textwrap

import pytest

from poise.core import phases

from support.paths import DECKS


class FakeClock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self):
        return self.t


@pytest.fixture
def fake(monkeypatch, tmp_path):
    clock = FakeClock()
    monkeypatch.setattr(phases, "_clock", clock)
    monkeypatch.setattr(phases, "_local", type(phases._local)())
    monkeypatch.syspath_prepend(str(tmp_path))
    sys.modules["_poise_fake_clock"] = clock
    yield clock, tmp_path
    sys.modules.pop("_poise_fake_clock", None)
    for name in [m for m in sys.modules if m.startswith("_pfc_")]:
        del sys.modules[name]


def _module(d, name, advance, body=""):
    (d / f"{name}.py").write_text(textwrap.dedent(f"""
        import _poise_fake_clock as clock
        {body}
        clock.t += {advance}
    """))


def test_imports_are_counted_once_and_left_out_of_now(fake):
    clock, d = fake
    _module(d, "_pfc_inner", 50.0)
    _module(d, "_pfc_outer", 100.0, body="import _pfc_inner")
    importlib.invalidate_caches()
    before = list(sys.meta_path)
    with phases.counting_imports():
        t0, i0 = phases.now(), phases.import_seconds()
        clock.t += 7.0                       # work, not imports
        import _pfc_outer  # noqa: F401
        clock.t += 3.0
        assert phases.import_seconds() - i0 == pytest.approx(150.0)   # nested: counted once
        assert phases.now() - t0 == pytest.approx(10.0)               # the work only
        import _pfc_outer  # noqa: F401,F811 - cached: nothing more
        assert phases.import_seconds() - i0 == pytest.approx(150.0)
    assert sys.meta_path == before                   # the finder left with its last user
    mod = sys.modules["_pfc_outer"]
    assert type(mod.__loader__).__name__ == "SourceFileLoader"     # its own loader back
    assert mod.__spec__.loader is mod.__loader__


def test_phase_intervals_exclude_imports(fake):
    clock, d = fake
    _module(d, "_pfc_lazy", 40.0)
    importlib.invalidate_caches()
    with phases.counting_imports():
        phases.reset()
        t0 = phases.now()
        clock.t += 2.0
        import _pfc_lazy  # noqa: F401 - a lazy import inside a timed phase
        phases.add("evaluate", phases.now() - t0)
    assert phases.snapshot()["evaluate"] == pytest.approx(2.0)


def test_outside_the_context_imports_are_not_timed(fake):
    clock, d = fake
    _module(d, "_pfc_plain", 40.0)
    importlib.invalidate_caches()
    i0 = phases.import_seconds()
    import _pfc_plain  # noqa: F401
    assert phases.import_seconds() == i0
    assert phases._finder not in sys.meta_path


def test_a_failing_import_is_still_timed_and_raises(fake):
    clock, d = fake
    (d / "_pfc_broken.py").write_text("import _poise_fake_clock as c\nc.t += 5\nraise ValueError('x')\n")
    importlib.invalidate_caches()
    with phases.counting_imports():
        i0 = phases.import_seconds()
        with pytest.raises(ValueError):
            import _pfc_broken  # noqa: F401
        assert phases.import_seconds() - i0 == pytest.approx(5.0)
        with pytest.raises(ModuleNotFoundError):
            import _pfc_missing  # noqa: F401


def test_first_fim_d_solve_in_a_process_times_its_imports_apart(tmp_path):
    """A fresh process: FIM_D imports SUNDIALS (scikit-sundae) on first use; that time is
    ``timings['import']``, recorded in the results file too."""
    out = tmp_path / "r.h5"
    code = textwrap.dedent(f"""
        import json, sys
        import poise
        from poise.results.hdf5 import write_results
        before = "sksundae" in sys.modules
        r = poise.solve({str(DECKS / "qs_pendulum_ramp.xml")!r}, method="FIM_D")
        write_results(r, {str(out)!r})
        import h5py
        with h5py.File({str(out)!r}) as f:
            filed = {{k: float(v) for k, v in f["timings"].attrs.items()}}
        print(json.dumps(dict(before=before, after="sksundae" in sys.modules,
                              status=r.status, timings=r.timings, filed=filed)))
    """)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=300, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout.strip().splitlines()[-1])
    assert doc["status"] == "converged" and not doc["before"] and doc["after"]
    t = doc["timings"]
    assert t["import"] > 0.0                       # SUNDIALS (and more) imported in the run
    assert doc["filed"]["import"] == pytest.approx(t["import"])
    assert all(t[k] >= 0.0 for k in ("parse", "compile", "solve", "import"))
