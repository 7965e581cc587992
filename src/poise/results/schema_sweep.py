"""The sweep file as data: every variable and attribute of ``OUT_DIR/sweep.h5``, declared once.

A sweep file (``format = "poise-sweep"``) is one netCDF-4 group (the root) with a ``case``
dimension: one row per case of a ``poise sweep``, the swept parameters as coordinates along
``case``, a ``frame`` dimension (the frames of every analysis, in order; coordinates ``time`` and
``analysis``) and the fixed-size dimensions of the results files (``axis``, ``channel``, ...).
Three kinds of variables:

* fixed ones (:data:`ROWS`: status, iterations, imbalance, ..., ``converged`` per frame);
* one coordinate per swept parameter, named as given to ``--set``
  (``Force_SpringDamper[1].stiffness``): :func:`parameter_item`;
* one variable per ``--output group[id].dataset``, named so: the results file's
  ``<group>/<dataset>`` for that element, ``(case, frame, ...)``, with that declaration's dtype,
  trailing axes, unit and long name (:func:`output_item`): declared once, in the results schema.

The writer (:mod:`poise.results.sweepfile`) writes nothing else and checks dtype and rank.
"""
from __future__ import annotations

import functools

from poise.results.schema_items import Item

FORMAT = "poise-sweep"
FORMAT_VERSION = 1
SCOPE = "sweep"

#: integer fill of a per-case number the case does not have (an invalid deck's iterations, ...)
NO_INT = -1

_ROWS: list[Item] = []


def _d(name, dtype, shape, unit, meaning, optional=False):
    _ROWS.append(Item(SCOPE, name, "dataset", dtype, tuple(shape), unit, meaning, optional,
                      "sweep"))


def _a(name, dtype, meaning, optional=False):
    _ROWS.append(Item(SCOPE, name, "attr", dtype, (), "", meaning, optional, "sweep-attrs"))


for _n, _t, _m in (
        ("format", "str", f'always `"{FORMAT}"`'),
        ("format_version", "int", f"`{FORMAT_VERSION}` (incompatible layout changes bump it)"),
        ("poise_version", "str", "version of poise that wrote the file"),
        ("deck", "str", "the swept deck's path as given"),
        ("deck_sha256", "str", "SHA-256 (hex) of the deck file bytes"),
        ("units", "str", "the deck's units (`force=NEWTON mass=KILOGRAM ...`): every "
                         "variable's `units` attribute is written in these"),
        ("command", "str", "the command that made the file (`poise sweep ...`, `poise.sweep`)"),
        ("mode", "str", "`grid`, `zip` or `random`"),
        ("parameters", "json", "JSON object: each swept parameter and its values as given "
                               "(`{\"Force_SpringDamper[1].stiffness\": [10000.0, ...]}`)"),
        ("overrides", "json", "JSON object (sorted keys): the solver options of every case "
                              "(and `ignore`: the `--ignore` kinds of an Adams dataset)"),
        ("outputs", "json", "JSON list: the `--output` variables, in the order given"),
        ("sweep_hash", "str", "SHA-256 of deck hash, solver options, `--ignore` kinds and poise "
                              "version: a later sweep reuses the file's cases when it matches "
                              "(a case is then known by its parameter values)"),
        ("n_cases", "int", "number of cases (the size of `case`)"),
        ("n_done", "int", "cases solved and written; `n_cases` unless the sweep gave up (no "
                          "Dask worker), the rest then have status `not_run`"),
        ("complete", "bool", "`true` when every case is written (`n_done == n_cases`)"),
        ("coordinates", "str", "netCDF: the swept parameters, `time` and `analysis`, read by "
                               "xarray as coordinates")):
    _a(_n, _t, _m)
_a("seed", "int", "`--seed` of a random sweep", optional=True)
_a("input_files", "json", "JSON (sorted keys): the files the cases read besides the deck "
   "(Python user scripts, path -> SHA-256); a changed one makes a later sweep solve again",
   optional=True)
_a("ignored", "json", "Adams datasets: the elements `--ignore KIND` left out (JSON list, as "
   "in a results file)", optional=True)

_d("case", "int", ("C",), "1", "case number (0-based, the order of `index.csv`): the "
   "coordinate of `case`")
_d("time", "float", ("F",), "time", "time of each frame: the output times of each analysis, "
   "each starting where the one before ends (0 for a static analysis first in the deck); a "
   "case's frame at another time (an analysis before it stopped early) is written as not "
   "converged with NaN outputs")
