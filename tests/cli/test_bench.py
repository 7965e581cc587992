"""Smoke test of the benchmark module (no timing assertions: targets live in docs/performance.md)."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from support.paths import ROOT


def test_bench_smoke(tmp_path):
    out = tmp_path / "results.jsonl"
    md = tmp_path / "performance.md"
    r = subprocess.run([sys.executable, "-m", "benchmarks", "--only", "chain,cli", "--sizes", "10", "--repeat", "1",
                        "--cli-repeat", "1", "--out", str(out), "--markdown", str(md)],
                       capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    chain = [x for x in rows if x["bench"] == "chain"]
    assert len(chain) == 1 and chain[0]["n"] == 10
    c = chain[0]
    for key in ("parse_s", "compile_s", "solve_s", "iteration_s", "lu_s", "peak_rss_bytes"):
        assert set(c[key]) >= {"median", "min", "max"}, key
    for key in ("iterations", "status", "nq", "nc", "phases", "counters", "iteration_per_lu"):
        assert key in c, key
    assert c["status"] == "converged"
    assert {x["bench"] for x in rows} >= {"chain", "help", "small_deck"}
    for x in rows:
        assert {"cores", "python", "numpy", "scipy"} <= set(x["machine"])
        if x["bench"] in ("help", "small_deck"):
            assert x["returncode"] == 0 and set(x["wall_s"]) >= {"median", "min", "max"}
    text = md.read_text()
    assert "## Targets" in text and "## Machine" in text and "| 10 |" in text


def test_unknown_table_is_a_usage_error(tmp_path):
    r = subprocess.run([sys.executable, "-m", "benchmarks", "--only", "chain,nosuch",
                        "--out", str(tmp_path / "r.jsonl")],
                       capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert r.returncode == 2
    assert "nosuch" in r.stderr and "failfast" in r.stderr     # names the known tables
    assert not (tmp_path / "r.jsonl").exists()


@pytest.mark.slow
def test_sweep_bench_rows_and_targets(tmp_path):
    """The sweep table (issue 25 §1) on a 6-case sweep: its rows, the report and the ratios."""
    pytest.importorskip("distributed")
    from benchmarks import sweep as bs
    rows = bs.run(tmp_path, ROOT, cases=(6,), repeat=1, inprocess_repeat=2, chunk=30)
    assert [r["bench"] for r in rows] == ["solve_process", "inprocess_solve", "inprocess_solve",
                                          "sweep_chunk", "sweep"]
    ch = rows[3]
    assert ch["batched"] and ch["same_verdicts"] and ch["converged"] == 30
    assert ch["max_position_difference"] < 1e-9 and ch["together_ms"] > 0
    sw = rows[-1]
    assert sw["returncode"] == 0 and sw["converged"] == 6 and sw["case_ms_median"] > 0
    assert sw["peak_rss_mb"] > 0 and rows[2]["bodies"] == 3 and rows[2]["status"] == "converged"
    assert rows[2]["calls"] > 1000 and rows[2]["fresh_ms"] > 0     # one solve's Python calls
    assert "| sweep, 6 cases |" in "\n".join(bs.markdown(rows))
    names = [t[0] for t in bs.targets(rows)]
    assert any("3-body deck" in n for n in names)        # 1000/100,000 rows: not run here
