"""The element registry and the tables derived from it (compile order, reactions, outputs)."""
import numpy as np
import pytest

from poise.deck.parser import parse_deck_bytes
from poise.elements.base import ConstraintFamily
from poise.elements.registry import (element_types, kernel_potential, kernel_types, output_groups,
                                     reaction_aliases, reaction_kinds, tileable_kernels, type_of,
                                     workless)
from poise.model.compile import compile_model
from poise.model.evaluate import evaluate
from poise.app.sweep import parse_outputs

from support.paths import DECKS


def test_compile_order_respects_declared_dependencies():
    seen = set()
    for et in element_types():
        assert set(et.needs) <= seen, f"{et.name} compiled before {set(et.needs) - seen}"
        seen.add(et.name)
    ranks = [et.rank for et in element_types()]
    assert ranks == sorted(ranks) and len(set(ranks)) == len(ranks)


def test_layout_rank_must_follow_data_dependencies():
    """Compile order is the layout rank; a rank before a type it needs, a shared rank or an
    unknown dependency is refused instead of silently reordering the model's layout."""
    from dataclasses import replace
    from poise.elements.registry import compile_order
    types = {et.name: et for et in element_types()}
    assert [et.name for et in compile_order(types)] == list(types)
    for bad, match in ((replace(types["expressions"], rank=15), "needs 'forces'"),
                       (replace(types["expressions"], rank=20), "same layout rank"),
                       (replace(types["expressions"], needs=("nothing",)), "unknown")):
        with pytest.raises(RuntimeError, match=match):
            compile_order(dict(types, expressions=bad))


def test_every_deck_tag_compiled_once():
    owners = {}
    for et in element_types():
        for tag in et.tags:
            if not et.types:               # a whole tag, not a claimed type inside one
                assert tag not in owners, f"{tag}: {owners.get(tag)} and {et.name}"
                owners[tag] = et.name


def test_reaction_tables():
    assert reaction_kinds()["BUSH"] == ("forces", ("Force_Bushing",))
    assert reaction_aliases()["FORCE_BUSHING"] == "BUSH"
    assert all(v in reaction_kinds() for v in reaction_aliases().values())


def test_tileable_kernels_are_declared_kernels():
    kernels = {k for et in element_types() for k in et.kernels()}
    assert set(tileable_kernels()) <= kernels


def test_sweep_accepts_every_output_group():
    """``--output gears[1].force`` was refused while sweep kept its own group table."""
    p = DECKS / "elem_gear_pair.xml"
    spec = parse_deck_bytes(p.read_bytes(), str(p))
    gid = next(e.id for e in spec.model if e.tag == "Constraint_Gear")
    assert "gears" in output_groups()
    (text, g, i, ds), = parse_outputs(spec, [f"gears[{gid}].force"])
    assert (g, i, ds) == ("gears", gid, "force")


def test_every_type_declares_energy_and_time_dependence():
    """Both are required (keyword-only) declarations, functions of a compiled family."""
    for et in element_types():
        assert callable(et.potential_energy) and callable(et.time_dependent), et.name


def test_every_kernel_belongs_to_one_type():
    owners = kernel_types()
    assert set(owners) == {k for et in element_types() for k in et.kernels()}


def test_declared_potential_energy_matches_the_kernels():
    """The energy pass (``evaluate(..., "energy")``) calls what each type declares: the kernels'
    own method (``kernel_potential``), nothing for constraint-only types (``workless``), NaN for
    forces without a potential (``not_conservative``)."""
    for et in element_types():
        has = any(callable(getattr(k, "potential_energy", None)) for k in et.kernels())
        assert (et.potential_energy is kernel_potential) == has, et.name
        if et.potential_energy is workless:
            assert all(issubclass(k, ConstraintFamily) for k in et.kernels()), et.name


def _energy_deck(extra=""):
    return f"""<?xml version="1.0"?>
<MotionSolve><Model>
  <Body_Rigid id="1" isground="TRUE" cg_id="10"/>
  <Reference_Marker id="10" body_id="1"/>
  <Body_Rigid id="2" cg_id="20" mass="2.0" inertia_xx="1" inertia_yy="1" inertia_zz="1"/>
  <Reference_Marker id="20" body_id="2" pos_x="0.5" pos_y="-1.5" pos_z="0.25"/>
  <Force_SpringDamper id="1" type="TRANSLATIONAL" i_marker_id="20" j_marker_id="10"
      stiffness="200." damping="0." length="1.0" preload="0."/>
  <Force_Gravity grav_x="0" grav_y="-9.81" grav_z="0"/>
  {extra}
</Model></MotionSolve>""".encode()


def test_energy_pass_sums_the_declared_terms():
    """Gravity (its own element type) and the spring add their potential; a joint adds
    nothing; an expression force has none, so the model's potential energy is NaN (MKEAM)."""
    joint = ('<Reference_Marker id="11" body_id="1" pos_x="0.5"/>'
             '<Reference_Marker id="21" body_id="2" pos_x="0.5"/>'
             '<Constraint_Joint id="1" type="INLINE" i_marker_id="21" j_marker_id="11"/>')
    m = compile_model(parse_deck_bytes(_energy_deck(joint), "e.xml"))
    assert [type_of(m.families[i]).name for i, _ in m.energy_terms] == ["gravity", "forces"]
    p = np.array([0.5, -1.5, 0.25])
    L = np.linalg.norm(p)
    expected = -2.0 * -9.81 * p[1] + 0.5 * 200.0 * (L - 1.0) ** 2
    assert evaluate(m, m.initial_state(), "energy") == pytest.approx(expected, rel=1e-14)
    xf = ('<Force_Vector_OneBody id="2" type="FORCEONLY" marker_id="20" fx_expression="0" '
          'fy_expression="-DX(20)" fz_expression="0"/>')
    m = compile_model(parse_deck_bytes(_energy_deck(xf), "e.xml"))
    assert np.isnan(evaluate(m, m.initial_state(), "energy"))
