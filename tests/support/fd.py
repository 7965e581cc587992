"""Finite-difference checks of the complete Newton Jacobian, shared by the element tests:
:func:`fd_check` (every coordinate and multiplier column against central differences on the
rotation group), a random two-body deck and state to run it on, and :func:`check_full_jacobian`
(the same check for the reaction-reading expression forces, with a test that the reaction
coupling is really present)."""
import numpy as np

from poise.model.evaluate import evaluate
from support.builders import DeckBuilder, random_rotation


def fd_check(model, state, h=1e-6, tol=2e-6):
    ev = model.evaluate(state, need_jac=True)
    # the constraint values alone (families' ``values``, used by projections) are the same
    phi_only = evaluate(model, state, "phi")
    assert np.allclose(phi_only, ev.phi, rtol=1e-12, atol=1e-12 * max(1.0, np.abs(ev.phi).max(initial=0.0)))
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


def two_body_deck(rng, point_b=False):
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


def perturbed_state(model, rng):
    st = model.initial_state()
    st = model.retract(st, rng.normal(scale=0.3, size=model.nq))
    st.lam = rng.normal(size=model.nc)
    return st


def _dense(J):
    return np.asarray(J.toarray() if hasattr(J, "toarray") else J)


def _central_differences(m, st, h=1e-6):
    """(N, N) central differences of ``[r; phi]`` along every coordinate (``retract``) and
    multiplier."""
    fd = np.zeros((m.N, m.N))
    for k in range(m.N):
        out = []
        for sgn in (1.0, -1.0):
            dq, dl = np.zeros(m.nq), np.zeros(m.nc)
            if k < m.nq:
                dq[k] = sgn * h
            else:
                dl[k - m.nq] = sgn * h
            ev = m.evaluate(m.retract(st, dq, dl), need_jac=False)
            out.append(np.r_[ev.r, ev.phi])
        fd[:, k] = (out[0] - out[1]) / (2 * h)
    return fd


def _reader_rows(m):
    rd = np.zeros(m.N, bool)
    for f in m.families:
        if getattr(f, "reads_reactions", False):
            g = f.gcol[:, :6 * f.K]
            rd[g[g >= 0]] = True
    return rd


def check_full_jacobian(m, st, tol=1e-7):
    """The whole KKT Jacobian (coordinate and multiplier columns) against central differences;
    returns the relative errors (coordinate columns, multiplier columns)."""
    J = _dense(m.evaluate(st).J)
    fd = _central_differences(m, st)
    scale = np.abs(J).max()
    err_q = np.abs(J[:, :m.nq] - fd[:, :m.nq]).max() / scale
    err_l = np.abs(J[:, m.nq:] - fd[:, m.nq:]).max() / scale
    assert err_q < tol and err_l < tol, (err_q, err_l)
    # the readers' rows carry a real coupling through the channels: without it (the readers'
    # own kinematics and the constraint transpose only) the coordinate columns would be off
    rd = _reader_rows(m)
    assert np.abs(J[rd, m.nq:]).max() > 1e-2
    return err_q, err_l
