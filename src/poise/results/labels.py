"""Labels of the element groups of a results file, and what each request channel is.

Every group with ids (``joints/id``, ``forces/id``, ``requests/id``, ... in ``/model`` and in
each analysis) gets ``<group>/label``: the deck element's ``label`` attribute, found by its
tag and id (empty when it has none). Requests also get ``requests/type``,
``requests/channel`` (the name of each of the 8 channels) and ``requests/channel_units``
(each channel's unit in the deck's units), declared in :mod:`poise.results.schema_items`.
Labels are kept per tag as two arrays (sorted ids, labels), not as one Python object per
element: objects made while the parsed deck is alive fill the holes between its objects, and
then hold its memory pages through the whole solve.
"""
from __future__ import annotations

import numpy as np

from poise.elements.registry import output_groups
from poise.results.schema import REQUEST_CHANNELS, element_groups, unit_string

_BODY_TAGS = ("Body_Rigid", "Body_Point")


class Labeller:
    """Labels of one deck (``spec``), built once, for ``model``'s output groups."""

    def __init__(self, spec, units: str = ""):
        self.units = units
        self.group_tags = {"bodies": _BODY_TAGS, **output_groups()}   # element registry
        self.requests: dict[int, object] = {}
        rows: dict[str, tuple[list, list]] = {}
        for e in spec.model:
            if e.tag == "Reference_Marker":      # no output group: 3 per body, kept for nothing
                continue
            lab = e.attrs.get("label", "") or ""
            if e.tag == "Post_Request":
                lab = lab or e.attrs.get("comment", "") or ""     # a request's comment labels it
                self.requests.setdefault(e.id, e)
            if isinstance(e.id, int):
                ids, labs = rows.setdefault(e.tag, ([], []))
                ids.append(e.id)
                labs.append(str(lab))
        #: tag -> (sorted ids, their labels): the first element of a (tag, id) wins
        self.by_tag: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for tag, (ids, labs) in rows.items():
            u, first = np.unique(np.asarray(ids, np.int64), return_index=True)
            self.by_tag[tag] = (u, np.asarray(labs, dtype=str)[first])

    def label(self, tag: str, i: int) -> str | None:
        """The label of element ``(tag, i)`` ("" without one), or None: no such element."""
        hit, labs = self._find(tag, np.asarray([i], np.int64))
        return str(labs[0]) if hit[0] else None

    def _find(self, tag: str, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Which of ``ids`` are elements of ``tag`` (a mask) and their labels (masked rows)."""
        got = self.by_tag.get(tag)
        if got is None or not len(ids):
            return np.zeros(len(ids), bool), np.zeros(0, str)
        tid, tlab = got
        pos = np.minimum(np.searchsorted(tid, ids), len(tid) - 1)
        hit = tid[pos] == ids
        return hit, tlab[pos[hit]]

    def _tags(self, g: str, datasets: dict, model, n: int) -> list:
        """Candidate tags of each of the ``n`` rows of group ``g``."""
        t = datasets.get(f"{g}/tag")
        if t is None:
            o = (getattr(model, "outputs", None) or {}).get(g)
            t = None if o is None else o.get("tag")
        if t is not None:
            t = np.asarray(t)
            return [(str(x),) for x in (np.broadcast_to(t, (n,)) if t.ndim == 0 else t)]
        return [self.group_tags.get(g) or ()] * n

    def datasets(self, datasets: dict, model=None) -> dict:
        """The label (and request) datasets ``datasets`` lacks."""
        out = {}
        for g in element_groups():
            ids = datasets.get(f"{g}/id")
            if ids is None or f"{g}/label" in datasets:
                continue
            ids = np.asarray(ids).ravel().astype(np.int64)
            tags = self._tags(g, datasets, model, len(ids))
            labels = self._labels(ids, tags)
            out[f"{g}/label"] = np.asarray(labels, dtype=str) if labels else np.zeros(0, str)
            if g == "requests" and "requests/type" not in datasets:
                out.update(self._request_datasets(ids.tolist()))
        return out

    def _labels(self, ids: np.ndarray, tags: list) -> list:
        """The label of each row (id, candidate tags): the first candidate tag with an element
        of that id gives it, "" when none has one."""
        rows: dict[tuple, list] = {}
        for k, ts in enumerate(tags):
            rows.setdefault(ts, []).append(k)
        labels = [""] * len(ids)
        for ts, at in rows.items():
            left = np.asarray(at, np.int64)
            for t in ts:
                hit, labs = self._find(t, ids[left])
                for k, lab in zip(left[hit].tolist(), labs.tolist()):
                    labels[k] = lab
                left = left[~hit]
        return labels

    def _request_datasets(self, ids: list) -> dict:
        types, names, units = [], [], []
        for i in ids:
            el = self.requests.get(i)
            t = str(el.attrs.get("type", "EXPRESSION") if el is not None else "").upper()
            ch, un = REQUEST_CHANNELS.get(t, REQUEST_CHANNELS["EXPRESSION"])
            types.append(t)
            names.append(list(ch))
            units.append([unit_string(u, self.units) if u else "" for u in un])
        R = len(ids)
        return {"requests/type": np.asarray(types, dtype=str).reshape(R),
                "requests/channel": np.asarray(names, dtype=str).reshape(R, 8),
                "requests/channel_units": np.asarray(units, dtype=str).reshape(R, 8)}
