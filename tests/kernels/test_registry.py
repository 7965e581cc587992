"""The element registry and the tables derived from it (compile order, reactions, outputs)."""
from poise.deck.parser import parse_deck_bytes
from poise.elements.registry import (element_types, output_groups, reaction_aliases,
                                     reaction_kinds, tileable_kernels)
from poise.app.sweep import parse_outputs

from support.paths import DECKS


def test_compile_order_respects_declared_dependencies():
    seen = set()
    for et in element_types():
        assert set(et.after) <= seen, f"{et.name} compiled before {set(et.after) - seen}"
        seen.add(et.name)


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


def test_declared_potential_energy_matches_the_kernels():
    """MKEAM sums ``potential_energy`` of the families that have it; the declaration says so."""
    for et in element_types():
        has = any(callable(getattr(k, "potential_energy", None)) for k in et.kernels())
        assert et.potential_energy == has, et.name
