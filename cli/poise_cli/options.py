"""Shared click options and option -> override mapping."""
from __future__ import annotations

import click

#: CLI option name -> ``Param_Static`` attribute name used as override key by poise.app.api.run_deck
OVERRIDE_KEYS = ("method", "max_num_iter", "max_imbalance", "max_error", "stability", "fallback",
                 "fallback_max_num_iter", "require_stable", "allow_neutral", "compliance_markers",
                 "compliance_method")

#: ``ctx.meta`` key of ``--fallback-budget`` (kept out of the commands' signatures)
_FALLBACK_BUDGET = "poise.fallback_max_num_iter"
#: Param_Static names of options kept out of the commands' signatures (``ctx.meta`` keys
#: ``poise.<name>``): the fallback budget and the compliance matrix options
_META = ("fallback_max_num_iter", "compliance_markers", "compliance_method")

METHODS = ("FIM_D", "FIM_S", "MKEAM")

#: smallest --max-imbalance / --max-error (poise.deck.schema.TOL_MIN; not imported: that module
#: is heavier than the CLI's start-up budget allows)
TOL_MIN = 1e-100

json_option = click.option(
    "--json", "as_json", is_flag=True,
    help="Print a machine-readable JSON summary on stdout.")

debug_option = click.option(
    "--debug", is_flag=True,
    help="Show full tracebacks for internal errors.")

user_code_option = click.option(
    "--allow-user-code", "allow_user_code", is_flag=True, default=False,
    help="Run the Python user routines (script_name) the deck names. Without it such a deck "
         "is refused (exit 3): decks may come from anywhere. Scripts must lie inside the "
         "deck's directory either way.")

ignore_option = click.option(
    "--ignore", "ignore", multiple=True, metavar="KIND",
    help="Adams datasets (.adm/.acf): leave out the statements of KIND poise cannot solve "
         "(CONTACT, FRICTION, SENSOR, GSE, USER for user subroutines, ...) instead of refusing "
         "the dataset; recorded in the results and on the summary lines. Repeatable.")

quiet_option = click.option(
    "-q", "--quiet", is_flag=True,
    help="Print nothing on stderr except errors (no summary lines, no warnings).")


class _Finite(click.FloatRange):
    """A float range that also refuses nan and inf (click's FloatRange lets nan through)."""

    def convert(self, value, param, ctx):
        import math
        v = super().convert(value, param, ctx)
        if not math.isfinite(v):
            self.fail(f"{value!r} is not a finite number.", param, ctx)
        return v


def _store_fallback_budget(ctx, param, value):
    if value is not None:
        ctx.meta[_FALLBACK_BUDGET] = value
    return value


def _store_compliance_markers(ctx, param, value):
    if value is not None:
        try:
            # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
            from poise.solvers.compliance import parse_markers
            ctx.meta["poise.compliance_markers"] = parse_markers(value)
        except ValueError as e:
            raise click.BadParameter(str(e)) from None
    return value


def _store_compliance_method(ctx, param, value):
    if value is not None:
        ctx.meta["poise.compliance_method"] = value.lower()
    return value


