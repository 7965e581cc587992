"""A sweep's chunk solved vectorised over cases (poise.solvers.batched, poise.app.chunk_batch):
the same answers and verdicts as each case's single solve, on decks of different element
families; cases the batch does not finish cleanly solved alone (the single solve's record);
structural parameters split groups; records independent of the chunk (resume); the swept
pendulum against its closed form."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

import poise
from poise.app.cases import group_cases, make_cases, resolve_param
from poise.app.chunk_batch import plan_batch
from poise.app.chunks import FrameLayout, Output, SweepJob, make_template, solve_chunk
from poise.solvers import batched

from support.paths import DECKS
from support.reference import PENDULUM_PARAMS, pendulum_multiturn


def _job(deck, params, overrides=None, outputs=("bodies[2].position",)):
    outs = tuple(Output(o, "bodies", int(o.split("[")[1].split("]")[0]), o.split(".")[1],
                        (3,) if o.endswith("position") else (3, 3)) for o in outputs)
    return SweepJob(deck.read_bytes(), str(deck), tuple(replace(p, values=[]) for p in params),
                    dict(overrides or {}), outs, FrameLayout((0.0,), (0,)), key=str(deck))


def _setup(name, sets, overrides=None, mode="grid"):
    deck = DECKS / name
    spec = poise.load_deck(str(deck))
    params = [resolve_param(spec, k, v) for k, v in sets.items()]
    cases = make_cases(params, mode)
    return deck, params, cases, _job(deck, params, overrides)


def _same_verdict(a, b, L):
    assert (a.status, a.exit_code, a.iterations, a.stability, a.n_negative, a.n_zero,
            a.stability_modes, a.modes, a.message) == \
        (b.status, b.exit_code, b.iterations, b.stability, b.n_negative, b.n_zero,
         b.stability_modes, b.modes, b.message)
    assert a.converged.tolist() == b.converged.tolist()
    for k, v in b.outputs.items():
        assert np.allclose(a.outputs[k], v, rtol=0, atol=1e-9 * L, equal_nan=True), k


@pytest.mark.parametrize("name, sets, overrides, family", [
    ("pendulum_multiturn.xml", {"Force_SpringDamper[1].stiffness": "6000:40000:2000"}, {},
     "AxisTorque"),
    ("fourbar_spring.xml", {"Force_SpringDamper[1].stiffness": "0.5:8:0.5",
                            "Force_SpringDamper[1].length": "150,200,250"}, {}, "LineForce"),
    ("bushing_block.xml", {"Force_Bushing[1].kx": "200:2000:300",
                           "Force_Bushing[1].preload_y": "0,20,40"},
     {"compliance_markers": "none"}, "Bushing"),
    # steps the neutral-direction filter shapes (Newton's filtered step tried first)
    ("double_pendulum.xml", {"Force_Vector_OneBody[1].fy_expression": "-20:20:5"}, {}, None),
])
def test_batched_cases_agree_with_their_single_solves(name, sets, overrides, family):
    deck, params, cases, job = _setup(name, sets, overrides)
    template = make_template(job, {})
    plan = plan_batch(template, cases[0])
    assert plan is not None                        # solved together
    fams = {type(plan.model.families[fi]).__name__ for fi in plan.arrays}
    assert family is None or family in fams
    together = solve_chunk(template, list(enumerate(cases)))
    alone = solve_chunk(template, list(enumerate(cases)), batched=False)
    L = float(plan.model.L)
    for a, b in zip(together, alone):
        _same_verdict(a, b, L)
        assert a.status == "converged" and a.stability == "stable"
        # certified at the written state within the deck's tolerances, as the single solve
        assert a.imbalance <= plan.settings.max_imbalance * max(1.0, L)
        assert a.error <= plan.settings.max_error


def test_a_case_the_batch_does_not_finish_is_solved_alone(monkeypatch):
    """Too few iterations for every case: the batch gives them up, each is solved alone and
    its record is the single solve's (here the fallback chain's verdict), whatever it is."""
    deck, params, cases, job = _setup("pendulum_multiturn.xml",
                                      {"Force_SpringDamper[1].stiffness": "5000:30000:5000"},
                                      {"max_num_iter": 3})
    template = make_template(job, {})
    seen = []
    real = batched.CaseBatch.solve

    def spy(self, state0, C, max_iter=None):
        out = real(self, state0, C, max_iter)
        seen.extend(out)
        return out
    monkeypatch.setattr(batched.CaseBatch, "solve", spy)
    together = solve_chunk(template, list(enumerate(cases)))
    assert seen and all(c.alone and c.why == "iteration limit" for c in seen)
    alone = solve_chunk(template, list(enumerate(cases)), batched=False)
    for a, b in zip(together, alone):
        _same_verdict(a, b, 400.0)
        assert a.imbalance == b.imbalance and a.error == b.error


def test_unstable_and_soft_cases_leave_the_batch_with_their_own_verdicts():
    """Springs too soft to hold the pendulum up (k < m g l_cg = 3924 N mm): whatever class or
    status a case gets alone, it gets in the sweep; the stiff ones stay batched."""
    deck, params, cases, job = _setup("pendulum_multiturn.xml",
                                      {"Force_SpringDamper[1].stiffness": "100,1000,3000,3900,"
                                                                          "4000,8000,20000"})
    template = make_template(job, {})
    together = solve_chunk(template, list(enumerate(cases)))
    alone = solve_chunk(template, list(enumerate(cases)), batched=False)
    for a, b in zip(together, alone):
        _same_verdict(a, b, 400.0)
    assert together[-1].status == "converged"


def test_structural_parameters_split_groups():
    deck, params, cases, job = _setup("pendulum_multiturn.xml",
                                      {"Param_Static.method": "FIM_S,MKEAM",
                                       "Force_SpringDamper[1].stiffness": "10000,20000,30000"})
    groups = group_cases(params, cases, range(len(cases)))
    assert len(groups) == 2
    for group, idx in groups.values():
        template = make_template(job, group)
        plan = plan_batch(template, cases[idx[0]])
        assert (plan is not None) == (group["Param_Static.method"] == "FIM_S")
        chunk = [(i, cases[i]) for i in idx]
        for a, b in zip(solve_chunk(template, chunk), solve_chunk(template, chunk, False)):
            _same_verdict(a, b, 400.0)


def test_records_do_not_depend_on_the_chunk():
    """A case's record is the same bits in any chunk, at any place in it (what resuming a
    sweep per chunk relies on)."""
    deck, params, cases, job = _setup("fourbar_spring.xml",
                                      {"Force_SpringDamper[1].stiffness": "0.5:6:0.25"})
    template = make_template(job, {})
    every = list(enumerate(cases))
    whole = solve_chunk(template, every)
    parts = solve_chunk(template, every[1::2]) + solve_chunk(template, every[::-2])
    by_case = {r.case: r for r in parts}
    for r in whole:
        p = by_case[r.case]
        assert (r.iterations, r.imbalance, r.error) == (p.iterations, p.imbalance, p.error)
        assert r.outputs["bodies[2].position"].tobytes() == \
            p.outputs["bodies[2].position"].tobytes()


def test_swept_pendulum_stiffness_against_the_closed_form():
    ks = [4500.0, 7000.0, 12000.0, 20000.0, 35000.0, 60000.0]
    deck, params, cases, job = _setup("pendulum_multiturn.xml",
                                      {"Force_SpringDamper[1].stiffness": ks})
    job = _job(deck, params, outputs=("bodies[2].position", "bodies[2].orientation"))
    template = make_template(job, {})
    assert plan_batch(template, cases[0]) is not None
    recs = solve_chunk(template, list(enumerate(cases)))
    for k, rec in zip(ks, recs):
        ref = pendulum_multiturn({**PENDULUM_PARAMS, "k": k})
        assert rec.status == "converged" and rec.stability == "stable"
        assert np.allclose(rec.outputs["bodies[2].position"][0], ref["cg"], atol=1e-7)
        assert np.allclose(rec.outputs["bodies[2].orientation"][0], ref["orientation"],
                           atol=1e-9)
        # the spring winds the pendulum by whole turns: the CG angle tells theta modulo 2 pi
        cg = rec.outputs["bodies[2].position"][0]
        assert math.isclose(math.atan2(cg[1], cg[0]) % (2 * math.pi),
                            ref["theta"] % (2 * math.pi), abs_tol=1e-9)


def test_an_invalid_case_is_reported_as_its_single_solve_reports_it():
    """A translational spring's free length < 0 is valid as a number but not for that type:
    the validator's element rule, as ``poise solve`` would say it (``invalid_deck``)."""
    deck, params, cases, job = _setup("fourbar_spring.xml",
                                      {"Force_SpringDamper[1].length": "-50,150,200"})
    template = make_template(job, {})
    together = solve_chunk(template, list(enumerate(cases)))
    alone = solve_chunk(template, list(enumerate(cases)), batched=False)
    assert together[0].status == "invalid_deck" and "length" in together[0].message
    for a, b in zip(together, alone):
        _same_verdict(a, b, 400.0)


