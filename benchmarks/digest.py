"""Results digest: solve every example deck with one source tree, compare two such runs bitwise.

A refactoring that must not change answers is checked by solving the example decks
(``decks/*.xml``, ``decks/bench/*.xml``, ``decks/adm/*`` when present) with the tree before and
the tree after, then comparing every dataset and attribute of the results files bit for bit,
except the ``/timings`` attributes and the version / provenance attributes::

    python -m benchmarks.digest solve --src /path/to/old/src --out /tmp/old
    python -m benchmarks.digest solve --src src --out /tmp/new
    python -m benchmarks.digest compare /tmp/old /tmp/new
    python -m benchmarks.digest compare --answers /tmp/old /tmp/new

With ``--answers`` the comparison is of answers, not bits (a change of algorithm that alters
last bits and iterates): exit codes, refusals and every non-float value outside the histories
must be identical (statuses, verdicts, stability classes, mode counts, redundant equations,
warnings, labels), every float outside the histories must agree within ``ANSWER_RTOL`` times its
dataset's largest magnitude, and the frames' residual measures only need the same convergence
verdicts. The histories (per-iteration rows, integrator steps, MKEAM iterates, ``/counts``) are
not answers: the decks whose iteration counts changed are listed with the counts.

``solve`` runs ``poise solve`` (``--allow-user-code``) in a fresh process per deck with the
given ``src`` (and its sibling ``cli``) first on ``PYTHONPATH``; a deck that exits 3 or 4 keeps
its stderr as ``<name>.err`` so that refusals are compared too.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: attributes whose values legitimately differ between two trees or two runs
#: ``--answers``: largest difference of a float answer, relative to its dataset's largest value
ANSWER_RTOL = 1e-9
#: ``--answers``: per-analysis objects that are histories of the solve, not answers
HISTORY = {"iterations", "iteration", "steps", "step", "mkeam_iterate"}
HISTORY_PATHS = {"frames/iterations", "frames/strategy_iterations", "mkeam/iterate_position",
                 "mkeam/iterate_orientation"}
#: ``--answers``: residual measures at the written state (round-off level, not answers)
RESIDUALS = {"frames/error", "frames/imbalance"}
SKIP_ATTRS = {"poise_version", "version", "provenance", "git_commit", "created", "host",
              "python_version", "numpy_version", "scipy_version", "platform", "command"}


def decks(root: Path) -> list[Path]:
    out = sorted((root / "decks").glob("*.xml")) + sorted((root / "decks" / "bench").glob("*.xml"))
    adm = root / "decks" / "adm"
    if adm.is_dir():
        out += sorted(p for p in adm.iterdir() if p.suffix in (".adm", ".acf", ".xml"))
    return out


def solve(src: Path, out: Path, only: str | None = None) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "ROOT").write_text(str(ROOT))       # the decks' tree: written into messages
    env = dict(os.environ, PYTHONPATH=f"{src}{os.pathsep}{src.parent / 'cli'}",
               POISE_QUIET="1")
    for deck in decks(ROOT):
        if only and only not in deck.name:
            continue
        name = (f"{deck.parent.name}__{deck.name}" if deck.parent.name != "decks"
                else deck.stem)
        h5 = out / f"{name}.h5"
        r = subprocess.run([sys.executable, "-c", "from poise_cli.main import main; main()",
                            "solve", str(deck), "-o", str(h5), "--allow-user-code", "-q"],
                           env=env, capture_output=True, text=True, cwd=deck.parent)
        (out / f"{name}.rc").write_text(f"{r.returncode}\n")
        if r.returncode not in (0, 1):
            (out / f"{name}.err").write_text(r.stderr.replace(str(ROOT), "ROOT"))
        print(f"{name}: exit {r.returncode}", flush=True)


def _attrs(obj) -> dict:
    """Attributes to compare: not version/provenance, not wall-clock times."""
    return {k: v for k, v in obj.attrs.items()
            if k not in SKIP_ATTRS and not k.endswith(("_wall_time", "_seconds"))}


def _plain(v, f, root=None):
    """``v`` with HDF5 object references (dimension scales) replaced by the names they point to
    in file ``f`` (references are file addresses, equal files have different ones) and the
    decks' tree ``root`` in text by ``ROOT`` (two checkouts solve the same decks)."""
    import h5py
    if isinstance(v, h5py.Reference):
        return f[v].name if v else None
    if isinstance(v, bytes):
        v = v.decode("utf-8", "replace")
    if isinstance(v, str):
        return v.replace(root, "ROOT") if root else v
    a = np.asarray(v)
    if a.dtype.names:                                    # REFERENCE_LIST: (dataset, dimension)
        return [tuple(_plain(x[n], f, root) for n in a.dtype.names) for x in a.ravel()]
    if a.dtype == object or a.dtype.kind in "SU":
        return [_plain(x, f, root) for x in a.ravel()] + [a.shape]
    return v


