"""What a sweep keeps from earlier runs: its journal of finished chunks and the last sweep file.

**Journal.** While a sweep runs, each finished chunk of cases is also written to
``OUT_DIR/.poise-sweep/part_<first case>_<pid>_<k>.npz`` (to a temporary name, then renamed:
a killed process leaves no half part). A part holds the chunk's rows as the sweep file stores
them, the cases' parameter values and a header (sweep hash, outputs, frames, the scripts the
cases read). The sweep file itself is written to a temporary file and renamed at the end, so a
killed sweep leaves the parts and the previous sweep file; the parts are removed once the new
sweep file is in place.

**Reuse.** A case of the new sweep is taken from the parts, else from the previous sweep file,
when the source has the same ``sweep_hash`` (deck, solver options, ``--ignore`` kinds, poise
version), the same frames, every requested output, the scripts it read unchanged, a finished
status (``converged``, ``failed``, ``invalid_deck``: an ``internal_error`` or ``io_error`` is
solved again, and so is an ``invalid_deck`` when user code is now allowed) and the same parameter values (the case number may differ: a longer range keeps
the cases solved before). With ``--per-case-files`` its file must exist too.
"""
from __future__ import annotations

import contextlib
import json
import os
from typing import Iterator

import numpy as np

from poise.app.batch import inputs_fresh
from poise.core.atomic import remove_stale_temps, temp_name
from poise.results.sweepfile import read_header, read_rows

PARTS = ".poise-sweep"
#: statuses a later sweep keeps (the others are solved again)
FINISHED = ("converged", "failed", "invalid_deck")
#: rows read from a previous sweep file at a time
BLOCK = 4096


def value_keys(params, columns: dict) -> list[str]:
    """One text per case identifying its parameter values (``columns``: ``{key: values}``)."""
    cols = [np.asarray(columns[p.key]).tolist() for p in params]
    return [json.dumps(list(v), default=str) for v in zip(*cols)] if cols else []


class Journal:
    """The parts of one sweep directory (module doc); ``header``: what a part must match."""

    def __init__(self, out_dir: str, header: dict):
        self.dir = os.path.join(out_dir, PARTS)
        self.header = header
        self.k = 0

    def add(self, rows: dict, values: dict) -> None:
        """Record a finished chunk: ``rows`` (sweep-file columns, ``case`` first) and the
        cases' parameter ``values`` (``{key: array}``)."""
        os.makedirs(self.dir, exist_ok=True)
        self.k += 1
        name = f"part_{int(np.min(rows['case'])):09d}_{os.getpid()}_{self.k}.npz"
        arrays = {f"v:{k}": _plain(v) for k, v in rows.items() if k != "input_files"}
        arrays.update({f"p:{k}": _plain(v) for k, v in values.items()})
        head = {**self.header, "input_files": rows.get("input_files") or None}
        arrays["header"] = np.asarray(json.dumps(head, sort_keys=True, default=str))
        target = os.path.join(self.dir, name)
        tmp = temp_name(target) + ".npz"
        try:
            with open(tmp, "wb") as f:
                np.savez(f, **arrays)
            os.replace(tmp, target)
        finally:
            with contextlib.suppress(OSError):
                os.unlink(tmp)

    def parts(self) -> Iterator[tuple[dict, dict, dict]]:
        """``(header, rows, values)`` of every readable part (unreadable ones are skipped)."""
        if not os.path.isdir(self.dir):
            return
        remove_stale_temps(self.dir)
        for name in sorted(os.listdir(self.dir)):
            if not (name.startswith("part_") and name.endswith(".npz")):
                continue
            try:
                with np.load(os.path.join(self.dir, name), allow_pickle=False) as z:
                    head = json.loads(str(z["header"]))
                    rows = {k[2:]: _objects(z[k]) for k in z.files if k.startswith("v:")}
                    values = {k[2:]: _objects(z[k]) for k in z.files if k.startswith("p:")}
            except (OSError, ValueError, KeyError, EOFError):
                continue
            yield head, rows, values

    def clear(self) -> None:
        if not os.path.isdir(self.dir):
            return
        for name in os.listdir(self.dir):
            with contextlib.suppress(OSError):
                os.unlink(os.path.join(self.dir, name))
        with contextlib.suppress(OSError):
            os.rmdir(self.dir)


def _plain(v) -> np.ndarray:
    arr = np.asarray(v)
    return arr.astype(str) if arr.dtype.kind == "O" else arr


def _objects(arr: np.ndarray) -> np.ndarray:
    return arr.astype(object) if arr.dtype.kind == "U" else arr


def _matches(head: dict, want: dict, outputs, allow_user_code: bool) -> bool:
    if head.get("sweep_hash") != want["sweep_hash"]:
        return False
    if int(head.get("n_frames", -1)) != int(want["n_frames"]):
        return False
    if not set(outputs) <= set(head.get("outputs") or ()):
        return False
    files = head.get("input_files")
    return not files or inputs_fresh({"input_files": files}, allow_user_code)


def _usable(rows: dict, out_dir: str, files: bool, allow_user_code: bool) -> np.ndarray:
    keep = [s for s in FINISHED if not (allow_user_code and s == "invalid_deck")]
    ok = np.isin(np.asarray(rows["status"], dtype=object), keep)
    if files:
        names = np.asarray(rows.get("file", np.full(len(ok), "", object)), dtype=object)
        ok &= np.array([bool(n) and os.path.isfile(os.path.join(out_dir, str(n)))
                        for n in names], bool)
    return ok


def reuse(journal: Journal, sweep_file: str, want: dict, params, keys: list[str], outputs,
          names, write, out_dir: str, files: bool = False, allow_user_code: bool = False
          ) -> np.ndarray:
    """Copy the reusable cases of the parts and of ``sweep_file`` into the new sweep file
    (``write(rows)``, rows in new case numbers) and return the mask of the cases so taken.
    ``want``: ``sweep_hash`` and ``n_frames`` of the new sweep; ``keys``: its cases' value
    texts (:func:`value_keys`); ``names``: the variables to copy."""
    where: dict[str, list[int]] = {}
    for i, k in enumerate(keys):
        where.setdefault(k, []).append(i)
    taken = np.zeros(len(keys), bool)

    def take(rows: dict, src_keys: list[str], files_read=None) -> None:
        ok = _usable(rows, out_dir, files, allow_user_code)
        src, dst = [], []
        for j, k in enumerate(src_keys):
            if ok[j]:
                for i in where.get(k, ()):
                    if not taken[i]:
                        src.append(j)
                        dst.append(i)
                        taken[i] = True
        if dst:
            sel = np.asarray(src, np.int64)
            out = {n: np.asarray(rows[n])[sel] for n in names if n in rows}
            out["case"] = np.asarray(dst, np.int64)
            if files_read:
                out["input_files"] = files_read
            write(out)

    for head, rows, values in journal.parts():
        if _matches(head, want, outputs, allow_user_code) and all(p.key in values
                                                                  for p in params):
            take(rows, value_keys(params, values), head.get("input_files"))
    head = read_header(sweep_file) if os.path.isfile(sweep_file) else None
    if head is not None and _matches(head, want, outputs, allow_user_code) \
            and all(p.key in head["variables"] for p in params) and not taken.all():
        n = int(head.get("n_cases", 0))
        have = [x for x in names if x in head["variables"]]
        for a in range(0, n, BLOCK):
            try:
                rows = read_rows(sweep_file, a, min(n, a + BLOCK),
                                 [*have, *[p.key for p in params]])
            except (OSError, KeyError, ValueError):
                break
            take(rows, value_keys(params, rows), head.get("input_files"))
    return taken
