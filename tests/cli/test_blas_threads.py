"""BLAS runs single-threaded inside a solve whatever the caller imported first (poise.core.blas):
checked in fresh processes with threadpoolctl's own report, taken inside the solve."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

from support.paths import DECKS

PROBE = textwrap.dedent("""
    import json
    {first}
    from threadpoolctl import threadpool_info, threadpool_limits

    def blas_threads():
        return sorted({{i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}})

    {raise_threads}
    before = blas_threads()
    inside = []
    import poise.app.runner as runner
    real = runner.Driver.run

    def spy(self, *a, **k):                  # inside the solve, per analysis
        inside.append(blas_threads())
        return real(self, *a, **k)

    runner.Driver.run = spy
    r = poise.solve({deck!r}, method="FIM_S")
    print(json.dumps(dict(status=r.status, before=before, inside=inside,
                          after=blas_threads())))
""")


def _probe(first: str, env_extra=None, raise_threads=True) -> dict:
    env = {k: v for k, v in os.environ.items()
           if k not in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")}
    env.update(env_extra or {})
    code = PROBE.format(first=first, deck=str(DECKS / "fourbar_spring.xml"),
                        raise_threads="threadpool_limits(2, 'blas')" if raise_threads else "")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=300, env=env)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1])


def test_numpy_imported_first_is_limited_inside_the_solve_and_restored():
    d = _probe("import numpy\nimport poise")
    assert d["status"] == "converged" and d["inside"]
    assert all(t == [1] for t in d["inside"])          # every BLAS library: one thread
    assert d["after"] == d["before"]                   # the caller's setting comes back
    if d["before"] == [1]:
        pytest.skip("this machine's BLAS cannot run 2 threads: nothing else to compare")


def test_poise_imported_first_leaves_blas_single_threaded_for_libraries_loaded_later():
    d = _probe("import poise\nimport numpy", raise_threads=False)
    assert d["before"] == [1] and all(t == [1] for t in d["inside"])


def test_the_callers_own_setting_wins():
    d = _probe("import numpy\nimport poise", env_extra={"OPENBLAS_NUM_THREADS": "2"},
               raise_threads=False)
    assert d["inside"] and all(t == d["before"] for t in d["inside"])
