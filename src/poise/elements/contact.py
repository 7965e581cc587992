"""``Force_Contact`` between analytic primitives, IMPACT normal law (statics: no damping, no
friction).

One instance = one potential contact point between a geometry on the body of marker I and one on
the body of marker J (two-body slot layout of :mod:`poise.elements.forces`). Each geometry is a
marker plus an offset ``o`` in the marker's axes (centre ``c = P + A o``).

Pair kinds SPHERE_PLANE, SPHERE_SPHERE, SPHERE_BOX and CORNER_PLANE, the smoothed IMPACT
normal law and the complex-step Jacobian: :class:`ContactForce`.
"""
from __future__ import annotations

import numpy as np

from poise.elements.forces import N_SLOTS, S_PI, S_PJ, S_XI, S_XJ, S_YI, S_YJ, S_ZI, S_ZJ, \
    TwoBodyForce

SPHERE_PLANE, SPHERE_SPHERE, SPHERE_BOX, CORNER_PLANE = 0, 1, 2, 3
KIND_NAMES = ("sphere-plane", "sphere-sphere", "sphere-box", "corner-plane")
_CS = 1e-30


def _dot(a, b):
    return np.sum(a * b, axis=-1)


def normal_law(delta, k, e, ds):
    """IMPACT static force magnitude (works on complex ``delta`` for the complex step)."""
    dr = np.real(delta)
    f = np.zeros(delta.shape, dtype=delta.dtype)
    on = dr > 0
    smooth = on & (e <= 1.0) & (dr < ds)
    plain = on & ~smooth
    if plain.any():
        f[plain] = k[plain] * delta[plain] ** e[plain]
    if smooth.any():
        x = delta[smooth] / ds[smooth]
        ee = e[smooth]
        f[smooth] = k[smooth] * ds[smooth] ** ee * ((3 - ee) * x ** 2 + (ee - 2) * x ** 3)
    return f


def law_energy(delta, k, e, ds):
    """Potential of the normal law, integral of f from 0 to delta."""
    dr = np.asarray(delta, float)
    V = np.zeros_like(dr)
    on = dr > 0
    smooth = on & (e <= 1.0) & (dr < ds)
    plain = on & ~smooth
    sm_full = on & (e <= 1.0) & (dr >= ds)
    ee = e
    Vs = lambda x, i: k[i] * ds[i] ** (ee[i] + 1) * ((3 - ee[i]) * x ** 3 / 3 + (ee[i] - 2) * x ** 4 / 4)  # noqa: E731
    if smooth.any():
        V[smooth] = Vs(dr[smooth] / ds[smooth], smooth)
    if plain.any():
        V[plain] = k[plain] * dr[plain] ** (e[plain] + 1) / (e[plain] + 1)
    if sm_full.any():
        # smoothed part up to ds, then the power law from ds
        i = sm_full
        V[i] = Vs(np.ones(i.sum()), i) + k[i] / (e[i] + 1) * (dr[i] ** (e[i] + 1) - ds[i] ** (e[i] + 1))
    return V


