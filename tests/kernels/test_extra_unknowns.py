"""Scalar unknowns appended to the coordinates (State.extra): kernel plumbing, FD Jacobian, solve.

A synthetic constraint family "point on a straight line through J along x_J with parameter u"
(Phi = P_I - P_J - u x_J) exercises every scalar-column piece: phi_s, G_ys, rho_s.
"""
import numpy as np

import poise.model.compile as C
from poise.elements.base import ConstraintFamily
from poise.elements.registry import ElementType, static, workless
from poise.model.compile import compile_model

from support.builders import DeckBuilder, random_rotation
from support.fd import fd_check


I3 = np.eye(3)


class PointOnLine(ConstraintFamily):
    def constraints(self, kin, lam, ctx):
        Y = kin.Y
        u = ctx.extra[self.scols[:, 0]]
        n = self.n
        phi = Y[:, 0] - Y[:, 1] - u[:, None] * Y[:, 2]
        phy = np.zeros((n, 3, 9))
        phy[:, :, 0:3] = I3
        phy[:, :, 3:6] = -I3
        phy[:, :, 6:9] = -u[:, None, None] * I3
        ext = {"phi_s": -Y[:, 2][:, :, None],
               "G_ys": np.zeros((n, 9, 1))}
        ext["G_ys"][:, 6:9, 0] = -lam
        return phi, phy, None, ext


def _compiler(spec, ctx):
    I = ctx.geometry.marker_index[21]
    J = ctx.geometry.marker_index[11]
    u = ctx.add_extra("<test> u", 0.3)
    crow = np.array([[ctx.add_row(spec.model[0], e, "trans", "test", 0) for e in "xyz"]])
    ctx.add_family(PointOnLine(name="test:line", markers=np.array([[I, J]]),
                               slot_ml=np.array([0, 1, 1]), slot_kind=np.array([[0, 0, 1]]),
                               owner=np.array([0]), m=3, crow=crow, scols=np.array([[u]])))


#: the synthetic element type (its kernel and capabilities declared, as every type's are)
TEST_TYPE = ElementType("test", (), _compiler, rank=1000, kernels=lambda: (PointOnLine,),
                        potential_energy=workless, time_dependent=static)


def _deck(rng):
    d = DeckBuilder().ground()
    d.body(2, 200, rng.normal(size=3), random_rotation(rng), mass=2.0, inertia=(1, 2, 3))
    d.marker(21, 2, rng.normal(size=3), random_rotation(rng))
    d.marker(11, 1, rng.normal(size=3), random_rotation(rng))
    return d


def test_scalar_unknown_jacobian(monkeypatch):
    orig = C.element_types
    monkeypatch.setattr(C, "element_types", lambda: orig() + (TEST_TYPE,))
    rng = np.random.default_rng(3)
    d = _deck(rng)
    d.add("Force_SpringDamper", id=1, type="TRANSLATIONAL", i_marker_id=21, j_marker_id=11,
          stiffness=5.0, damping=0.0, length=0.5, preload=0.0)
    m = compile_model(d.spec)
    assert m.n_extra == 1 and m.nq == 7
    st = m.initial_state()
    st = m.retract(st, rng.normal(scale=0.3, size=m.nq))
    st.lam = rng.normal(size=m.nc)
    fd_check(m, st)


def test_scalar_unknown_solve(monkeypatch):
    # a body whose marker 21 slides on a frictionless line through marker 11 (axis x_J), pulled
    # by gravity: it comes to rest where the line's lowest point ... the line is straight, so the
    # marker slides to where the spring to a ground anchor balances gravity along the line.
    orig = C.element_types
    monkeypatch.setattr(C, "element_types", lambda: orig() + (TEST_TYPE,))
    from poise.app.runner import AnalysisRequest
    from poise.solvers.settings import StaticSettings
    from poise.solvers.driver import Driver
    d = DeckBuilder().ground()
    d.body(2, 200, (0.3, 0.0, 0.0), None, mass=1.0, point=True)
    d.marker(21, 2, (0.3, 0.0, 0.0))
    d.marker(11, 1, (0.0, 0.0, 0.0))            # line along global x
    d.marker(12, 1, (2.0, 0.0, 0.0))            # spring anchor on the line
    d.add("Force_SpringDamper", id=1, type="TRANSLATIONAL", i_marker_id=21, j_marker_id=12,
          stiffness=10.0, damping=0.0, length=0.5, preload=0.0)
    m = compile_model(d.spec)
    req = AnalysisRequest(simulate=None, kind="static",
                          settings=StaticSettings(method="FIM_S", max_imbalance=1e-10,
                                                  max_error=1e-10))
    st, ar = Driver(m, req).run(m.initial_state())
    assert ar.converged
    # spring at rest: the point sits 0.5 from the anchor, u = 1.5
    assert abs(st.extra[0] - 1.5) < 1e-9
    np.testing.assert_allclose(st.pos[0], [1.5, 0, 0], atol=1e-9)