def solver_options(f):
    """The ``Param_Static`` overrides of ``poise solve`` (applied in reverse for help order)."""
    opts = [
        click.option("--method", type=click.Choice(METHODS, case_sensitive=False), default=None,
                     metavar="[" + "|".join(METHODS) + "]",
                     help="Equilibrium method (overrides the deck's Param_Static method). "
                          "Default FIM_D."),
        click.option("--max-num-iter", type=click.IntRange(min=1), default=None,
                     help="Maximum Newton iterations per frame."),
        click.option("--max-imbalance", type=_Finite(min=TOL_MIN),
                     default=None, help="Convergence tolerance on the force imbalance."),
        click.option("--max-error", type=_Finite(min=TOL_MIN), default=None,
                     help="Convergence tolerance on the (scaled) displacement step."),
        click.option("--stability", type=_Finite(min=0), default=None,
                     help="sqrt(stability) x mass matrix is added to the Jacobian only "
                          "(Param_Static stability)."),
        click.option("--no-fallback", "no_fallback", is_flag=True, default=False,
                     help="Do not run the fallback chain (larger stability, continuation, "
                          "MKEAM) when FIM_S fails."),
        click.option("--fallback-budget", type=click.IntRange(min=0), default=None,
                     expose_value=False, callback=_store_fallback_budget, metavar="N",
                     help="Units of work (Newton iterations, continuation steps, MKEAM "
                          "integration and descent steps) the fallback chain may spend on one "
                          "frame after plain Newton failed. Default: max_num_iter."),
        click.option("--require-stable", "require_stable", is_flag=True, default=None,
                     help="Static analyses succeed only at a stable equilibrium: FIM_S leaves "
                          "an unstable equilibrium along its negative modes and continues "
                          "downhill; otherwise exit 1 with status 'unstable'."),
        click.option("--allow-neutral/--no-allow-neutral", "allow_neutral", default=None,
                     help="With --require-stable: a neutral equilibrium (free spins) counts as "
                          "stable (default: allowed)."),
        click.option("--compliance-markers", default=None, metavar="IDS|all|auto|none",
                     expose_value=False, callback=_store_compliance_markers,
                     help="Write the compliance matrix of these markers at every equilibrium "
                          "frame: marker ids (\"10,20\"), 'all' (every body's CG marker), "
                          "'auto' (all up to 100 bodies) or 'none'. Default: the deck's "
                          "Param_Static compliance_markers, else none."),
        click.option("--compliance-method", default=None, expose_value=False,
                     type=click.Choice(("exact", "fd"), case_sensitive=False),
                     callback=_store_compliance_method,
                     help="exact: from the analytic tangent (default); fd: re-solve under a "
                          "load compliance_delta per column (Param_Static compliance_method)."),
    ]
    for opt in reversed(opts):
        f = opt(f)
    return f


def collect_overrides(**values) -> dict:
    """Only the options the user actually gave, keyed by Param_Static attribute name."""
    ctx = click.get_current_context(silent=True)
    for k in _META:
        if ctx is not None and values.get(k) is None:
            values[k] = ctx.meta.get(f"poise.{k}")
    return {k: values[k] for k in OVERRIDE_KEYS if values.get(k) is not None}


#: ``--worker-timeout`` of poise batch / sweep (poise.app.engine.WORKER_TIMEOUT, not imported:
#: that module is heavier than the CLI's start-up budget allows)
WORKER_TIMEOUT = 120.0

worker_timeout_option = click.option(
    "--worker-timeout", type=_Finite(min=0, min_open=True), default=WORKER_TIMEOUT,
    show_default=True, metavar="SECONDS",
    help="Give up (exit 2, keeping what finished) when the Dask cluster has had no worker for "
         "this long (a scheduler nobody joined, or whose workers all died).")


#: ``ctx.meta`` key of ``poise batch --jobs`` (the former name of -j/--workers, kept hidden)
_JOBS_ALIAS = "poise.jobs"


def _store_jobs(ctx, param, value):
    if value is not None:
        ctx.meta[_JOBS_ALIAS] = value
    return value


def workers_option(f):
    """``-j/--workers N`` of ``poise batch`` and ``poise sweep`` (one name, one meaning)."""
    f = click.option("--jobs", type=click.IntRange(min=0), default=None, hidden=True,
                     expose_value=False, callback=_store_jobs,
                     help="Former name of -j/--workers.")(f)
    return click.option(
        "-j", "--workers", type=click.IntRange(min=0), default=0, show_default=True,
        metavar="N", help="Worker processes of the local cluster (0 = number of CPUs; ignored "
                          "with --scheduler).")(f)


def workers_given(workers: int) -> int:
    """``-j/--workers``, or the hidden ``--jobs`` when only that was given."""
    ctx = click.get_current_context(silent=True)
    jobs = ctx.meta.get(_JOBS_ALIAS) if ctx is not None else None
    if jobs is not None and ctx.get_parameter_source("workers") is click.core.ParameterSource.DEFAULT:
        return jobs
    return workers
