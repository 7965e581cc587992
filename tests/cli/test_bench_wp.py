"""Smoke tests of the work-precision benchmark code (no timing assertions)."""
from __future__ import annotations

import pytest
from click.testing import CliRunner

from benchmarks import wp
from benchmarks.decks import BENCH_DIR, build_grid_deck, with_settings


def test_bench_decks_exist():
    for name, (file, *_rest) in wp.DECKS.items():
        assert (BENCH_DIR / file).exists(), name


def test_ladder_point_error_small(tmp_path):
    xml = (BENCH_DIR / "pendulum_multiturn.xml").read_text()
    st, tr = wp.method_settings("FIM_S", 1e-8)
    r = wp.run_point(xml, st, tr, 1, tmp_path, wp.DECKS["pendulum_multiturn"][3],
                     wp._reference_module(), warmup=False)
    assert r["status"] == "converged" and r["error"] < 1e-8
    assert set(r["counts"]) >= {"residuals", "jacobians", "factorizations"}


def test_with_settings_transient():
    out = with_settings((BENCH_DIR / "slider_crank_qs.xml").read_text(),
                        {"method": "FIM_D"}, {"integr_tol": "1.0E-05"}).decode()
    assert 'integr_tol="1.0E-05"' in out and 'method="FIM_D"' in out


def test_grid_deck_solves(tmp_path):
    from poise.app.api import run_deck
    p = tmp_path / "g.xml"
    p.write_text(build_grid_deck(3))
    res = run_deck(str(p))
    assert res.analyses[0].status == "converged"
    assert "analysis_000" in res.timings and "solve" in res.timings


def test_poise_bench_cli(tmp_path):
    from poise_cli.main import cli
    out = tmp_path / "b.jsonl"
    r = CliRunner().invoke(cli, ["bench", str(BENCH_DIR / "chain_20.xml"), "--tolerances",
                                 "1e-4", "--repeat", "1", "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert "FIM_S" in r.output and out.exists()


def _peer_or_skip():
    from benchmarks import peer
    ok, note = peer.exudyn_available()
    if not ok:
        pytest.skip(note)
    ns = {}
    exec(peer.SCRIPT, ns)
    return peer, ns


@pytest.mark.parametrize("name", ["pendulum_multiturn", "fourbar_spring"])
def test_peer_converges_to_reference(name):
    """The Exudyn models of the small linkages (KinematicTree, loop closed by one GenericJoint)
    converge with the peer's settings to the same closed-form reference as poise."""
    peer, ns = _peer_or_skip()
    ref = wp._reference_module()
    prob = {"pendulum_multiturn": peer.problem_pendulum,
            "fourbar_spring": peer.problem_fourbar}[name](ref)
    o = ns["solve"](prob["spec"])
    assert o["converged"], o["message"]
    assert peer._peer_error(o, prob) <= 1e-6
    assert o["iterations"] <= 25


def test_peer_script_as_process_and_chain_row(tmp_path):
    """The same script runs as a whole process (JSON out); a chain (known Exudyn failure,
    reason in the caption) returns a result with its error at stop instead of raising."""
    import json
    import subprocess
    import sys
    peer, ns = _peer_or_skip()
    ref = wp._reference_module()
    prob = peer.problem_fourbar(ref)
    (tmp_path / "spec.json").write_text(json.dumps(prob["spec"]))
    (tmp_path / "peer.py").write_text(peer.SCRIPT)
    out = subprocess.run([sys.executable, str(tmp_path / "peer.py"), str(tmp_path / "spec.json")],
                         capture_output=True, text=True, check=True).stdout
    o = json.loads(out.strip().splitlines()[-1])
    assert o["converged"] and peer._peer_error(o, prob) <= 1e-6
    chain = peer.problem_chain(ref, 10)
    o = ns["solve"](chain["spec"])
    assert len(o["cg"]) == 10 and peer._peer_error(o, chain) is not None
    assert any("geometric stiffness" in ln for ln in peer.caption())
