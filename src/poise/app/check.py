"""``poise check``: parse and compile a deck, detect redundant equations, report; no solve.

No deck code runs here: user routines are validated (their scripts must lie inside the deck's
directory) and listed, never imported.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from poise.app.runner import load_input, plan
from poise.model.compile import compile_model
from poise.elements.user import USER_CONSTRAINT_TAGS
from poise.solvers.redundancy import detect_redundancy


@dataclass
class CheckReport:
    """What ``poise check`` prints: the compiled model without solving.

    Attributes
    ----------
    deck : str
    bodies : list[dict]
        One dict per body: ``id``, ``label``, ``kind`` (``rigid``/``point``/``ground``), ``mass``.
    constraints : list[dict]
        One dict per constraint element: ``tag``, ``id``, ``type``, ``n_equations``, ``line``.
    forces : list[dict]
        One dict per force element: ``tag``, ``id``, ``type``, ``line``.
    n_coordinates : int
        Number of tangent coordinates (6 per rigid body, 3 per point body, + extra unknowns).
    n_equations : int
        Number of constraint equations before redundancy removal.
    n_redundant : int
    dof : int or None
        Degrees of freedom = n_coordinates - rank of the constraint Jacobian; ``None`` when the
        deck has user constraints (``Constraint_UserConstr``): their number of equations is known
        only by running their routine, which ``check`` never does.
    dof_without_user_constraints : int or None
        The degrees of freedom of the model without its user constraints (an upper bound), when
        ``dof`` is ``None``.
    user_routines : list[dict]
        Elements given by Python user routines: ``tag``, ``id``, ``script``, ``function``,
        ``line``. ``check`` validates the reference (inside the deck's directory) but never
        imports the script; the elements are left out of the compiled model.
    redundant : list[dict]
        Removed equations: ``tag``, ``id``, ``equation`` (e.g. ``"rot_x"``), ``line``.
    active_effects : list[str]
    warnings : list[str]
    analyses : list[dict]
        One dict per Simulate: ``analysis_type``, ``method``, ``n_frames`` (output frames: 1 for
        a static analysis, the output times of a quasi-static one).
    """

    deck: str
    bodies: list = field(default_factory=list)
    constraints: list = field(default_factory=list)
    forces: list = field(default_factory=list)
    n_coordinates: int = 0
    n_equations: int = 0
    n_redundant: int = 0
    dof: int | None = 0
    redundant: list = field(default_factory=list)
    active_effects: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    analyses: list = field(default_factory=list)
    user_routines: list = field(default_factory=list)
    dof_without_user_constraints: int | None = None


def check(path: str, ignore=()):
    spec = load_input(path, ignore)
    model = compile_model(spec, user_code="skip")      # check never runs deck code
    rep = CheckReport(deck=spec.path)
    mass = model.deck_mass()
    for i, bid in enumerate(model.body_id):
        rep.bodies.append(dict(id=int(bid), label=model.body_label[i],
                               kind="rigid" if model.body_kind[i] == 0 else "point",
                               mass=float(mass[i])))
    seen = {}
    tags = {ri["tag"] for ri in model.row_info}
    by_key = {}       # (tag, id) -> first element: one pass, not one scan per row
    for e in spec.model:
        if e.tag in tags:
            by_key.setdefault((e.tag, e.id), e)
    for ri in model.row_info:
        key = (ri["tag"], ri["id"])
        if key not in seen:
            el = by_key[key]
            seen[key] = dict(tag=ri["tag"], id=ri["id"], type=str(el.attrs.get("type", "")),
                             n_equations=0, line=ri["line"])
        seen[key]["n_equations"] += 1
    rep.constraints = list(seen.values())
    for el in spec.model:
        if el.tag.startswith("Force_") and el.tag != "Force_Gravity":
            rep.forces.append(dict(tag=el.tag, id=el.id, type=str(el.attrs.get("type", "")),
                                   line=el.loc.line))
    red = detect_redundancy(model, model.initial_state())
    rep.n_coordinates = model.nq
    rep.n_equations = model.nc
    rep.n_redundant = len(red)
    rep.dof = model.nq - (model.nc - len(red))
    rep.user_routines = sorted(getattr(model, "user_routines", []), key=lambda u: u["line"])
    n_user_c = sum(u["tag"] in USER_CONSTRAINT_TAGS for u in rep.user_routines)
    if n_user_c:      # their equation count is known only by calling them: not here
        rep.dof_without_user_constraints = rep.dof
        rep.dof = None
    rep.redundant = [dict(tag=model.row_info[r]["tag"], id=model.row_info[r]["id"],
                          equation=model.row_info[r]["equation"], line=model.row_info[r]["line"])
                     for r in red]
    rep.active_effects = list(model.active_effects)
    rep.warnings = [str(w) for w in spec.warnings] + [str(w) for w in model.spec_warnings]
    t_now = model.initial_state().t
    for req in plan(spec, None):
        method = req.settings.method
        if req.kind == "static" and method == "FIM_D":
            method = "FIM_S"
        n_frames = 1
        if req.kind == "quasistatic":       # the times the solve will output (same planner)
            times = req.output_times(t_now)
            n_frames, t_now = len(times), float(times[-1])
        rep.analyses.append(dict(analysis_type=req.kind, method=method, n_frames=n_frames))
    return rep