def _same(a, b, answers: bool = False) -> bool:
    if isinstance(a, list) or isinstance(b, list):
        return a == b
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype != b.dtype or a.shape != b.shape:
        return False
    if a.dtype.kind in "fc":
        return a.tobytes() == b.tobytes() or (answers and _close(a, b))
    return np.array_equal(a, b)


def _close(a: np.ndarray, b: np.ndarray) -> bool:
    """Floats equal within ``ANSWER_RTOL`` of the dataset's largest finite magnitude (the same
    non-finite entries in the same places)."""
    fa, fb = np.isfinite(a), np.isfinite(b)
    if not np.array_equal(fa, fb) or not np.array_equal(a[~fa], b[~fb], equal_nan=True):
        return False
    if not fa.any():
        return True
    scale = max(float(np.abs(a[fa]).max()), float(np.abs(b[fb]).max()))
    return bool(np.all(np.abs(a[fa] - b[fb]) <= ANSWER_RTOL * scale))


def _largest_difference(a, b) -> str:
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.shape != b.shape:
        return f"shapes {a.shape} != {b.shape}"
    f = np.isfinite(a) & np.isfinite(b)
    if not f.any():
        return "non-finite entries differ"
    d = float(np.abs(a[f] - b[f]).max())
    scale = max(float(np.abs(a[f]).max()), float(np.abs(b[f]).max()), 1e-300)
    return f"largest difference {d:.3g} ({d / scale:.3g} of the largest value)"


def _kind(name: str) -> str:
    """``--answers``: 'history', 'residual' or 'answer' for an object path."""
    parts = name.split("/")
    if parts[0] in ("timings", "counts"):
        return "history"
    if parts[0].startswith("analysis_") and len(parts) > 1:
        rel = "/".join(parts[1:])
        if parts[1] in HISTORY or rel in HISTORY_PATHS:
            return "history"
        if rel in RESIDUALS:
            return "residual"
    return "answer"


