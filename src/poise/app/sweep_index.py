"""A sweep's ``--output`` variables and its index (``OUT_DIR/index.csv`` and ``index.json``).

Outputs ``group[id].dataset`` (``bodies[2].position``, ``joints[1].force``,
``requests[1].values``, ...) name a per-element dataset of the results schema; the sweep file
keeps it at every frame, the index the last frame flattened (``bodies[2].position[0]`` ...
``[2]``), with its unit in the CSV header. The index is written from the finished sweep file,
a block of rows at a time (memory stays bounded whatever the number of cases): one row per
case, keys :data:`INDEX_KEYS` with the parameters after ``case`` and the output columns last.
"""
from __future__ import annotations

import csv
import json
import math
import re

import numpy as np

from poise.app.batch import sanitize
from poise.app.chunks import Output
from poise.core.atomic import atomic_output
from poise.core.errors import UsageError
from poise.elements.registry import output_groups as registry_output_groups
from poise.results.schema import REQUEST_CHANNELS, element_outputs, lookup, unit_string
from poise.results.sweepfile import read_rows

INDEX_VERSION = 1
INDEX_KEYS = ("case", "file", "status", "exit_code", "iterations", "wall_time", "imbalance",
              "imbalance_analysis", "imbalance_frame", "error", "stability_class",
              "stability_analysis", "stability_frame", "n_negative", "n_zero",
              "stability_modes", "modes", "resumed", "message", "ignored")
#: index column -> sweep file variable, where they differ
_VARIABLE = {"stability_class": "stability"}
#: index columns that are no variable of the sweep file
_NOT_STORED = ("case", "resumed", "ignored")
_INT_COLUMNS = ("exit_code", "iterations", "imbalance_analysis", "imbalance_frame",
                "stability_analysis", "stability_frame", "n_negative", "n_zero")

_OUT = re.compile(r"^\s*([a-z_]+)\s*\[\s*(-?\d+)\s*\]\s*\.\s*([A-Za-z_][A-Za-z0-9_]*)\s*$")


def output_groups() -> dict:
    """Output group -> deck tags whose ids it holds (for checking ``--output`` ids; None: any
    tag): the bodies and every group an element type declares
    (:func:`poise.elements.registry.output_groups`) whose per-element datasets the results
    schema declares."""
    declared = element_outputs()
    groups = {"bodies": ("Body_Rigid", "Body_Point"), **registry_output_groups()}
    return {g: tags for g, tags in groups.items() if g in declared}


def parse_outputs(spec, outputs) -> list[tuple[str, str, int, str]]:
    """``bodies[2].position`` -> (text, group, id, dataset); ids checked against the deck."""
    out = []
    for text in outputs or ():
        m = _OUT.match(text)
        groups = output_groups()
        if not m or m.group(1) not in groups:
            raise UsageError(f"--output {text!r}: expected group[id].dataset with group one of "
                             f"{', '.join(groups)}, e.g. bodies[2].position")
        g, i, ds = m.group(1), int(m.group(2)), m.group(3)
        known = element_outputs()[g]
        if ds not in known:
            import difflib
            near = difflib.get_close_matches(ds, known, n=1)
            raise UsageError(f"--output {text!r}: {g} has no dataset {ds!r}"
                             + (f"; did you mean {g}[{i}].{near[0]}?" if near else "")
                             + f" ({g} datasets: {', '.join(known)})")
        tags = groups[g]
        if tags and not any(e.tag in tags and e.id == i for e in spec.model):
            raise UsageError(f"--output {text!r}: the deck has no {'/'.join(tags)} id={i}")
        canon = f"{g}[{i}].{ds}"
        if canon in [o[0] for o in out]:
            raise UsageError(f"--output {canon!r} is given twice")
        out.append((canon, g, i, ds))
    return out


def source_item(g: str, ds: str):
    """The results declaration of ``<g>/<ds>`` (an analysis dataset ``(F, n, ...)``)."""
    return lookup("analysis", "dataset", f"{g}/{ds}")


def outputs_of(parsed) -> tuple[Output, ...]:
    """:class:`~poise.app.chunks.Output` of each parsed ``--output``, with its trailing shape."""
    out = []
    for text, g, i, ds in parsed:
        it = source_item(g, ds)
        out.append(Output(text, g, i, ds, tuple(int(d) for d in it.shape[2:]),
                          "f" if it.dtype == "float" else "i"))
    return tuple(out)


