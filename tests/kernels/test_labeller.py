"""The labeller's per-tag arrays give what a (tag, id) -> label dict gave: the first element of
a (tag, id) wins, the first candidate tag with an element of that id labels a row, rows with no
element get "" and elements without an id are never matched."""
from types import SimpleNamespace

import numpy as np

from poise.results.labels import Labeller


def _el(tag, id, label=None, **attrs):
    if label is not None:
        attrs["label"] = label
    return SimpleNamespace(tag=tag, id=id, attrs=attrs)


def _labeller():
    spec = SimpleNamespace(model=[
        _el("Body_Rigid", 30, "Crank"), _el("Body_Rigid", 2, "Ground"),
        _el("Body_Rigid", 30, "Duplicate"),             # the first (tag, id) wins
        _el("Body_Point", 7, "Point mass"), _el("Body_Rigid", 7),   # no label: ""
        _el("Force_Gravity", None, "Gravity"),           # no id: never matched
        _el("Reference_Marker", 2, "Marker"),            # markers are not labelled
    ])
    return Labeller(spec)


def test_labels_by_tag_and_id():
    lab = _labeller()
    assert lab.label("Body_Rigid", 30) == "Crank"
    assert lab.label("Body_Rigid", 7) == ""
    assert lab.label("Body_Rigid", 8) is None
    assert lab.label("Reference_Marker", 2) is None
    assert lab.label("Force_Gravity", 0) is None


def test_rows_take_the_first_candidate_tag_with_that_id():
    lab = _labeller()
    ids = np.array([30, 2, 7, 99, 7])
    tags = [("Body_Rigid", "Body_Point")] * 3 + [("Body_Rigid",), ("Body_Point", "Body_Rigid")]
    assert lab._labels(ids, tags) == ["Crank", "Ground", "", "", "Point mass"]


def test_group_datasets_get_labels():
    lab = _labeller()
    out = lab.datasets({"bodies/id": np.array([2, 30, 5])})
    assert out["bodies/label"].tolist() == ["Ground", "Crank", ""]
