"""``poise check``: parse and compile a deck, report its structure; no solve."""
from __future__ import annotations

import dataclasses

import click

from poise.core.wording import plural
from poise_cli.errors import report_exception
from poise_cli.options import debug_option, ignore_option, json_option
from poise_cli.summary import print_json, sanitize


def _table(rows: list[list[str]], indent: str = "  ") -> list[str]:
    if not rows:
        return []
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return [indent + "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip() for r in rows]


def _s(v) -> str:
    return "" if v is None else str(v)


def format_report(rep) -> list[str]:
    lines = [f"deck: {rep.deck}"]
    lines.append(f"analyses: {len(rep.analyses)}")
    for i, a in enumerate(rep.analyses):
        n = a.get("n_frames")
        lines.append(f"  {i}: {_s(a.get('analysis_type'))} {_s(a.get('method'))}"
                     + ("" if n is None else f", {plural(n, 'frame')}"))
    lines.append(f"bodies: {len(rep.bodies)}")
    lines += _table([["id", "label", "kind", "mass"]] + [
        [_s(b.get("id")), _s(b.get("label")), _s(b.get("kind")), _s(b.get("mass"))]
        for b in rep.bodies]) if rep.bodies else []
    lines.append(f"constraints: {len(rep.constraints)} ({plural(rep.n_equations, 'equation')})")
    lines += _table([["tag", "id", "type", "equations", "line"]] + [
        [_s(c.get("tag")), _s(c.get("id")), _s(c.get("type")), _s(c.get("n_equations")),
         _s(c.get("line"))] for c in rep.constraints]) if rep.constraints else []
    lines.append(f"forces: {len(rep.forces)}")
    lines += _table([["tag", "id", "type", "line"]] + [
        [_s(f.get("tag")), _s(f.get("id")), _s(f.get("type")), _s(f.get("line"))]
        for f in rep.forces]) if rep.forces else []
    lines.append(f"coordinates: {rep.n_coordinates}")
    lines.append(f"constraint equations: {rep.n_equations}")
    lines.append(f"redundant equations: {rep.n_redundant}")
    lines += _table([["tag", "id", "equation", "line"]] + [
        [_s(r.get("tag")), _s(r.get("id")), _s(r.get("equation")), _s(r.get("line"))]
        for r in rep.redundant]) if rep.redundant else []
    users = list(getattr(rep, "user_routines", None) or [])
    if users:
        lines.append(f"user routines: {len(users)} (not run: poise check never executes deck "
                     "code; poise solve needs --allow-user-code)")
        lines += _table([["tag", "id", "script", "function", "line"]] + [
            [_s(u.get("tag")), _s(u.get("id")), _s(u.get("script")), _s(u.get("function")),
             _s(u.get("line"))] for u in users])
    if rep.dof is None:
        lines.append("degrees of freedom: unknown (the equations of user constraints are known "
                     "only by running their routines); without the user constraints: "
                     f"{_s(getattr(rep, 'dof_without_user_constraints', None))}")
    else:
        lines.append(f"degrees of freedom: {rep.dof}")
    lines.append("active effects: " + (", ".join(rep.active_effects) or "(none)"))
    return lines


@click.command(short_help="Validate a deck and print its structure (no solve).")
@click.argument("deck", type=click.Path(exists=True, dir_okay=False, readable=True))
@ignore_option
@json_option
@debug_option
def check(deck, ignore, as_json, debug):
    """Parse and compile DECK; print bodies, constraints, degrees of freedom, redundant
    equations and active effects without solving.

    Never runs deck code: Python user routines are listed (their scripts must lie inside the
    deck's directory) but not imported, and the elements they define are left out.

    Exit code 0 for a valid deck, 3 for an invalid one (every problem printed on stderr).
    """
    ctx = click.get_current_context()
    from poise_cli.streams import collected_warnings, guarded_stdout
    try:
        with guarded_stdout(), collected_warnings() as numeric:
            # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
            from poise.app.api import check_deck
            rep = check_deck(deck, **({"ignore": ignore} if ignore else {}))
    except (Exception, KeyboardInterrupt) as exc:
        code, info = report_exception(exc, debug=debug)
        if as_json:
            print_json({"deck": deck, "exit_code": code, **info})
        ctx.exit(code)
        return
    warnings = [str(w) for w in rep.warnings] + numeric
    for w in warnings:
        click.echo(f"warning: {w}", err=True)
    if as_json:
        data = dataclasses.asdict(rep) if dataclasses.is_dataclass(rep) else dict(vars(rep))
        data["warnings"] = warnings
        data["status"] = "valid"
        data["exit_code"] = 0
        print_json(sanitize(data))
    else:
        click.echo("\n".join(format_report(rep)))
    ctx.exit(0)