_d("analysis", "int", ("F",), "1", "the analysis (`Simulate`, 0-based) each frame belongs to")
for _n, _t, _u, _m in (
        ("status", "str", "", "`converged`, `failed` (an analysis did not converge; exit 1), "
         "`invalid_deck` (this combination of values is not a valid deck; exit 3), "
         "`internal_error` (exit 4), `io_error` (its `--per-case-files` file could not be "
         "written; exit 2), or `not_run`"),
        ("exit_code", "int", "1", "what `poise solve` of the case would exit with (-1 "
         "`not_run`)"),
        ("iterations", "int", "1", "iterations of all frames of all analyses (-1 when none)"),
        ("wall_time", "float", "s", "parse + compile + solve of the case in its worker "
         "[s] (not reproducible)"),
        ("imbalance", "float", "mixed", "the largest `frames/imbalance` over every analysis "
         "and frame (force rows in force units, moment rows in force×length)"),
        ("imbalance_analysis", "int", "1", "its analysis (-1 when none)"),
        ("imbalance_frame", "int", "1", "its frame within that analysis (-1 when none)"),
        ("error", "float", "1", "the largest `frames/error` over every analysis and frame"),
        ("stability", "str", "", "the worst stability class over every analysis and frame "
         "(`stable < neutral < unknown < unstable`; empty when none)"),
        ("stability_analysis", "int", "1", "its analysis (-1 when none)"),
        ("stability_frame", "int", "1", "its frame within that analysis (-1 when none)"),
        ("n_negative", "int", "1", "negative reduced stiffness eigenvalues at that frame"),
        ("n_zero", "int", "1", "zero reduced stiffness eigenvalues at that frame"),
        ("stability_modes", "str", "", "that frame's unstable and neutral modes as text"),
        ("modes", "json", "", "that frame's modes as numbers (JSON list of `{class, body, "
         "kind, direction, eigenvalue}`)"),
        ("message", "str", "", "failed analyses' messages, or the located deck problems, or "
         "the error, joined by `; ` (empty for a converged case)")):
    _d(_n, _t, ("C",), _u, _m)
_d("converged", "bool", ("C", "F"), "1", "whether the case's frame converged "
   "(`frames/converged` of its analysis; false where the case has no such frame)")
_d("file", "str", ("C",), "", "the case's own results file (`case_NNNNN.h5`, relative to "
   "the sweep directory) with `--per-case-files`; empty when not written", optional=True)

#: the rules for the variables named by the sweep (documented, resolved by the functions below)
_d("<parameter>", "float", ("C",), "mixed", "one coordinate per swept parameter, named as in "
   "`--set` (`Force_SpringDamper[1].stiffness`, `Param_Static.method`): the case's value, in "
   "the deck's units for that attribute; dtype from the attribute (real: float, int: int, "
   "enum: str, bool: bool)")
_d("<output>", "float", ("C", "F"), "mixed", "one variable per `--output group[id].dataset` "
   "(`bodies[2].position`, `joints[1].force`, `requests[3].values`), named so: the results "
   "file's `<group>/<dataset>` of that element at every frame, followed by that dataset's "
   "trailing dimensions (`axis`, `channel`, ...); dtype, units and long name from its "
   "declaration (NaN where the case has no such frame)")


def declared() -> list[Item]:
    """Every sweep-file declaration (the two rules last)."""
    return list(_ROWS)


@functools.cache
def fixed() -> dict[tuple[str, str], Item]:
    """``{(kind, name): Item}`` of the fixed variables and attributes."""
    return {(it.kind, it.name): it for it in _ROWS if not it.pattern}


_KIND_DTYPE = {"real": "float", "real_or_expr": "float", "int": "int", "enum": "str",
               "bool": "bool"}


def parameter_item(key: str, kind: str) -> Item:
    """The declaration of the coordinate of swept parameter ``key`` of deck attribute kind
    ``kind`` (``real``, ``int``, ``enum``, ``bool``)."""
    rule = next(it for it in _ROWS if it.name == "<parameter>")
    return Item(SCOPE, key, "dataset", _KIND_DTYPE[kind], ("C",),
                "1" if kind == "int" else "" if kind in ("enum", "bool") else rule.unit,
                rule.meaning, False, rule.section)


def output_item(text: str, source: Item) -> Item:
    """The declaration of ``--output`` variable ``text`` (``bodies[2].position``) from the
    results declaration ``source`` of ``<group>/<dataset>`` (shape ``(F, n, ...)``)."""
    return Item(SCOPE, text, "dataset", source.dtype, ("C", "F", *source.shape[2:]),
                source.unit, source.meaning, False, "sweep")
