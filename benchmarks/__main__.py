"""``make bench`` / ``make bench-quick``: every benchmark table, from the repository root.

    python -m benchmarks [--out bench/results.jsonl] [--markdown docs/performance.md]
                         [--only TABLE,...] [--skip TABLE,...] [--sizes 10,100,1000,10000]
                         [--repeat 3] [--cli-repeat 7] [--quick]

The tables are declared once, in :data:`TABLES` (name, what it measures, how to run it); every
table runs unless ``--only`` names others or ``--skip`` names it. A table's run returns a
:class:`Out`: summary records (rendered by :func:`benchmarks.chain.render_markdown`), extra JSON
rows, markdown sections and PASS/MISS targets. The JSON lines and the markdown report are
written at the end. The benchmarks are not part of the installed package.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from benchmarks.chain import (SIZES, SMALL_DECK, _pf, _s, bench_chain, bench_cli,
                              machine_info, render_markdown, targets)


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


@dataclass
class Out:
    """What one table produced: ``results`` (summary records, also read by later tables),
    ``rows`` (more JSON lines), ``md`` (markdown sections), ``targets`` ((name, limit,
    measured, ok) tuples)."""

    results: list = field(default_factory=list)
    rows: list = field(default_factory=list)
    md: list = field(default_factory=list)
    targets: list = field(default_factory=list)


@dataclass(frozen=True)
class Run:
    """What a table's run gets: the options, a scratch directory, the repository root and the
    summary records of the tables that ran before it."""

    args: argparse.Namespace
    tmp: Path
    root: Path
    results: list


def _chain(r: Run) -> Out:
    from benchmarks import floor
    out = Out()
    for n in [int(x) for x in r.args.sizes.split(",") if x.strip()]:
        reps = max(1, r.args.repeat)
        if n in floor.SIZES and not r.args.quick:
            reps = max(reps, floor.REPEAT)
        c = bench_chain(n, reps, r.tmp)
        _log(f"chain N={n}: parse {_s(c['parse_s']['median'])} s, compile "
             f"{_s(c['compile_s']['median'])} s, solve {_s(c['solve_s']['median'])} s, "
             f"{c['iterations']} iterations, {c['status']}")
        out.results.append(c)
    return out


def _cli(r: Run) -> Out:
    out = Out()
    if (r.root / SMALL_DECK).exists():
        for c in bench_cli(max(1, r.args.cli_repeat), r.tmp, r.root):
            _log(f"{c['command']}: {_s(c['wall_s']['median'])} s")
            out.results.append(c)
    return out


def _expr(r: Run) -> Out:
    from benchmarks import expr
    rx = expr.bench_expressions()
    _log(f"expressions n={rx['n']}: compile {_s(rx['compile_s']['median'])} s, "
         f"evaluate {1e3 * rx['eval_s']['median']:.2f} ms")
    return Out([rx], [], [expr.markdown(rx)], expr.targets(rx))


def _adm(r: Run) -> Out:
    from benchmarks import adm
    ra = adm.bench_adm(r.tmp)
    _log(f"adm {ra['statements']} statements: check {_s(ra['check_s']['median'])} s")
    return Out([ra], [], [adm.markdown(ra)], adm.targets(ra))


def _sweep(r: Run) -> Out:
    from benchmarks import sweep
    sw = sweep.run(r.tmp, r.root, (1000, 10_000) if r.args.quick else (1000, 100_000), log=_log)
    return Out(sw, [], sweep.markdown(sw), sweep.targets(sw))


def _wp(r: Run) -> Out:
    from benchmarks.suite import run as run_issue7
    other = ("expressions", "adm_read_check", "sweep", "sweep_chunk", "solve_process",
             "inprocess_solve")
    rows, md, t = run_issue7(r.root, r.tmp, [x for x in r.results if x.get("bench") not in other],
                             quick=r.args.quick)
    return Out([], rows, md, t)


def _rows_table(*modules: str) -> Callable[[Run], Out]:
    """A table made of modules whose ``run(tmp, log=, quick=)`` gives (rows, md, targets)."""
    def run(r: Run) -> Out:
        import importlib
        out = Out()
        for name in modules:
            rows, md, t = importlib.import_module(f"benchmarks.{name}").run(
                r.tmp, log=_log, quick=r.args.quick)
            out.rows += rows
            out.md += md
            out.targets += t
        return out
    return run


@dataclass(frozen=True)
class Table:
    name: str
    help: str
    run: Callable[[Run], Out]


TABLES = (
    Table("chain", "hanging chain: parse, compile, solve per size (--sizes)", _chain),
    Table("cli", "command-line runs of the small deck", _cli),
    Table("expr", "10,000 expression-based forces (issue 3)", _expr),
    Table("adm", "a 2,500-statement Adams dataset read and checked (issue 23)", _adm),
    Table("sweep", "sweeps of a small model, in-process solve (issue 25 §1)", _sweep),
    Table("wp", "work-precision, peers, scaling, the §2 floor (issue 7; reads chain's records)",
          _wp),
    Table("failfast", "time to fail: failing decks against healthy ones (issue 22)",
          _rows_table("failfast")),
    Table("path", "singular configurations and frame error of quasi-static paths (issue 22)",
          _rows_table("singular", "frame_error")),
    Table("stable", "stable equilibria: MKEAM and --require-stable against FIM_S",
          _rows_table("stable")),
)
NAMES = tuple(t.name for t in TABLES)


def _names(text: str | None, ap: argparse.ArgumentParser, option: str) -> set[str]:
    names = {x.strip() for x in (text or "").split(",") if x.strip()}
    bad = sorted(names - set(NAMES))
    if bad:
        ap.error(f"{option}: unknown table(s) {', '.join(bad)} (tables: {', '.join(NAMES)})")
    return names


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks", description="Run the poise benchmarks (make bench).",
        epilog="tables: " + "; ".join(f"{t.name}: {t.help}" for t in TABLES))
    ap.add_argument("--out", default="bench/results.jsonl", help="JSON lines output")
    ap.add_argument("--markdown", default=None, help="markdown report (docs/performance.md)")
    ap.add_argument("--only", default=None, metavar="TABLE,...",
                    help=f"run only these tables (of: {', '.join(NAMES)})")
    ap.add_argument("--skip", default=None, metavar="TABLE,...", help="skip these tables")
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)), help="chain sizes, comma-separated")
    ap.add_argument("--repeat", type=int, default=3, help="runs per chain size (fresh processes)")
    ap.add_argument("--cli-repeat", type=int, default=7, help="runs per command-line benchmark")
    ap.add_argument("--quick", action="store_true",
                    help="reduced ladders, sizes and sweeps (make bench-quick)")
    args = ap.parse_args(argv)
    only, skip = _names(args.only, ap, "--only"), _names(args.skip, ap, "--skip")
    chosen = [t for t in TABLES if (not only or t.name in only) and t.name not in skip]
    root = Path(__file__).resolve().parents[1]
    machine = machine_info()
    total = Out()
    with tempfile.TemporaryDirectory(prefix="poise-bench-") as td:
        for table in chosen:
            out = table.run(Run(args, Path(td), root, list(total.results)))
            total.results += out.results
            total.rows += out.rows
            total.md += out.md
            total.targets += out.targets
    if args.out:
        p = Path(args.out)
        p.parent.mkdir(parents=True, exist_ok=True)
        with p.open("w") as f:
            for r in total.results + total.rows:
                f.write(json.dumps(dict(r, machine=machine), sort_keys=True, default=float)
                        + "\n")
    if args.markdown:
        p = Path(args.markdown)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(render_markdown(total.results, machine) + "\n" + "\n".join(total.md))
    for name, lim, meas, ok in targets(total.results) + total.targets:
        print(f"{_pf(ok):4s} {name}: {meas} (target {lim})", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
