"""Decks as modelling tools export them: elements without effect on statics (controls plant
inputs and outputs, user output routines, linear-analysis settings, string data) and requests of
types poise does not compute are accepted with one warning per kind (with the count), exit 0; a
request's ``comment`` labels it when it has no ``label``."""
import json
import subprocess
import sys

import h5py
import numpy as np

from poise.app.api import run_deck

from support.paths import DECKS

EXTRA = """
    <Reference_Variable id="5" type="EXPRESSION" expr="DX(202,101)"/>
    <Control_PlantInput id="1" label="Torque in" num_element="1" variable_id_list="5"/>
    <Control_PlantInput id="2" num_element="1" variable_id_list="5" hold_order="1"/>
    <Control_PlantOutput id="1" num_element="1" variable_id_list="5" sampling_period="0."/>
    <Post_UserAPI/>
    <Reference_String id="3" string="road.rdf"/>
    <Post_Request id="3" type="USERSUB" usrsub_param_string="USER(1)" usrsub_fnc_name="REQSUB"/>
    <Post_Request id="4" script_name="req.py" interpreter="PYTHON" usrsub_fnc_name="REQSUB"
        usrsub_param_string="USER(2)"/>
    <Post_Request id="6" type="ORIENT" i_marker_id="202"/>
    <Post_Request id="7" type="MARKER_DISPLACEMENT" i_marker_id="202" comment="Tip"/>
    <Post_Request id="8" type="MARKER_DISPLACEMENT" i_marker_id="202" label="Tip label"
        comment="not used"/>
"""


def _deck(tmp_path):
    text = (DECKS / "pendulum_multiturn.xml").read_text()
    text = text.replace("</Model>", EXTRA + "  </Model>")
    text = text.replace('<Simulate analysis_type="Static"/>',
                        '<Param_Linear/><Simulate analysis_type="Static"/>')
    p = tmp_path / "tool.xml"
    p.write_text(text)
    return p, text


def _line(text, needle):
    return 1 + text.split(needle)[0].count("\n")


def test_no_effect_elements_warn_once_per_kind(tmp_path):
    p, text = _deck(tmp_path)
    run = run_deck(str(p))
    assert run.analyses[0].converged
    w = [str(x) for x in run.warnings]
    l1, l2 = _line(text, '<Control_PlantInput id="1"'), _line(text, '<Control_PlantInput id="2"')
    plant_in = [x for x in w if "<Control_PlantInput" in x]
    assert plant_in == [f"{p}:{l1}: <Control_PlantInput id=1>: controls plant inputs "
                        "(linearisation and co-simulation; PINVAL reads them): no effect on "
                        f"statics; 2 <Control_PlantInput> elements ignored (lines {l1}, {l2})"]
    for tag in ("Control_PlantOutput", "Post_UserAPI", "Reference_String", "Param_Linear"):
        assert sum(f"<{tag}" in x and "no effect on statics; 1" in x for x in w) == 1, tag
    user = [x for x in w if "type USERSUB" in x]
    assert len(user) == 1 and "2 requests skipped" in user[0]
    assert sum("type ORIENT" in x and "1 request skipped" in x for x in w) == 1
    d = run.analyses[0].datasets
    assert list(d["requests/id"]) == [7, 8]               # the computed requests only
    np.testing.assert_allclose(d["requests/values"][-1, 0, 1:4],
                               d["requests/values"][-1, 1, 1:4])


def test_cli_exit_0_and_comment_labels_the_request(tmp_path):
    p, _ = _deck(tmp_path)
    out = tmp_path / "o.h5"
    r = subprocess.run([sys.executable, "-m", "poise_cli.main", "solve", str(p), "-o", str(out),
                        "--json"], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    js = json.loads(r.stdout)
    assert js["status"] == "converged" and len(js["warnings"]) == 7
    assert r.stderr.count("warning:") == 7
    with h5py.File(out) as f:
        labels = [x.decode() for x in f["analysis_000/requests/label"][:]]
    assert labels == ["Tip", "Tip label"]
