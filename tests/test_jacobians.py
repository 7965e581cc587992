"""Every element family's analytic Jacobian against central finite differences.

The check runs on random (non-equilibrium, constraint-violating) configurations with random
multipliers, so it covers the complete Newton Jacobian: stiffness of forces, constraint Jacobian
and the geometric stiffness d(Phi_q^T lam)/dq, on the rotation group.
"""
import numpy as np
import pytest

from builders import DeckBuilder, random_rotation, stable_seed
from poise.elements.constraints import JOINT_EQUATIONS
from poise.model.compile import compile_model


def _fd_check(model, state, h=1e-6, tol=2e-6):
    ev = model.evaluate(state, need_jac=True)
    J = ev.J.toarray() if hasattr(ev.J, "toarray") else np.asarray(ev.J)
    F0 = np.concatenate([ev.r, ev.phi])
    N = model.N
    Jfd = np.zeros((N, N))
    for i in range(model.nq):
        e = np.zeros(model.nq)
        e[i] = h
        sp = model.retract(state, e)
        sm = model.retract(state, -e)
        fp = model.evaluate(sp, need_jac=False)
        fm = model.evaluate(sm, need_jac=False)
        Jfd[:, i] = (np.concatenate([fp.r, fp.phi]) - np.concatenate([fm.r, fm.phi])) / (2 * h)
    for j in range(model.nc):
        s2 = state.copy()
        s2.lam[j] += h
        s3 = state.copy()
        s3.lam[j] -= h
        fp = model.evaluate(s2, need_jac=False)
        fm = model.evaluate(s3, need_jac=False)
        Jfd[:, model.nq + j] = (np.concatenate([fp.r, fp.phi]) - np.concatenate([fm.r, fm.phi])) / (2 * h)
    scale = max(1.0, np.abs(J).max())
    err = np.abs(J - Jfd).max() / scale
    assert err < tol, f"max rel error {err:.3e}\n{np.round(J - Jfd, 6)}"
    assert np.abs(F0).max() > 0  # a real, non-trivial state
    return err


def _two_body_deck(rng, point_b=False):
    d = DeckBuilder().ground()
    d.body(2, 200, rng.normal(size=3), random_rotation(rng), mass=2.0, inertia=(1, 2, 3))
    d.body(3, 300, rng.normal(size=3), None if point_b else random_rotation(rng), mass=1.5,
           inertia=(2, 1, 1.5), point=point_b)
    d.marker(21, 2, rng.normal(size=3), random_rotation(rng))
    d.marker(22, 2, rng.normal(size=3), random_rotation(rng))
    d.marker(31, 3, rng.normal(size=3), random_rotation(rng))
    d.marker(32, 3, rng.normal(size=3), random_rotation(rng))
    d.marker(11, 1, rng.normal(size=3), random_rotation(rng))
    return d


def _perturbed_state(model, rng):
    st = model.initial_state()
    st = model.retract(st, rng.normal(scale=0.3, size=model.nq))
    st.lam = rng.normal(size=model.nc)
    return st


@pytest.mark.parametrize("jtype", sorted(t for t, e in JOINT_EQUATIONS.items() if e))
@pytest.mark.parametrize("tag", ["Constraint_Joint", "Constraint_Jprim"])
def test_joint_jacobian(jtype, tag):
    rng = np.random.default_rng(stable_seed(jtype, tag))
    d = _two_body_deck(rng)
    d.add(tag, id=1, type=jtype, i_marker_id=21, j_marker_id=31)
    d.add(tag, id=2, type=jtype, i_marker_id=22, j_marker_id=11)   # J on ground
    if jtype == "CONSTANT_VELOCITY":    # z axes down the shafts: opposite ways (else an error)
        _cv_convention(d, [(21, 31), (22, 11)])
    m = compile_model(d.spec)
    _fd_check(m, _perturbed_state(m, rng))


def _cv_convention(d, pairs):
    """Turn each J marker by pi about its x axis when its z axis points the I marker's way."""
    mk = {e.attrs["id"]: e.attrs for e in d.spec.model if e.tag == "Reference_Marker"}
    R = {k: np.array([[mk[k][f"a{i}{j}"] for j in range(3)] for i in range(3)])
         for k in {m for p in pairs for m in p}}
    for i, j in pairs:
        if R[i][:, 2] @ R[j][:, 2] > 0:
            Rj = R[j] @ np.diag([1.0, -1.0, -1.0])
            mk[j].update({f"a{r}{c}": float(Rj[r, c]) for r in range(3) for c in range(3)})


def _force_decks():
    yield "spring_translational", [("Force_SpringDamper", dict(type="TRANSLATIONAL", stiffness=30.0, damping=1.0, length=0.7, preload=2.0))]
    yield "spring_rotational", [("Force_SpringDamper", dict(type="ROTATIONAL", stiffness=30.0, damping=1.0, length=7.0, preload=2.0))]
    yield "bushing", [("Force_Bushing", dict(kx=10.0, ky=20.0, kz=30.0, ktx=4.0, kty=5.0, ktz=6.0, preload_x=1.0, preload_tz=2.0))]
    yield "scalar_force", [("Force_Scalar_TwoBody", dict(type="FORCE", val=3.0))]
    yield "scalar_force_action_only", [("Force_Scalar_TwoBody", dict(type="FORCE", val=3.0, is_action_only=True))]
    yield "scalar_torque", [("Force_Scalar_TwoBody", dict(type="TORQUE", val=3.0))]
    yield "vector_twobody", [("Force_Vector_TwoBody", dict(type="FORCEANDTORQUE", fx_expression=1.0, fy_expression=2.0, fz_expression=-3.0, tx_expression=0.5, ty_expression=-1.0, tz_expression=2.0, ref_marker_id=32))]


@pytest.mark.parametrize("name,elements", list(_force_decks()))
@pytest.mark.parametrize("point_b", [False, True])
def test_force_jacobian(name, elements, point_b):
    rng = np.random.default_rng(stable_seed(name, point_b))
    d = _two_body_deck(rng, point_b)
    for k, (tag, attrs) in enumerate(elements):
        jm = "j_floating_marker_id" if tag == "Force_Vector_TwoBody" else "j_marker_id"
        d.add(tag, id=k + 1, i_marker_id=21, **{jm: 31}, **attrs)
        d.add(tag, id=k + 11, i_marker_id=32, **{jm: 11}, **attrs)   # J on ground
    m = compile_model(d.spec)
    _fd_check(m, _perturbed_state(m, rng))


def test_vector_onebody_jacobian():
    rng = np.random.default_rng(5)
    d = _two_body_deck(rng)
    d.add("Force_Vector_OneBody", id=1, type="FORCEANDTORQUE", marker_id=21, ref_marker_id=31,
          fx_expression=1.0, fy_expression=-2.0, fz_expression=0.5, tx_expression=0.3,
          ty_expression=0.2, tz_expression=-0.1)
    d.add("Force_Gravity", grav_x=0.0, grav_y=-9.81, grav_z=1.0)
    m = compile_model(d.spec)
    _fd_check(m, _perturbed_state(m, rng))
