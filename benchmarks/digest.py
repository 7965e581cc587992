"""Results digest: solve every example deck with one source tree, compare two such runs bitwise.

A refactoring that must not change answers is checked by solving the example decks
(``decks/*.xml``, ``decks/bench/*.xml``, ``decks/adm/*`` when present) with the tree before and
the tree after, then comparing every dataset and attribute of the results files bit for bit,
except the ``/timings`` attributes and the version / provenance attributes::

    python -m benchmarks.digest solve --src /path/to/old/src --out /tmp/old
    python -m benchmarks.digest solve --src src --out /tmp/new
    python -m benchmarks.digest compare /tmp/old /tmp/new

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


def _same(a, b) -> bool:
    if isinstance(a, list) or isinstance(b, list):
        return a == b
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype != b.dtype or a.shape != b.shape:
        return False
    if a.dtype.kind in "fc":
        return a.tobytes() == b.tobytes()
    return np.array_equal(a, b)


def compare_files(pa: Path, pb: Path, roots=(None, None)) -> list[str]:
    import h5py
    root_a, root_b = roots
    diffs = []
    with h5py.File(pa, "r") as fa, h5py.File(pb, "r") as fb:
        names_a, names_b = [], []
        fa.visit(names_a.append)
        fb.visit(names_b.append)
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
                if not _same(va, vb):
                    diffs.append(f"/{name} attr {k}: {str(va)[:80]} != {str(vb)[:80]}")
            if isinstance(oa, h5py.Dataset) and not _same(_plain(oa[()], fa, root_a),
                                                          _plain(ob[()], fb, root_b)):
                diffs.append(f"/{name}: values differ")
    return diffs


def compare(a: Path, b: Path) -> int:
    names = sorted({p.stem for p in a.glob("*.rc")} | {p.stem for p in b.glob("*.rc")})
    roots = tuple((p / "ROOT").read_text() if (p / "ROOT").exists() else None for p in (a, b))
    bad = 0
    for n in names:
        d = []
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
            d += compare_files(ha, hb, roots)
        if d:
            bad += 1
            print(f"{n}: " + "; ".join(d[:4]) + (f" (+{len(d) - 4})" if len(d) > 4 else ""))
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
    args = ap.parse_args(argv)
    if args.cmd == "solve":
        solve(args.src.resolve(), args.out, args.only)
        return 0
    return compare(args.a, args.b)


if __name__ == "__main__":
    sys.exit(main())
