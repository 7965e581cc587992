"""``make bench`` / ``make bench-quick``: every benchmark suite, from the repository root.

    python -m benchmarks [--out bench/results.jsonl] [--markdown docs/performance.md]
                         [--sizes 10,100,1000,10000] [--repeat 3] [--cli-repeat 7] [--quick]

Runs the hanging-chain and command-line benchmarks (:mod:`benchmarks.chain`), the expression
benchmark (:mod:`benchmarks.expr`), the work-precision, peer and scaling suites
(:mod:`benchmarks.suite`), the time-to-fail table (:mod:`benchmarks.failfast`), the
stable-equilibria table (:mod:`benchmarks.stable`) and the quasi-static path tables
(:mod:`benchmarks.singular`, :mod:`benchmarks.frame_error`), then writes the JSON lines and the
markdown report.
The benchmarks are not part of the installed package.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from benchmarks import adm as bench_adm
from benchmarks import expr as bench_expr
from benchmarks import failfast as bench_failfast
from benchmarks import frame_error as bench_frame_error
from benchmarks import singular as bench_singular
from benchmarks import stable as bench_stable
from benchmarks.chain import (SIZES, SMALL_DECK, _pf, _s, bench_chain, bench_cli,
                              machine_info, render_markdown, targets)
from benchmarks.suite import run as run_issue7


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks",
                                 description="Run the poise benchmarks (make bench).")
    ap.add_argument("--out", default="bench/results.jsonl", help="JSON lines output")
    ap.add_argument("--markdown", default=None, help="markdown report (docs/performance.md)")
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)), help="chain sizes, comma-separated")
    ap.add_argument("--repeat", type=int, default=3, help="runs per chain size (fresh processes)")
    ap.add_argument("--cli-repeat", type=int, default=7, help="runs per command-line benchmark")
    ap.add_argument("--no-cli", action="store_true", help="skip the command-line benchmarks")
    ap.add_argument("--quick", action="store_true",
                    help="issue-7 suites with a reduced ladder and sizes (make bench-quick)")
    ap.add_argument("--no-adm", action="store_true",
                    help="skip the Adams dataset reading benchmark (issue 23)")
    ap.add_argument("--no-expr", action="store_true",
                    help="skip the expression benchmark (issue 3)")
    ap.add_argument("--no-wp", action="store_true",
                    help="skip the issue-7 suites (work-precision, peer, scaling)")
    ap.add_argument("--no-stable", action="store_true",
                    help="skip the stable-equilibria table (MKEAM, --require-stable; also "
                         "skipped with --no-wp)")
    ap.add_argument("--stable-only", action="store_true",
                    help="run only the stable-equilibria table")
    ap.add_argument("--no-failfast", action="store_true",
                    help="skip the time-to-fail table (failing decks vs healthy ones)")
    ap.add_argument("--failfast-only", action="store_true",
                    help="run only the time-to-fail table")
    ap.add_argument("--no-path", action="store_true",
                    help="skip the quasi-static path tables (issue 22: time to a singular "
                         "configuration, reported vs true frame error; also skipped with "
                         "--no-wp)")
    ap.add_argument("--path-only", action="store_true",
                    help="run only the quasi-static path tables")
    args = ap.parse_args(argv)
    root = Path(__file__).resolve().parents[1]
    machine = machine_info()
    results = []
    only = args.stable_only or args.failfast_only or args.path_only
    if only:
        args.sizes, args.no_cli, args.no_expr, args.no_wp = "", True, True, True
        args.no_adm = True
    with tempfile.TemporaryDirectory(prefix="poise-bench-") as td:
        tmp = Path(td)
        for n in [int(x) for x in args.sizes.split(",") if x.strip()]:
            r = bench_chain(n, max(1, args.repeat), tmp)
            print(f"chain N={n}: parse {_s(r['parse_s']['median'])} s, compile "
                  f"{_s(r['compile_s']['median'])} s, solve {_s(r['solve_s']['median'])} s, "
                  f"{r['iterations']} iterations, {r['status']}", file=sys.stderr)
            results.append(r)
        if not args.no_cli and (root / SMALL_DECK).exists():
            for r in bench_cli(max(1, args.cli_repeat), tmp, root):
                print(f"{r['command']}: {_s(r['wall_s']['median'])} s", file=sys.stderr)
                results.append(r)
        wp_md, wp_targets = [], []
        if not args.no_expr:    # issue 3: 10 000 expression-based forces
            rx = bench_expr.bench_expressions()
            print(f"expressions n={rx['n']}: compile {_s(rx['compile_s']['median'])} s, "
                  f"evaluate {1e3 * rx['eval_s']['median']:.2f} ms", file=sys.stderr)
            results.append(rx)
            wp_md.append(bench_expr.markdown(rx))
            wp_targets += bench_expr.targets(rx)
        if not args.no_adm:     # issue 23: a 2,500-statement Adams dataset read and checked
            ra = bench_adm.bench_adm(tmp)
            print(f"adm {ra['statements']} statements: check {_s(ra['check_s']['median'])} s",
                  file=sys.stderr)
            results.append(ra)
            wp_md.append(bench_adm.markdown(ra))
            wp_targets += bench_adm.targets(ra)
        if not args.no_wp:      # issue 7: work-precision, peer, scaling (benchmarks)
            other = ("expressions", "adm_read_check")
            wp_rows, md7, t7 = run_issue7(root, tmp, [r for r in results
                                                       if r.get("bench") not in other],
                                          quick=args.quick)
            wp_md += md7
            wp_targets += t7
        st_rows = []
        if not args.no_failfast and (args.failfast_only or not only):
            # time to fail: failing decks against their healthy counterparts
            ff_rows, ff_md, ff_t = bench_failfast.run(
                tmp, log=lambda m: print(m, file=sys.stderr, flush=True), quick=args.quick)
            st_rows += ff_rows
            wp_md += ff_md
            wp_targets += ff_t
        if args.path_only or not (only or args.no_path or args.no_wp):
            # issue 22: singular configurations, frame error bounds (long suites, like wp)
            for table in (bench_singular, bench_frame_error):
                rows_p, p_md, p_t = table.run(
                    tmp, log=lambda m: print(m, file=sys.stderr, flush=True), quick=args.quick)
                st_rows += rows_p
                wp_md += p_md
                wp_targets += p_t
        if args.stable_only or not (only or args.no_stable or args.no_wp):
            # stable equilibria: MKEAM and --require-stable vs FIM_S (a long suite, like wp)
            rows_s, st_md, st_t = bench_stable.run(
                tmp, log=lambda m: print(m, file=sys.stderr, flush=True), quick=args.quick)
            st_rows += rows_s
            wp_md += st_md
            wp_targets += st_t
    if args.out:
        p = Path(args.out)
        p.parent.mkdir(parents=True, exist_ok=True)
        with p.open("w") as f:
            for r in results:
                f.write(json.dumps(dict(r, machine=machine), sort_keys=True) + "\n")
            for r in st_rows:
                f.write(json.dumps(dict(r, machine=machine), sort_keys=True, default=float) + "\n")
            for r in wp_rows if not args.no_wp else []:
                f.write(json.dumps(dict(r, machine=machine), sort_keys=True, default=float) + "\n")
    if args.markdown:
        p = Path(args.markdown)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(render_markdown(results, machine) + "\n" + "\n".join(wp_md))
    for name, lim, meas, ok in targets(results) + wp_targets:
        print(f"{_pf(ok):4s} {name}: {meas} (target {lim})", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