def test_each_case_takes_its_single_solves_iterates():
    """Per case the batch records the rows a single solve records (imbalance, error, step and
    line-search length per Newton iteration, then the converged row): the same iterates (to
    round-off: a single small solve sums its residual in another order than the batch, so the
    measures at the round-off floor agree to 1e-9 of the column's first, largest, values)."""
    from poise.app.cases import apply_case
    deck, params, cases, job = _setup("fourbar_spring.xml",
                                      {"Force_SpringDamper[1].stiffness": "0.5,2,6"})
    template = make_template(job, {})
    plan = plan_batch(template, cases[0])
    vals = np.array([[c[p.key] for p in params] for c in cases])
    res = batched.CaseBatch(plan.model, plan.settings, plan.fields(vals),
                            plan.active).solve(plan.state0, len(cases))
    spec = poise.load_deck(str(deck))
    for c, r in zip(cases, res):
        assert not r.alone and len(r.rows) == r.iterations + 1
        one = poise.solve(apply_case(spec, params, c)[0], quiet=True).analyses[0].datasets
        rows = np.array(r.rows, float)
        for k, name in enumerate(("imbalance", "error", "step_norm", "step_length")):
            ref = np.asarray(one[f"iterations/{name}"], float)
            floor = 1e-9 * float(np.max(np.abs(ref[np.isfinite(ref)]), initial=0.0))
            assert np.allclose(rows[:, k], ref, rtol=1e-9, atol=max(floor, 1e-12),
                               equal_nan=True), name