def compare_files(pa: Path, pb: Path, roots=(None, None), answers: bool = False,
                  notes: list | None = None) -> list[str]:
    """Differences between two results files (bitwise, or of answers with ``answers``; then
    changed iteration counts are appended to ``notes``)."""
    import h5py
    root_a, root_b = roots
    diffs = []
    with h5py.File(pa, "r") as fa, h5py.File(pb, "r") as fb:
        names_a, names_b = [], []
        fa.visit(names_a.append)
        fb.visit(names_b.append)
        if answers:
            names_a = [n for n in names_a if _kind(n) != "history"]
            names_b = [n for n in names_b if _kind(n) != "history"]
        if sorted(names_a) != sorted(names_b):
            diffs.append(f"objects differ: {sorted(set(names_a) ^ set(names_b))}")
        for name in [""] + sorted(set(names_a) & set(names_b)):
            oa, ob = (fa[name], fb[name]) if name else (fa, fb)
            if name.split("/")[0] == "timings":
                continue
            aa, ab = _attrs(oa), _attrs(ob)
            if sorted(aa) != sorted(ab):
                diffs.append(f"/{name}: attributes differ {sorted(set(aa) ^ set(ab))}")
            for k in set(aa) & set(ab):
                va, vb = _plain(aa[k], fa, root_a), _plain(ab[k], fb, root_b)
                if not _same(va, vb, answers):
                    diffs.append(f"/{name} attr {k}: {str(va)[:80]} != {str(vb)[:80]}")
            if not isinstance(oa, h5py.Dataset) or (answers and _kind(name) == "residual"):
                continue
            va, vb = _plain(oa[()], fa, root_a), _plain(ob[()], fb, root_b)
            if not _same(va, vb, answers):
                what = (_largest_difference(va, vb) if answers and not isinstance(va, list)
                        and np.asarray(va).dtype.kind in "fc" else "values differ")
                diffs.append(f"/{name}: {what}")
        if answers and notes is not None:
            for name in sorted(n for n in fa if n.startswith("analysis_")):
                key = f"{name}/frames/iterations"
                if key in fa and key in fb and not np.array_equal(fa[key][()], fb[key][()]):
                    ia, ib = fa[key][()], fb[key][()]
                    notes.append(f"{name}: iterations {int(ia.sum())} -> {int(ib.sum())}"
                                 f" over {len(ia)} frame(s)")
    return diffs


def compare(a: Path, b: Path, answers: bool = False) -> int:
    names = sorted({p.stem for p in a.glob("*.rc")} | {p.stem for p in b.glob("*.rc")})
    roots = tuple((p / "ROOT").read_text() if (p / "ROOT").exists() else None for p in (a, b))
    bad = bitwise = 0
    changed = []
    for n in names:
        d, notes = [], []
        ra, rb = a / f"{n}.rc", b / f"{n}.rc"
        if not (ra.exists() and rb.exists()):
            d.append("solved in one run only")
        elif ra.read_text() != rb.read_text():
            d.append(f"exit {ra.read_text().strip()} != {rb.read_text().strip()}")
        ea, eb = a / f"{n}.err", b / f"{n}.err"
        if ea.exists() != eb.exists() or (ea.exists() and _plain(ea.read_text(), None, roots[0])
                                          != _plain(eb.read_text(), None, roots[1])):
            d.append("stderr differs")
        ha, hb = a / f"{n}.h5", b / f"{n}.h5"
        if ha.exists() != hb.exists():
            d.append("results file in one run only")
        elif ha.exists():
            d += compare_files(ha, hb, roots, answers, notes)
            if answers and not d and compare_files(ha, hb, roots):
                bitwise += 1
        if notes:
            changed.append(f"{n}: " + "; ".join(notes))
        if d:
            bad += 1
            print(f"{n}: " + "; ".join(d[:4]) + (f" (+{len(d) - 4})" if len(d) > 4 else ""))
    if answers:
        for line in changed:
            print(f"iterations changed: {line}")
        print(f"digest (answers): {len(names)} decks, {bad} answer differences, "
              f"{len(changed)} with changed iteration counts, "
              f"{bitwise} with the same answers but different bits")
    else:
        print(f"digest: {len(names)} decks, {bad} differences")
    return 1 if bad else 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.digest", description=__doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("solve")
    s.add_argument("--src", type=Path, default=ROOT / "src")
    s.add_argument("--out", type=Path, required=True)
    s.add_argument("--only", default=None, help="decks whose file name contains this")
    c = sub.add_parser("compare")
    c.add_argument("a", type=Path)
    c.add_argument("b", type=Path)
    c.add_argument("--answers", action="store_true",
                   help="compare answers within tolerance, not bits (histories excluded)")
    args = ap.parse_args(argv)
    if args.cmd == "solve":
        solve(args.src.resolve(), args.out, args.only)
        return 0
    return compare(args.a, args.b, args.answers)


if __name__ == "__main__":
    sys.exit(main())
