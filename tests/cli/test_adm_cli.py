"""Adams datasets at the command line: ``poise solve|check`` of ``.adm``/``.acf``, ``--ignore``
(recorded in the results file and on the summary line), and ``poise convert`` (exit codes,
``--json``, atomic output that never replaces an input)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from support.paths import DECKS

POISE = str(Path(sys.executable).with_name("poise"))
PENDULUM = DECKS / "adm" / "pendulum_multiturn.adm"
CONTACT = """contact model
PART/1, GROUND
MARKER/10, PART = 1
PART/2, MASS = 1, CM = 20, IP = 1, 1, 1
MARKER/20, PART = 2, QP = 1, 0, 0
MARKER/21, PART = 2
JOINT/1, REVOLUTE, I = 21, J = 10
SPRINGDAMPER/2, ROTATION, I = 21, J = 10, KT = 100
ACCGRAV/JGRAV = -9.81
CONTACT/7, IGEOM = 1, JGEOM = 2
GRAPHICS/1, CYLINDER, CM = 20
"""


def poise(*args, cwd=None):
    r = subprocess.run([POISE, *map(str, args)], capture_output=True, text=True, cwd=cwd,
                       timeout=120)
    assert "Traceback" not in r.stderr
    return r


def test_solve_and_check_a_dataset(tmp_path):
    out = tmp_path / "p.h5"
    r = poise("solve", PENDULUM, "-o", out, "--json")
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    assert data["status"] == "converged" and data["deck"] == str(PENDULUM)
    with h5py.File(out) as f:
        assert f.attrs["deck"] == str(PENDULUM)
        assert "ignored" not in f.attrs
    r = poise("check", PENDULUM, "--json")
    assert r.returncode == 0
    assert json.loads(r.stdout)["dof"] == 1


def test_refused_physics_is_exit_3_then_ignore_solves_and_records(tmp_path):
    adm = tmp_path / "c.adm"
    adm.write_text(CONTACT)
    r = poise("solve", adm, "-o", tmp_path / "c.h5")
    assert r.returncode == 3
    assert f"{adm}:10: CONTACT/7: poise does not support contact between CAD solids; " \
           "`--ignore CONTACT` solves without it" in r.stderr
    assert not (tmp_path / "c.h5").exists()
    r = poise("solve", adm, "-o", tmp_path / "c.h5", "--ignore", "contact")
    assert r.returncode == 0, r.stderr
    assert "; left out (--ignore): 1 CONTACT" in r.stderr.splitlines()[0]
    assert f"{adm}:11: GRAPHICS/1: 1 GRAPHICS statement skipped" in r.stderr
    with h5py.File(tmp_path / "c.h5") as f:
        assert json.loads(f.attrs["ignored"]) == [
            {"file": str(adm), "kind": "CONTACT", "line": 10, "statement": "CONTACT/7"}]
    assert poise("check", adm, "--ignore", "CONTACT").returncode == 0


def test_ignore_usage_errors(tmp_path):
    r = poise("solve", PENDULUM, "-o", tmp_path / "x.h5", "--ignore", "CONTACTS")
    assert r.returncode == 2 and "unknown kind (did you mean CONTACT?)" in r.stderr
    r = poise("solve", DECKS / "pendulum_multiturn.xml", "-o", tmp_path / "x.h5",
              "--ignore", "CONTACT")
    assert r.returncode == 2 and "--ignore applies to Adams datasets" in r.stderr


def test_convert_writes_a_deck_that_solves_the_same(tmp_path):
    out = tmp_path / "p.xml"
    r = poise("convert", PENDULUM, "-o", out, "--json")
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    assert (data["status"], data["output"], data["exit_code"]) == ("converted", str(out), 0)
    assert data["model_elements"] > 0 and data["commands"] == 2
    assert [p for p in os.listdir(tmp_path) if p != "p.xml"] == []      # no temporary left
    a = poise("solve", PENDULUM, "-o", tmp_path / "a.h5")
    b = poise("solve", out, "-o", tmp_path / "b.h5")
    assert a.returncode == b.returncode == 0
    with h5py.File(tmp_path / "a.h5") as fa, h5py.File(tmp_path / "b.h5") as fb:
        pa, pb = fa["analysis_000/bodies/position"][...], fb["analysis_000/bodies/position"][...]
        assert (pa == pb).all()
        assert list(fa["model/bodies/label"][...]) == list(fb["model/bodies/label"][...])


def test_convert_refuses_its_inputs_and_bad_datasets(tmp_path):
    acf = DECKS / "adm" / "adm_commands.acf"
    for target in (acf, DECKS / "adm" / "adm_commands.adm"):
        r = poise("convert", acf, "-o", target)
        assert r.returncode == 2 and "is the input deck" in r.stderr
    bad = tmp_path / "bad.adm"
    bad.write_text("t\nPART/1, GROUND\nJOINT/1, REVOLUTE, I = 1, J = 2\n")
    r = poise("convert", bad, "-o", tmp_path / "bad.xml", "--json")
    assert r.returncode == 3
    assert json.loads(r.stdout)["problems"] == [f"{bad}:3: JOINT/1: I=1: no MARKER/1 in the "
                                                 f"dataset",
                                                 f"{bad}:3: JOINT/1: J=2: no MARKER/2 in the "
                                                 f"dataset"]
    assert not (tmp_path / "bad.xml").exists()
    r = poise("convert", DECKS / "pendulum_multiturn.xml", "-o", tmp_path / "x.xml")
    assert r.returncode == 2 and "not an Adams dataset" in r.stderr


@pytest.mark.parametrize("name", ["adm_commands.acf", "qs_slider_crank_rev.acf"])
def test_command_files_run_every_analysis(name, tmp_path):
    r = poise("solve", DECKS / "adm" / name, "-o", tmp_path / "r.h5", "--json")
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    assert data["status"] == "converged"
    kinds = [a["analysis_type"] for a in data["analyses"]]
    assert kinds == (["static", "quasistatic", "quasistatic"] if name == "adm_commands.acf"
                     else ["quasistatic"])
    with h5py.File(tmp_path / "r.h5") as f:
        model = json.loads(f.attrs["input_files"])
        assert list(model) == [str(DECKS / "adm" / name.replace(".acf", ".adm"))]


def test_batch_freshness_follows_the_dataset_of_a_command_file(tmp_path):
    from poise.app.batch import up_to_date
    (tmp_path / "model.adm").write_text((DECKS / "adm" / "pendulum_multiturn.adm").read_text())
    acf = tmp_path / "run.acf"
    acf.write_text("model\nout\nSIMULATE/STATIC\nSTOP\n")
    out = tmp_path / "b" / "run.h5"
    assert poise("batch", acf, "--out-dir", tmp_path / "b", "-j", "1", "-q").returncode == 0
    assert up_to_date(str(acf), str(out), {})
    (tmp_path / "model.adm").write_text((tmp_path / "model.adm").read_text() + "! edited\n")
    assert not up_to_date(str(acf), str(out), {})


def test_bench_ladder_of_a_dataset():
    r = poise("bench", PENDULUM, "--methods", "FIM_S", "--tolerances", "1e-6", "--repeat", "1",
              "-q")
    assert r.returncode == 0, r.stderr
    row = [ln.split() for ln in r.stdout.splitlines() if ln.startswith("FIM_S")][0]
    assert row[2] == "converged"


def test_batch_ignore_applies_to_datasets_records_and_keys_freshness(tmp_path):
    from poise.app.batch import BATCH_KEYS, up_to_date
    adm = tmp_path / "c.adm"
    adm.write_text(CONTACT)
    xml = DECKS / "pendulum_multiturn.xml"
    out = tmp_path / "b"
    r = poise("batch", adm, xml, "--out-dir", out, "-j", "1", "--json")
    assert r.returncode == 3
    rows = json.loads(r.stdout)["rows"]
    assert rows[0]["status"] == "invalid_deck" and "`--ignore CONTACT`" in rows[0]["message"]
    assert rows[1]["status"] == "converged" and rows[1]["ignored"] == ""

    r = poise("batch", adm, xml, "--out-dir", out, "-j", "1", "--ignore", "contact", "--json")
    assert r.returncode == 0, r.stderr
    c, p = json.loads(r.stdout)["rows"]
    assert (c["status"], c["skipped"], c["ignored"]) == ("converged", False, "1 CONTACT")
    assert (p["skipped"], p["ignored"]) == (True, "")       # an XML deck: --ignore is not its
    assert f"{adm}: converged" in r.stderr and "; left out (--ignore): 1 CONTACT" in r.stderr
    with h5py.File(out / "c.h5") as f:
        assert [d["statement"] for d in json.loads(f.attrs["ignored"])] == ["CONTACT/7"]
        assert json.loads(f.attrs["run_overrides"]) == {"ignore": ["CONTACT"]}
    with open(out / "summary.csv") as f:
        head = f.readline().strip().split(",")
    assert head == list(BATCH_KEYS) and head[-1] == "ignored"
    assert "1 CONTACT" in (out / "summary.csv").read_text().splitlines()[1]
    # the --ignore kinds key freshness: the same kinds are up to date, others are not
    assert up_to_date(str(adm), str(out / "c.h5"), {}, ignore=("CONTACT",))
    assert not up_to_date(str(adm), str(out / "c.h5"), {})
    assert not up_to_date(str(adm), str(out / "c.h5"), {}, ignore=("CONTACT", "FRICTION"))
    assert up_to_date(str(xml), str(out / "pendulum_multiturn.h5"), {}, ignore=("CONTACT",))

    r = poise("batch", adm, xml, "--out-dir", out, "-j", "1", "--ignore", "CONTACT", "--json")
    assert [row["skipped"] for row in json.loads(r.stdout)["rows"]] == [True, True]
    assert "1 CONTACT (skipped, up to date)" in r.stderr    # read back from the file

    r = poise("batch", xml, "--out-dir", out, "--ignore", "CONTACT")
    assert r.returncode == 2 and "none of the decks is one" in r.stderr
    r = poise("batch", adm, "--out-dir", out, "--ignore", "CONTACTS")
    assert r.returncode == 2 and "did you mean CONTACT?" in r.stderr


def test_sweep_ignore_records_in_cases_index_and_summary(tmp_path):
    adm = tmp_path / "c.adm"
    adm.write_text(CONTACT)
    out = tmp_path / "s"
    args = ["sweep", adm, "--set", "Force_SpringDamper[2].stiffness=100,400", "--out-dir", out,
            "-j", "1", "--output", "bodies[2].position"]
    r = poise(*args, "--json")
    assert r.returncode == 3 and "CONTACT/7" in r.stderr
    r = poise(*args, "--ignore", "CONTACT", "--json")
    assert r.returncode == 0, r.stderr
    assert r.stderr.strip().splitlines()[-1].endswith("; left out (--ignore): 1 CONTACT")
    rows = json.loads(r.stdout)["rows"]
    assert [row["ignored"] for row in rows] == ["1 CONTACT", "1 CONTACT"]
    # a 1 kg bob 1 m from the hinge, gravity -Y, torsion spring k: k theta = g cos(theta)
    for row, k in zip(rows, (100.0, 400.0)):
        x, y = row["bodies[2].position[0]"], row["bodies[2].position[1]"]
        theta = np.arctan2(-y, x)
        assert abs(k * theta - 9.81 * np.cos(theta)) < 1e-8
        with h5py.File(out / row["file"]) as f:
            assert json.loads(f.attrs["ignored"])[0]["kind"] == "CONTACT"
            assert json.loads(f.attrs["run_overrides"]) == {"ignore": ["CONTACT"]}
    index = json.loads((out / "index.json").read_text())
    assert index["ignore"] == ["CONTACT"] and index["ignored"][0]["line"] == 10
    r = poise(*args, "--ignore", "CONTACT", "--json")        # the same kinds: resumed
    assert json.loads(r.stdout)["resumed"] == 2
    r = poise(*args, "--ignore", "CONTACT", "--ignore", "SENSOR", "--json")   # others: run
    assert json.loads(r.stdout)["resumed"] == 0
    r = poise("sweep", DECKS / "pendulum_multiturn.xml", "--set",
              "Force_SpringDamper[1].stiffness=1,2", "--out-dir", out, "--ignore", "CONTACT")
    assert r.returncode == 2 and "--ignore applies to Adams datasets" in r.stderr


def test_bench_ignore(tmp_path):
    adm = tmp_path / "c.adm"
    adm.write_text(CONTACT)
    args = ["bench", adm, "--tolerances", "1e-6", "--repeat", "1", "--json"]
    r = poise(*args)
    assert r.returncode == 3 and "CONTACT/7" in r.stderr
    r = poise(*args, "--ignore", "CONTACT", "--out", tmp_path / "rows.jsonl")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["ignored"] == [{"file": str(adm), "kind": "CONTACT", "line": 10,
                               "statement": "CONTACT/7"}]
    assert doc["rows"][0]["status"] == "converged" and doc["rows"][0]["error"] < 1e-6
    assert "poise bench: left out (--ignore): 1 CONTACT" in r.stderr
    row = json.loads((tmp_path / "rows.jsonl").read_text().splitlines()[0])
    assert row["ignored"][0]["statement"] == "CONTACT/7"
    r = poise("bench", DECKS / "pendulum_multiturn.xml", "--ignore", "CONTACT")
    assert r.returncode == 2 and "--ignore applies to Adams datasets" in r.stderr