def test_a_small_batched_sweep_is_solved_in_the_sweeping_process(tmp_path, monkeypatch):
    """Cases solved together estimated below a local cluster's start are solved in the
    sweeping process (no worker started); the file holds what the workers would write. The
    estimate is a measured time: the limit is set so that the decision does not depend on the
    machine's load."""
    import poise.app.sweep as sweep_mod
    monkeypatch.setattr(sweep_mod, "HEAD_START_S", 1e9)
    sets = {"Force_SpringDamper[1].stiffness": "6000:40000:2000"}
    deck = str(DECKS / "pendulum_multiturn.xml")
    run_sweep = sweep_mod.run_sweep
    here = run_sweep(deck, sets, out_dir=str(tmp_path / "here"), workers=2,
                     progress=False, outputs=("bodies[2].position",))
    there = run_sweep(deck, sets, out_dir=str(tmp_path / "there"), workers=2,
                      progress=False, outputs=("bodies[2].position",),
                      chunk_size=4)                          # a chunk size: on the workers
    assert here.timings["start"] == 0.0 and here.workers == 1
    assert there.timings["start"] > 0.0
    import h5py
    with h5py.File(tmp_path / "here" / "sweep.h5") as a, \
            h5py.File(tmp_path / "there" / "sweep.h5") as b:
        assert a["status"].shape == (18,)
        assert [s.decode() if isinstance(s, bytes) else s for s in a["status"][()]] == \
            ["converged"] * 18
        pa, pb = a["bodies[2].position"][()], b["bodies[2].position"][()]
        assert np.array_equal(pa, pb)                 # the same bits, wherever solved
        k = a["Force_SpringDamper[1].stiffness"][()]
    assert k[0] == pytest.approx(6000.0) and k[-1] == pytest.approx(40000.0)


def test_a_batched_sweep_estimated_beyond_the_limit_goes_to_the_workers(tmp_path, monkeypatch):
    """Only the timed first chunk is solved in the sweeping process when the rest would take
    longer than HEAD_START_S; the rest is solved on the workers, with the same bits."""
    import h5py

    import poise.app.sweep as sweep_mod
    monkeypatch.setattr(sweep_mod, "HEAD_START_S", 0.0)
    sets = {"Force_SpringDamper[1].stiffness": "6000:40000:2000"}
    deck = str(DECKS / "pendulum_multiturn.xml")
    out = sweep_mod.run_sweep(deck, sets, out_dir=str(tmp_path / "s"), workers=2,
                              progress=False, outputs=("bodies[2].position",))
    assert out.timings["start"] > 0.0 and out.workers >= 1
    monkeypatch.setattr(sweep_mod, "HEAD_START_S", 1e9)
    ref = sweep_mod.run_sweep(deck, sets, out_dir=str(tmp_path / "r"), workers=2,
                              progress=False, outputs=("bodies[2].position",))
    assert ref.timings["start"] == 0.0
    with h5py.File(tmp_path / "s" / "sweep.h5") as a, h5py.File(tmp_path / "r" / "sweep.h5") as b:
        assert np.array_equal(a["bodies[2].position"][()], b["bodies[2].position"][()])
        assert a["iterations"][()].tolist() == b["iterations"][()].tolist()
        assert np.all(a["iterations"][()] > 0)


def test_templates_do_not_share_the_cached_parse():
    """Each template gets its own copy of the process's parsed deck: an element changed through
    one template (or anything that holds its spec) reaches neither the cache nor the next
    template of the same deck."""
    deck, params, cases, job = _setup("pendulum_multiturn.xml",
                                      {"Force_SpringDamper[1].stiffness": "10000,20000"})
    first = make_template(job, {})
    ps = next(e for e in first.spec.model if e.tag == "Param_Static")
    ps.attrs["method"] = "MKEAM"
    first.spec.model[0].attrs.clear()
    again = make_template(job, {})
    assert next(e for e in again.spec.model
                if e.tag == "Param_Static").attrs["method"] == "FIM_S"
    assert again.spec.model[0].attrs and again.spec.model[0] is not first.spec.model[0]
    assert plan_batch(again, cases[0]) is not None
