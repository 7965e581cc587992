"""The declarations of :mod:`poise.results.schema`: one row per dataset or attribute.

Long by nature (a table of the whole file format; split it by section past ~500 lines).
Shape symbols: F frames, B bodies, N iteration rows, and one symbol per element group (declared
with the group by its element types, :class:`poise.elements.registry.OutputGroup`, listed in
``results_format.md``, *Conventions*); ``6Mc`` is six times Mc. Unit expressions: ``length force mass time`` and
``rad``; ``"1"`` dimensionless; ``""`` text; ``"mixed"`` components of different units (the
meaning says which). Adding a capability: declare its datasets here, in a section of
``results_format.md`` (or a new ``{{datasets:SECTION}}`` line there), then regenerate the
document.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Item:
    """One declared dataset (``kind="dataset"``) or attribute (``kind="attr"``)."""

    scope: str
    name: str               # dataset path relative to the scope, or attribute name
    kind: str               # "dataset" | "attr"
    dtype: str              # float | int | bool | str | json (a JSON text attribute)
    shape: tuple = ()       # symbols / ints; () scalar
    unit: str = ""          # unit expression ("" text, "1" dimensionless, "mixed")
    meaning: str = ""
    optional: bool = False  # written only when the model / method / run has it
    section: str = ""       # documentation table it belongs to

    @property
    def path(self) -> str:
        sep = "@" if self.kind == "attr" else "/"
        return f"{self.scope}{sep}{self.name}"

    @property
    def pattern(self) -> bool:
        return "<" in self.name


_ROWS: list[Item] = []


def _d(scope, name, dtype, shape, unit, meaning, section, optional=False):
    _ROWS.append(Item(scope, name, "dataset", dtype, tuple(shape), unit, meaning, optional,
                      section))


def _a(scope, name, dtype, meaning, section, optional=False, unit=""):
    _ROWS.append(Item(scope, name, "attr", dtype, (), unit, meaning, optional, section))


# ------------------------------------------------------------------------------ root
for n, t, m in (
        ("format", "str", 'always `"poise-results"`'),
        ("format_version", "int", "`1` (incompatible layout changes bump it)"),
        ("poise_version", "str", "version of poise that wrote the file"),
        ("deck", "str", "deck path as given on the command line"),
        ("deck_sha256", "str", "SHA-256 (hex) of the deck file bytes"),
        ("status", "str", "`converged` if every analysis converged, else `failed`"),
        ("units", "str", "the deck's units, e.g. `force=NEWTON mass=KILOGRAM "
                         "length=MILLIMETER time=SECOND`; every dataset's `units` attribute "
                         "is written in these"),
        ("active_effects", "str", "(string array) element families compiled and evaluated "
                                  "(e.g. `gravity`, `revolute`, `spring_translational`)"),
        ("command", "str", "the command line that produced the file (`poise solve …`)")):
    _a("root", n, t, m, "root")
for n, t, m in (
        ("input_files", "json", "written by `poise solve` when the deck reads other files "
                                "(user scripts, the dataset an Adams command file names): JSON "
                                "(sorted keys) describing them; `poise batch` freshness covers "
                                "them"),
        ("ignored", "json", "Adams datasets: the elements `--ignore KIND` left out, a JSON list "
                            "of `{kind, statement, file, line}` (absent when none)"),
        ("run_overrides", "json", "JSON (sorted keys) of the solver options given on the "
                                  "command line (`{}` if none) and, for an Adams dataset, "
                                  "the `--ignore` kinds (`ignore`); `poise batch` compares it "
                                  "to decide whether a file is up to date"),
        ("sweep_case", "int", "case number of a sweep case file"),
        ("sweep_values", "json", "JSON of the case's parameter values "
                                 "(`{\"Force_SpringDamper[1].stiffness\": 15000.0}`)"),
        ("sweep_case_hash", "str", "SHA-256 of deck hash, values, overrides and poise "
                                   "version; a sweep skips the case when it matches")):
    _a("root", n, t, m, "root-optional", optional=True)
_d("root", "warnings", "str", ("W",), "", "located warnings (`FILE:LINE: <Tag id=N>: message`) "
   "from reading/compiling the deck", "root-objects")

# ------------------------------------------------------------------------------ timings, counts
for n, m in (("parse", "reading and validating the deck"),
             ("compile", "building the compiled model"),
             ("solve", "all analyses (everything between compile and writing)"),
             ("import", "importing the modules the run needed on first use (SciPy, SUNDIALS, "
                        "...); left out of `parse`, `compile`, `solve` and its phases"),
             ("solve_evaluate", "inside `solve`: element kernels and residuals (incl. batched "
                                "frame outputs)"),
             ("solve_assemble", "inside `solve`: KKT Jacobian assembly (local tangents + "
                                "scatter)"),
             ("solve_factorise", "inside `solve`: LU factorisations"),
             ("analysis_<NNN>", "one analysis (part of `solve`; printed on the analysis' "
                                "summary line)"),
             ("write", "writing this file, up to closing it (fsync and rename excluded)")):
    _a("timings", n, "float", m, "timings", unit="s",
       optional=n.startswith("solve_") or n == "import")
for n, m in (("residuals", "residual evaluations"), ("jacobians", "Jacobian evaluations"),
             ("factorizations", "factorisations of the KKT matrix, and of the least-squares "
                                "multipliers' Gram matrix where it replaces their weighted KKT "
                                "matrix (redundancy detection's, once per model: not counted)")):
    _a("counts", n, "int", m, "counts")

# ------------------------------------------------------------------------------ /model
M = "model"
_d(M, "bodies/id", "int", ("B",), "1", "deck id of each body (`Body_Rigid` / `Body_Point`)",
   "model")
_d(M, "bodies/label", "str", ("B",), "", "the body's `label` attribute (empty if none)", "model")
_d(M, "bodies/kind", "str", ("B",), "", "`rigid` or `point`", "model")
_d(M, "bodies/mass", "float", ("B",), "mass", "mass in the deck's mass unit", "model")
_d(M, "length_scale", "float", (), "length", "the model size L that scales moment rows and "
   "translational constraint errors", "model")
_d(M, "n_coordinates", "int", (), "1", "number of generalised coordinates", "model")
_d(M, "n_equations", "int", (), "1", "number of constraint equations (before redundancy "
   "removal)", "model")
_d(M, "markers/id", "int", ("Mk",), "1", "marker ids in compiled order (id 0 = the global "
   "frame)", "model-markers")
_d(M, "markers/body_id", "int", ("Mk",), "1", "id of the moving body the marker is on; `-1` "
   "for ground and the global frame", "model-markers")
_d(M, "markers/offset", "float", ("Mk", 3), "length", "marker origin in the body (CG marker) "
   "frame; for ground markers in the global frame. Global position at a frame: "
   "`bodies/position[f, b] + bodies/orientation[f, b] @ offset`", "model-markers")
for e in ("i", "j"):
    _d(M, f"joints/{e}_marker", "int", ("J",), "1", f"{e.upper()} marker id of each "
       "`Constraint_Joint` (order of `joints/id`)", "model-markers", optional=True)
    _d(M, f"joints/{e}_body", "int", ("J",), "1", f"body id of the {e.upper()} marker "
       "(`-1` = ground)", "model-markers", optional=True)
for n, t, sh, u, m in (
        ("id", "int", ("Gr",), "1", "`Post_Graphic` id"),
        ("type", "str", ("Gr",), "", "`sphere`, `box` (`Box`, `BoxDefinedFromCenter`, "
                                     "`BoxDefinedFromCorner`) or `plane`"),
        ("marker_id", "int", ("Gr",), "1", "the centre / corner / reference marker"),
        ("body_id", "int", ("Gr",), "1", "body of that marker (`-1` = ground: fixed, global "
                                         "frame)"),
        ("offset", "float", ("Gr", 3), "length", "geometric centre in the body (CG marker) "
         "frame (corner boxes: corner + half lengths along the marker axes); a plane's point"),
        ("axes", "float", ("Gr", 3, 3), "1", "the marker's axes (columns) in the body frame; a "
         "plane's normal is column 3 (`z`)"),
        ("radius", "float", ("Gr",), "length", "sphere radius (NaN otherwise)"),
        ("half_length", "float", ("Gr", 3), "length", "box half lengths along the marker axes "
                                                      "(NaN otherwise)")):
    _d(M, f"graphics/{n}", t, sh, u, m, "model-graphics", optional=True)

# ------------------------------------------------------------------------------ /analysis_NNN
A = "analysis"
for n, t, m in (
        ("analysis_type", "str", "`static` or `quasistatic`"),
        ("method", "str", "method actually used: `FIM_S`, `FIM_D`, `MKEAM` (a fallback is "
                          "recorded here and in `message`)"),
        ("status", "str", "`converged` or `failed`"),
        ("message", "str", "human-readable outcome: why it failed, fallbacks taken"),
        ("settings", "json", "JSON object: effective settings after defaults < deck < command "
                             "line (`method`, `max_num_iter`, `max_imbalance`, `max_error`, "
                             "`stability`, …), keys sorted"),
        ("reactions_unique", "bool", "`true` if joint reactions are uniquely determined (no "
                                     "redundant constraints removed); when `false`, the "
                                     "reactions reported are one valid distribution"),
        ("assembled", "bool", "the initial configuration was moved to satisfy the "
                              "constraints before solving")):
    _a(A, n, t, m, "analysis-attrs")
_a(A, "coordinates", "str", "`time` when the analysis has frames: netCDF's name of the "
   "coordinate of the `frame` dimension (see *netCDF and xarray*)", "analysis-attrs",
   optional=True)
_a(A, "iterations_total", "int", "iterations of all frames (`sum(frames/iterations)`; FIM_S "
   "and FIM_D analyses)", "analysis-attrs", optional=True)
for s in ("plain", "stability", "continuation", "mkeam", "polish"):
    _a(A, f"iterations_{s}", "int", f"iterations of the `{s}` stage, all frames (column of "
       "`frames/strategy_iterations`; FIM_S and FIM_D analyses)", "analysis-attrs",
       optional=True)
_a(A, "iterations_poses_stride", "int", "iterate poses recorded every k-th row (see "
   "`iterations/pose_row`)", "analysis-attrs", optional=True)
_a(A, "mkeam_wall_time", "float", "MKEAM: wall time of the attrition iteration [s] (not "
   "reproducible)", "analysis-attrs", optional=True, unit="s")
for n, t, m in (
        ("time_independent", "bool", "nothing depends on time: one solve, frames replicated"),
        ("n_frames", "int", "number of output frames"),
        ("ida_steps", "int", "FIM_D: accepted internal IDA steps"),
        ("fim_s_fallbacks", "int", "FIM_D: frames solved by the FIM_S fallback"),
        ("dae_tol", "float", "FIM_D: IDA's relative/absolute tolerance"),
        ("ida_linear_solver", "str", "FIM_D: `dense` (up to 200 unknowns) or `sparse`")):
    _a(A, n, t, m, "quasistatic-attrs", optional=True)
for n, t, m in (
        ("singular_time", "float", "quasi-static run that ended at a singular configuration "
         "(status `singular_configuration`): its time, located by bisection"),
        ("singular_kind", "str", "`dead_point` (the constraint equations lose rank: a toggle, "
         "a dead centre, a motion beyond the linkage's reach) or `limit_point` (the reduced "
         "stiffness reaches zero) or `bifurcation` (it changes sign along the path)"),
        ("singular_elements", "json", "JSON list of the constraints that lock there (the "
         "self-stress), largest share first: `tag`, `id`, `label`, `line`, `share`"),
        ("singular_mode", "str", "the motion at the singular point, named by the body that "
         "moves most, e.g. `body 2 rotation about z`")):
    _a(A, n, t, m, "quasistatic-attrs", optional=True, unit="time" if n == "singular_time" else "")
for n, t, m in (("frames", "int", "output frames corrected onto the equilibrium"),
                ("corrections", "int", "Newton corrections of those frames"),
                ("residuals", "int", "residual evaluations of the corrections"),
                ("factorisations", "int", "factorisations of the corrections"),
                ("newton", "int", "frames that needed a full Newton solve"),
                ("seconds", "float", "wall time of the corrections (not reproducible)")):
    _a(A, f"correction_{n}", t, f"FIM_D: {m}", "quasistatic-attrs", optional=True,
       unit="s" if t == "float" else "")
for n, t, m in (("compliance_method", "str", "`exact` or `fd`"),
                ("compliance_units", "str", "the units of a 6×6 block (text below)"),
                ("compliance_delta", "float", "`fd` only: the load of a column (force units; "
                                              "torques `delta × L`)"),
                ("compliance_note", "str", "why the matrix (or part of it) is not written")):
    _a(A, n, t, m, "compliance", optional=True)

# frames
_d(A, "time", "float", ("F",), "time", "time of each output frame (0 for a plain static "
   "analysis; quasi-static: simulation time)", "frames")
for n, t, sh, u, m in (
        ("converged", "bool", ("F",), "1", "whether the reported state meets the "
         "`Param_Static` tolerances, measured there for every method (force rows ≤ "
         "`max_imbalance`, moment rows ≤ `max_imbalance`·L, constraint rows ≤ `max_error` (·L "
         "for translations), and the method's own error estimate ≤ `max_error`); a frame a "
         "method called converged that misses them has status `tolerance_not_met`"),
        ("iterations", "int", ("F",), "1", "all iterations of the frame: plain Newton "
         "(sub-steps included) and every fallback strategy; MKEAM: its iterations; FIM_D "
         "output frames: corrections of IDA's point onto the equilibrium"),
        ("strategy", "str", ("F",), "", "recovery stage that produced the frame: `plain` (no "
         "recovery), `stability`, `continuation`, `mkeam`"),
        ("strategy_iterations", "int", ("F", 5), "1", "the frame's iterations split by "
         "stage, columns `plain`, `stability`, `continuation`, `mkeam`, `polish` (they sum to "
         "`frames/iterations`)"),
        ("imbalance", "float", ("F",), "mixed", "infinity norm of the force/moment residual "
         "(`Φ_qᵀλ − Q`) at the final iterate, **without** the `stability` regularisation "
         "(force rows in force units, moment rows in force×length: the largest of both, so "
         "the units attribute says `mixed`; force rows meet `max_imbalance`, moment rows "
         "`max_imbalance`·L, L = `/model/length_scale`)"),
        ("error", "float", ("F",), "1", "final error compared with `max_error`: the larger of "
         "the constraint violation (translational rows divided by the model size L, "
         "rotational rows in rad) and the last Newton update (translations / L, rotations in "
         "rad)"),
        ("status", "str", ("F",), "", "solver status of the frame: `converged`, "
         "`max_iterations`, `singular_jacobian`, `nonfinite`, `assembly_failed`, "
         "`inconsistent_constraints`, `tolerance_not_met` (see `frames/converged`), "
         "`no_equilibrium`, `diverged`, `step_too_small`, `unstable` (`--require-stable`), "
         "`singular_configuration` (a quasi-static run's last frame: the state where the "
         "branch ends, at the time `singular_time`), …"),
        ("stability", "str", ("F",), "", "stability class of the converged equilibrium: "
         "`stable`, `neutral`, `unstable`, or `unknown` (frame not converged, or the sparse "
         "inertia computation could not be trusted — the reason is in "
         "`frames/stability_modes`); the last frame of a path that ended at a singular "
         "configuration or lost stability is classified too (the state past the event)"),
        ("n_negative", "int", ("F",), "1", "number of negative eigenvalues of the tangent "
         "stiffness reduced to the constraint manifold (−1 when not classified)"),
        ("n_zero", "int", ("F",), "1", "number of zero eigenvalues (neutral directions; "
         "|λ| ≤ 1e-8 × the largest, after equilibration)"),
        ("stability_modes", "str", ("F",), "", "the unstable and neutral modes, each named by "
         "the body with the largest participation and its dominant motion, e.g. `unstable: "
         "body 2 rotation about (0.00,0.00,1.00)`; at most six per class; for an `unknown` "
         "frame, `not classified: <reason>`"),
        ("n_modes", "int", ("F",), "1", "number of the frame's modes described as numbers in "
         "`modes/*` (≤ 12; 0 for a stable or unclassified frame)"),
        ("min_stiffness_eigenvalue", "float", ("F",), "force/length", "smallest eigenvalue of "
         "the reduced stiffness (coordinates scaled to lengths: rotations × the body's length "
         "scale); NaN when not classified, +inf without degrees of freedom")):
    _d(A, f"frames/{n}", t, sh, u, m, "frames")
for n, t, sh, u, m in (
        ("class", "str", ("K",), "", "`unstable` or `neutral`"),
        ("body", "int", ("K",), "1", "id of the body with the largest participation in the "
         "mode (`-1` in a model without bodies)"),
        ("kind", "str", ("K",), "", "that body's dominant motion: `rotation` (about "
         "`modes/direction`), `translation` (along it), or `coordinate`"),
        ("direction", "float", ("K", 3), "1", "unit vector in global axes, sign-normalised "
         "(largest-magnitude component positive); NaN for `coordinate`"),
        ("eigenvalue", "float", ("K",), "force/length", "the mode's Rayleigh quotient of the "
         "reduced stiffness in length coordinates: negative for an unstable mode, ≈ 0 for a "
         "neutral one")):
    _d(A, f"modes/{n}", t, sh, u, m, "modes")

# bodies
for n, t, sh, u, m in (
        ("id", "int", ("B",), "1", "deck id of each body (column order of every `bodies/*` "
         "array)"),
        ("label", "str", ("B",), "", "the body's `label` attribute (empty if none)"),
        ("position", "float", ("F", "B", 3), "length", "origin of the body's CG marker in the "
         "global frame"),
        ("orientation", "float", ("F", "B", 3, 3), "1", "rotation matrix of the CG marker: "
         "**columns** are the marker's x, y, z axes in the global frame "
         "(`v_global = R @ v_cg`)"),
        ("euler_parameters", "float", ("F", "B", 4), "1", "Euler parameters (unit quaternion) "
         "`e0, e1, e2, e3` of `bodies/orientation`, `e0 >= 0`"),
        ("euler_313", "float", ("F", "B", 3), "rad", "body-fixed 3-1-3 angles `psi, theta, "
         "phi` of `bodies/orientation` (MotionSolve convention)"),
        ("rotation_from_input", "float", ("F", "B", 3), "rad", "continuous rotation vector "
         "from the body's input orientation, full turns counted (`|v|` may exceed pi)")):
    _d(A, f"bodies/{n}", t, sh, u, m, "bodies")

# iterations
for n, t, u, m in (
        ("frame", "int", "1", "frame index (0-based) the iteration belongs to"),
        ("iteration", "int", "1", "iteration number within the frame (0-based)"),
        ("imbalance", "float", "mixed", "imbalance (infinity norm of the residual; force rows "
         "in force units, moment rows in force×length, hence `mixed`) after the iteration"),
        ("error", "float", "1", "error measure of the iteration (constraint violation and "
         "update, translations / L, rotations in rad)"),
        ("step_norm", "float", "1", "scaled norm of the Newton step before line search"),
        ("step_length", "float", "1", "line-search factor applied to the step (1 = full "
         "Newton step)"),
        ("worst_equation", "str", "", "element and equation with the largest scaled residual, "
         "e.g. `<Constraint_Joint id=5> rot_x`"),
        ("event", "str", "", "what the row was: `assembly`, `newton`, `newton-chord` (a "
         "step by an earlier iterate's factorisation in Newton's quadratic phase), `substep`, "
         "`mkeam`, `polish`, `ida`, `fallback: <reason>`, …"),
        ("strategy", "str", "", "recovery stage of the row: `plain`, `stability`, "
         "`continuation`, `mkeam`, `polish`")):
    _d(A, f"iterations/{n}", t, ("N",), u, m, "iterations")
_d(A, "iterations/position", "float", ("Np", "B", 3), "length", "CG positions of the "
   "iterate of each recorded row", "poses", True)
_d(A, "iterations/orientation", "float", ("Np", "B", 3, 3), "1", "orientations, same rows",
   "poses", True)
_d(A, "iterations/pose_row", "int", ("Np",), "1", "the `iterations/*` row of each pose",
   "poses", True)

# MKEAM
for n, t, u, m in (
        ("kinetic_energy", "float", "force*length", "peak kinetic energy of the iteration"),
        ("peak_time", "float", "time", "time of the peak from the restart"),
        ("max_dq", "float", "1", "largest change since the previous restart (translation / L, "
         "rad)"),
        ("potential_energy", "float", "force*length", "potential at the peak (NaN if a force "
         "is not conservative)"),
        ("integrator_steps", "int", "1", "integration steps of the iteration (-1 elsewhere)")):
    _d(A, f"iterations/{n}", t, ("N",), u, m + " (NaN / -1 on non-MKEAM rows)", "mkeam", True)
_d(A, "mkeam/iterate_position", "float", ("I1", "B", 3), "length", "CG positions at the start "
   "and at every restart", "mkeam", True)
_d(A, "mkeam/iterate_orientation", "float", ("I1", "B", 3, 3), "1", "orientations, same rows",
   "mkeam", True)
_d(A, "mkeam/position", "float", (1, "B", 3), "length", "the MKEAM point before the Newton "
   "polish", "mkeam", True)
_d(A, "mkeam/orientation", "float", (1, "B", 3, 3), "1", "its orientations", "mkeam", True)
_d(A, "mkeam/initial_potential_energy", "float", (), "force*length", "potential of the start",
   "mkeam", True)

# redundancy
for n, t, m in (("tag", "str", "element tag of each removed equation"),
                ("id", "int", "element id"),
                ("equation", "str", "which equation of the element (e.g. `rot_x`, `trans_z`)"),
                ("line", "int", "deck line of the element")):
    _d(A, f"redundant/{n}", t, ("D",), "" if t == "str" else "1", m, "redundant")

# compliance
_d(A, "compliance/marker_id", "int", ("Mc",), "1", "the markers, in matrix order",
   "compliance", True)
_d(A, "compliance/method", "str", (), "", "`exact` or `fd`", "compliance", True)
_d(A, "frames/compliance", "float", ("F", "6Mc", "6Mc"), "mixed", "entry `[f, 6i+a, 6j+b]`: "
   "component `a` of the displacement of marker i (a = 0–2 translation x/y/z, 3–5 small "
   "rotation about x/y/z) per unit component `b` of a load at marker j (b = 0–2 force x/y/z, "
   "3–5 torque about x/y/z), global axes; block units in `compliance_units`", "compliance",
   True)
_d(A, "frames/compliance_flag", "str", ("F",), "", "`ok`, `unstable`, `singular`, "
   "`fd_failed` or `not_converged` (text below)", "compliance", True)

# FIM_D steps
for n, t, u, m in (
        ("time", "float", "time", "time reached by each accepted internal IDA step"),
        ("step_size", "float", "time", "the step size used (`IDAGetLastStep`)"),
        ("order", "int", "1", "BDF order of the step, 1..`max_order`; -1 only if IDA's "
         "counters could not be read"),
        ("nonlinear_iterations", "int", "1", "Newton iterations of the step, failed attempts "
         "included"),
        ("error_test_failures", "int", "1", "local error-test failures before the step was "
         "accepted"),
        ("convergence_failures", "int", "1", "Newton convergence failures before the step was "
         "accepted; -1 if IDA's counters could not be read"),
        ("jacobian_evaluations", "int", "1", "analytic Jacobians handed to IDA during the "
         "step"),
        ("rebase", "int", "1", "1 where IDA was (re)initialised before the step")):
    _d(A, f"steps/{n}", t, ("S",), u, m, "steps", True)


def declared() -> list[Item]:
    """Every declaration: this table, then the element groups' datasets, derived from the
    element registry's :class:`~poise.elements.registry.OutputGroup` declarations
    (:mod:`poise.results.schema_groups`)."""
    from poise.results.schema_groups import element_items     # lazy: imports every element type
    return list(_ROWS) + element_items(Item)