def output_units(spec, outputs) -> dict:
    """``{column: unit}`` of the ``--output`` columns in the deck's units (``"mm"``, ``"N"``):
    one per output from the results schema, one per channel for ``requests[i].values``; and
    ``wall_time`` in seconds. Columns of a dataset without one unit are left out."""
    from poise.model.compile import unit_info     # lazy: compiling is the workers' business
    units = unit_info(spec)[1]
    out = {"wall_time": "s"}
    for text, g, i, ds in outputs:
        if (g, ds) == ("requests", "values"):
            el = next((e for e in spec.model if e.tag == "Post_Request" and e.id == i), None)
            t = str(el.attrs.get("type", "EXPRESSION") if el is not None else "").upper()
            chans = REQUEST_CHANNELS.get(t, REQUEST_CHANNELS["EXPRESSION"])[1]
            out.update({f"{text}[{k}]": unit_string(u, units) for k, u in enumerate(chans) if u})
            continue
        it = lookup("analysis", "dataset", f"{g}/{ds}")
        if it is None or not it.unit or it.unit == "mixed":
            continue
        u = unit_string(it.unit, units)
        n = 1
        for d in it.shape[2:]:
            n *= d if isinstance(d, int) else 0
        out.update({text: u} if n == 1 else {f"{text}[{k}]": u for k in range(n)})
    return out


def output_columns(outputs, values: dict) -> list[tuple[str, np.ndarray]]:
    """``[(column, values (rows,))]``: each output's last frame, flattened (``[k]``)."""
    cols = []
    for o in outputs:
        arr = np.asarray(values[o.text])
        last = arr[:, -1] if arr.ndim >= 2 and arr.shape[1] else \
            np.full((len(arr), *o.trailing), np.nan)
        flat = last.reshape(len(arr), -1)
        if flat.shape[1] == 1:
            cols.append((o.text, flat[:, 0]))
        else:
            cols.extend((f"{o.text}[{k}]", flat[:, k]) for k in range(flat.shape[1]))
    return cols


def index_keys(params, outputs) -> list[str]:
    """The index columns: ``case``, the parameters, :data:`INDEX_KEYS`, the output columns."""
    one = {o.text: np.zeros((1, 1, *o.trailing)) for o in outputs}
    return ["case", *[p.key for p in params], *INDEX_KEYS[1:],
            *[c for c, _ in output_columns(outputs, one)]]


def index_rows(sweep_file: str, params, outputs, resumed: np.ndarray, ignored: str,
               done: np.ndarray, block: int = 4096):
    """The index rows (dicts, JSON-ready) of the finished cases ``done`` of ``sweep_file``,
    in case order, read ``block`` cases at a time."""
    n = len(done)
    stored = [c for c in INDEX_KEYS if c not in _NOT_STORED]
    names = [_VARIABLE.get(c, c) for c in stored]
    present = _present(sweep_file, names)
    for a in range(0, n, block):
        b = min(n, a + block)
        sel = np.nonzero(done[a:b])[0]
        if not len(sel):
            continue
        have = read_rows(sweep_file, a, b, ["case", *[p.key for p in params],
                                            *present,
                                            *[o.text for o in outputs]])
        outs = output_columns(outputs, {o.text: have[o.text] for o in outputs})
        for j in sel:
            row = {"case": int(have["case"][j])}
            row.update({p.key: _value(have[p.key][j]) for p in params})
            for c, v in zip(stored, names):
                row[c] = _cell_value(c, have.get(v, [None] * (b - a))[j])
            row["resumed"] = bool(resumed[a + j])
            row["ignored"] = ignored
            row.update({c: _value(v[j]) for c, v in outs})
            yield row


def _present(path: str, names) -> list[str]:
    import h5py
    with h5py.File(path, "r") as f:
        return [x for x in names if x in f]


def _value(v):
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def _cell_value(column: str, v):
    v = _value(v)
    if column == "modes":
        return json.loads(v) if v else []
    if column == "file":
        return v or None
    if column in _INT_COLUMNS and v == -1 and column != "exit_code":
        return None
    if column in ("stability_class",) and v == "":
        return None
    return v


def write_index(rows, path_stem: str, keys: list[str], head: dict, units: dict) -> None:
    """``<path_stem>.csv`` and ``<path_stem>.json`` (``{**head, "units": ..., "rows": [...]}``)
    from the iterable ``rows``, streamed, each atomically (a failed write: ``OutputError``).
    The CSV header says ``column [unit]``; lists are JSON in a CSV cell, None is empty."""
    units = {k: u for k, u in (units or {}).items() if k in keys and u}
    head = {**head, **({"units": units} if units else {})}
    with atomic_output(f"{path_stem}.csv") as tmp_csv, open(tmp_csv, "w", newline="") as fc, \
            atomic_output(f"{path_stem}.json") as tmp_js, open(tmp_js, "w") as fj:
        w = csv.writer(fc)
        w.writerow([f"{k} [{units[k]}]" if k in units else k for k in keys])
        text = json.dumps(sanitize(head), indent=1)
        fj.write(text[:-2] + (',\n "rows": [' if head else '{\n "rows": ['))
        first = True
        for r in rows:
            w.writerow(["" if r.get(k) is None else json.dumps(r[k], separators=(",", ":"))
                        if isinstance(r.get(k), (list, dict)) else r.get(k) for k in keys])
            fj.write(("\n  " if first else ",\n  ")
                     + json.dumps(sanitize({k: r.get(k) for k in keys}), allow_nan=False))
            first = False
        fj.write("\n ]\n}\n")