class ContactForce(TwoBodyForce):
    """Parameters (n,): ``kind``, ``rI``, ``rJ``, ``k``, ``e``, ``ds``; (n,3): ``oI``, ``oJ``,
    ``half`` (box half lengths on J for SPHERE_BOX).

    * ``SPHERE_PLANE`` (0): sphere (radius ``rI``) on I, plane = J's x-y plane, outward normal +z_J,
      material on the -z side. ``delta = rI - (cI - P_J) . z_J``, ``F = f z_J`` through the centre.
    * ``SPHERE_SPHERE`` (1): ``delta = rI + rJ - |cI - cJ|``, ``F = f n`` along the centre line.
    * ``SPHERE_BOX`` (2): box on J (half lengths ``a``), ``e`` = sphere centre minus the closest box
      point, ``delta = rI - |e|``, ``F = f e/|e|`` through the centre (a centre inside the box gives no
      force: deep penetration is outside the analytic model).
    * ``CORNER_PLANE`` (3): one corner ``p = P_I + A_I oI`` of a box on I against J's plane:
      ``delta = -(p - P_J) . z_J``, ``F = f z_J`` at the corner (a box-plane pair = 8 instances).

    Normal law (IMPACT, static part): ``f = k delta^e`` for ``delta > 0``, 0 otherwise. For ``e > 1``
    this is C1 at zero penetration. For ``e <= 1`` it is replaced below ``delta_s`` (the deck's ``dmax``,
    or 1e-3 L when dmax is absent) by ``k delta_s^e (a x^2 + b x^3)``, ``x = delta/delta_s``,
    ``a = 3 - e``, ``b = e - 2`` (value and slope match at ``delta_s``, zero value and slope at 0), so
    Newton always sees a C1 force.

    Jacobian: complex-step differentiation of the force and torque with respect to the 33 slot
    components (``h = 1e-30``), exact to rounding (no truncation error); branch decisions use real
    parts. Only instances in contact are differentiated.
    """

    def geometry(self, Y, idx):
        """(delta (m,), direction n (m,3), application point (m,3)) for instances ``idx``.
        ``Y`` (m, 11, 3), real or complex."""
        kind = self.kind[idx]
        PI, PJ = Y[:, S_PI], Y[:, S_PJ]
        AI = np.stack([Y[:, S_XI], Y[:, S_YI], Y[:, S_ZI]], axis=2)
        AJ = np.stack([Y[:, S_XJ], Y[:, S_YJ], Y[:, S_ZJ]], axis=2)
        cI = PI + np.einsum("nij,nj->ni", AI, self.oI[idx])
        cJ = PJ + np.einsum("nij,nj->ni", AJ, self.oJ[idx])
        zJ = Y[:, S_ZJ]
        m = Y.shape[0]
        delta = np.zeros(m, dtype=Y.dtype)
        n = np.zeros((m, 3), dtype=Y.dtype)
        pt = cI.copy()
        rI, rJ = self.rI[idx], self.rJ[idx]
        s = kind == SPHERE_PLANE
        if s.any():
            delta[s] = rI[s] - _dot(cI[s] - PJ[s], zJ[s])
            n[s] = zJ[s]
        s = kind == CORNER_PLANE
        if s.any():
            delta[s] = -_dot(cI[s] - PJ[s], zJ[s])
            n[s] = zJ[s]
        s = kind == SPHERE_SPHERE
        if s.any():
            d = cI[s] - cJ[s]
            L = np.sqrt(_dot(d, d))
            delta[s] = rI[s] + rJ[s] - L
            n[s] = d / np.where(np.real(L) > 0, L, 1.0)[:, None]
        s = kind == SPHERE_BOX
        if s.any():
            d = cI[s] - cJ[s]
            A = AJ[s]
            sl = np.einsum("nik,ni->nk", A, d)                      # centre in box axes
            a = self.half[idx][s]
            out = np.abs(np.real(sl)) > a
            cl = np.where(out, np.sign(np.real(sl)) * a, sl)
            e = np.einsum("nik,nk->ni", A, sl - cl)
            dist = np.sqrt(_dot(e, e))
            ok = np.real(dist) > 0
            delta[s] = np.where(ok, rI[s] - dist, -1.0)
            n[s] = e / np.where(ok, dist, 1.0)[:, None]
        return delta, n, pt

    def _ft(self, Yf, idx):
        Y = Yf.reshape(-1, N_SLOTS, 3)
        delta, n, pt = self.geometry(Y, idx)
        f = normal_law(delta, self.k[idx], self.e[idx], self.ds[idx])
        F = f[:, None] * n
        T = np.cross(pt - Y[:, S_PI], F)
        return F, T, np.real(delta)

    def compute(self, Y, ctx, need_jac):
        nI = Y.shape[0]
        Yf = Y.reshape(nI, -1)
        idx = np.arange(nI)
        F, T, delta = self._ft(Yf, idx)
        F, T = np.real(F), np.real(T)
        self.last_delta = delta
        self.last_force = F
        dF = dT = None
        if need_jac:
            W = 3 * N_SLOTS
            dF = np.zeros((nI, 3, W))
            dT = np.zeros((nI, 3, W))
            act = np.nonzero(delta > 0)[0]
            if len(act):
                m = len(act)
                Yc = np.repeat(Yf[act].astype(complex)[:, None, :], W, axis=1)   # (m, W, W)
                Yc[:, np.arange(W), np.arange(W)] += 1j * _CS
                rep = np.repeat(act, W)
                Fc, Tc, _ = self._ft(Yc.reshape(m * W, W), rep)
                dF[act] = np.swapaxes(np.imag(Fc).reshape(m, W, 3), 1, 2) / _CS
                dT[act] = np.swapaxes(np.imag(Tc).reshape(m, W, 3), 1, 2) / _CS
        return F, T, dF, dT

    def potential_energy(self, kin, ctx):
        Y = kin.Y
        idx = np.arange(Y.shape[0])
        delta, _, _ = self.geometry(Y, idx)
        return law_energy(np.real(delta), self.k, self.e, self.ds)
