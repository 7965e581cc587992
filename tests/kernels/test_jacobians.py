"""Every element family's analytic Jacobian against central finite differences.

The check runs on random (non-equilibrium, constraint-violating) configurations with random
multipliers, so it covers the complete Newton Jacobian: stiffness of forces, constraint Jacobian
and the geometric stiffness d(Phi_q^T lam)/dq, on the rotation group.
"""
import numpy as np
import pytest

from poise.elements.registry import element_types, fd_cases
from poise.model.compile import compile_model

from support.builders import stable_seed
from support.fd import fd_check, perturbed_state, two_body_deck
from support.paths import ROOT


#: every FD case every registered element type declares (poise.elements.registry)
CASES = [(c, pb) for c in fd_cases() for pb in c.point_b]


@pytest.mark.parametrize("case,point_b", CASES, ids=[f"{c.name}-{pb}" for c, pb in CASES])
def test_element_jacobian(case, point_b):
    """Each element of the case between two bodies and between a body and ground."""
    seed = case.seed if case.seed is not None else (case.name, point_b)
    rng = np.random.default_rng(stable_seed(*seed))
    d = two_body_deck(rng, point_b)
    for k, (tag, attrs) in enumerate(case.elements):
        for n, pair in enumerate(case.pairs):    # () with marker_attrs (): no markers, no id
            ids = {"id": k + 1 + 10 * n} if case.marker_attrs else {}
            d.add(tag, **ids, **dict(zip(case.marker_attrs, pair)), **attrs)
    if case.opposite_z:   # z axes down the shafts: opposite ways (else an error)
        _cv_convention(d, list(case.pairs))
    m = compile_model(d.spec)
    fd_check(m, perturbed_state(m, rng))


@pytest.mark.parametrize("et", element_types(), ids=lambda et: et.name)
def test_every_element_type_has_a_jacobian_check(et):
    """A registered element type declares FD cases (run above) or names the test module that
    checks its Jacobian (set-ups a two-body deck cannot express: motions, curves, ...)."""
    assert list(et.fd_cases()) or (et.fd_tests and (ROOT / et.fd_tests).is_file()), \
        f"element type {et.name!r} has no finite-difference Jacobian check"


def _cv_convention(d, pairs):
    """Turn each J marker by pi about its x axis when its z axis points the I marker's way."""
    mk = {e.attrs["id"]: e.attrs for e in d.spec.model if e.tag == "Reference_Marker"}
    R = {k: np.array([[mk[k][f"a{i}{j}"] for j in range(3)] for i in range(3)])
         for k in {m for p in pairs for m in p}}
    for i, j in pairs:
        if R[i][:, 2] @ R[j][:, 2] > 0:
            Rj = R[j] @ np.diag([1.0, -1.0, -1.0])
            mk[j].update({f"a{r}{c}": float(Rj[r, c]) for r in range(3) for c in range(3)})


def test_vector_onebody_jacobian():
    rng = np.random.default_rng(5)
    d = two_body_deck(rng)
    d.add("Force_Vector_OneBody", id=1, type="FORCEANDTORQUE", marker_id=21, ref_marker_id=31,
          fx_expression=1.0, fy_expression=-2.0, fz_expression=0.5, tx_expression=0.3,
          ty_expression=0.2, tz_expression=-0.1)
    d.add("Force_Gravity", grav_x=0.0, grav_y=-9.81, grav_z=1.0)
    m = compile_model(d.spec)
    fd_check(m, perturbed_state(m, rng))
