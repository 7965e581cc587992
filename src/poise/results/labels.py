"""Labels of the element groups of a results file, and what each request channel is.

Every group with ids (``joints/id``, ``forces/id``, ``requests/id``, ... in ``/model`` and in
each analysis) gets ``<group>/label``: the deck element's ``label`` attribute, found by its
tag and id (empty when it has none). Requests also get ``requests/type``,
``requests/channel`` (the name of each of the 8 channels) and ``requests/channel_units``
(each channel's unit in the deck's units), declared in :mod:`poise.results.schema_items`.
One dict lookup per row: a model with thousands of elements costs milliseconds.
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
        self.by_key: dict[tuple, str] = {}
        self.requests: dict[int, object] = {}
        for e in spec.model:
            if e.tag == "Reference_Marker":      # no output group: 3 per body, kept for nothing
                continue
            lab = e.attrs.get("label", "") or ""
            if e.tag == "Post_Request":
                lab = lab or e.attrs.get("comment", "") or ""     # a request's comment labels it
                self.requests.setdefault(e.id, e)
            self.by_key.setdefault((e.tag, e.id), str(lab))

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
            ids = [int(i) for i in np.asarray(ids).ravel()]
            tags = self._tags(g, datasets, model, len(ids))
            labels = []
            for i, ts in zip(ids, tags):
                lab = ""
                for t in ts:
                    lab = self.by_key.get((t, i))
                    if lab is not None:
                        break
                labels.append(lab or "")
            out[f"{g}/label"] = np.asarray(labels, dtype=str) if labels else np.zeros(0, str)
            if g == "requests" and "requests/type" not in datasets:
                out.update(self._request_datasets(ids))
        return out

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
