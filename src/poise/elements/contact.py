"""``Force_Contact`` between analytic primitives, IMPACT normal law (statics: no damping, no
friction).

One instance = one potential contact point between a geometry on the body of marker I and one on
the body of marker J (two-body slot layout of :mod:`poise.elements.forces`). Each geometry is a
marker plus an offset ``o`` in the marker's axes (centre ``c = P + A o``).

Pair kinds SPHERE_PLANE, SPHERE_SPHERE, SPHERE_BOX and CORNER_PLANE, the smoothed IMPACT
normal law and the complex-step Jacobian: :class:`ContactForce`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from poise.elements.context import GLOBAL
from poise.elements.forces import N_SLOTS, S_PI, S_PJ, S_XI, S_XJ, S_YI, S_YJ, S_ZI, S_ZJ, \
    TwoBodyForce
from poise.elements.kernel import slot_kinematics
from poise.elements.registry import ElementType, OutputGroup, kernel_potential, static


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


@dataclass(frozen=True, eq=False, kw_only=True)
class ContactForce(TwoBodyForce):
    """Parameters (n,): ``kind``, ``rI``, ``rJ``, ``k``, ``e``, ``ds``; (n,3): ``oI``, ``oJ``,
    ``half`` (box half lengths on J for SPHERE_BOX); ``contact_ids`` (n,) the Force_Contact id
    of each contact point.

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

    kind: np.ndarray
    rI: np.ndarray
    rJ: np.ndarray
    k: np.ndarray
    e: np.ndarray
    ds: np.ndarray
    oI: np.ndarray
    oJ: np.ndarray
    half: np.ndarray
    contact_ids: np.ndarray

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

    def contact_state(self, Y):
        """Force on the I geometry's body (n, 3) and penetration (n,) (negative: a gap)."""
        nI = Y.shape[0]
        F, _, delta = self._ft(Y.reshape(nI, -1), np.arange(nI))
        return np.real(F), delta

    def potential_energy(self, kin, ctx):
        Y = kin.Y
        idx = np.arange(Y.shape[0])
        delta, _, _ = self.geometry(Y, idx)
        return law_energy(np.real(delta), self.k, self.e, self.ds)


# ----------------------------------- compile
def attr_of(el, *names, default=None):
    low = {str(k).lower(): v for k, v in el.attrs.items()}
    for n in names:
        if n in low and low[n] is not None:
            return low[n]
    return default


def _ids(v, el=None, attr=None, pc=None):
    """Id list of a ``*_graphics_id`` attribute; bad entries are reported (located) and skipped."""
    if v is None:
        return []
    items = [v] if isinstance(v, (int, float)) else str(v).replace(",", " ").split()
    out = []
    for t in items:
        try:
            f = float(t)
            if not np.isfinite(f) or f != int(f):
                raise ValueError
            out.append(int(f))
        except (TypeError, ValueError, OverflowError):
            if pc is not None:
                pc.error(el.loc, f"not a list of ids; expected integers, got {v!r}", attr)
            return []
    return out


def _real(el, names, default, pc, what=None):
    """A finite number from the first present attribute of ``names`` (located error otherwise)."""
    v = attr_of(el, *names, default=default)
    try:
        f = float(v)
        if not np.isfinite(f):
            raise ValueError
        return f
    except (TypeError, ValueError, OverflowError):
        pc.error(el.loc, f"attribute is not a finite number; expected a real number, got {v!r}",
                 what or names[0])
        return float(default) if default is not None else 0.0


def compile_contacts(spec, ctx):
    """``Post_Graphic`` forms read (attribute names case-insensitive):

    * sphere: ``type="Sphere"`` with ``center_marker_id`` (also ``cm_id``, ``marker_id``) and
      ``radius``;
    * box: ``type="BoxDefinedFromCenter"`` (``center_marker_id``) or ``type="BoxDefinedFromCorner"``
      (``corner_marker_id``: the box spans +x/+y/+z of that marker) with ``length_x/y/z`` (full
      lengths); ``type="Box"`` is read as the centre form;
    * plane: ``type="Plane"`` with ``ref_marker_id`` (also ``rm_id``, ``marker_id``,
      ``center_marker_id``): the marker's x-y plane, outward normal +z, material on the -z side
      (unbounded: ``x_min``... extents are ignored).

    Pairs: sphere-plane, sphere-sphere, sphere-box, box-plane (8 corner contacts); other pairs are a
    deck error. ``cnf_type`` must be ``IMPACT``; ``stiffness``, ``exponent`` (default 1.5), ``dmax``
    (smoothing length for exponent <= 1); damping and friction act only on velocities, so they vanish
    in statics. Per-frame outputs ``contacts/id``, ``contacts/kind``, ``contacts/force`` (force on the
    I geometry's body, global), ``contacts/penetration`` (negative = gap) come from a frame hook.

    Compile ``Force_Contact`` (IMPACT law) between ``Post_Graphic`` analytic primitives.

    Supported ``Post_Graphic`` forms: sphere, box (centre or corner form), plane; supported pairs:
    sphere-plane, sphere-sphere, sphere-box, box-plane (8 corner contacts), any other a deck error.
    Statics: only the IMPACT normal law acts (damping and friction act on velocities). The forms and
    attributes read: :func:`compile_contacts`; per-frame outputs ``contacts/*``: a frame hook.
    """
    els = list(spec.elements("Force_Contact"))
    if not els:
        return
    marker = ctx.marker
    pc = ctx.pc
    graphics = {e.id: e for e in spec.elements("Post_Graphic")}
    rows = []          # dict per instance
    L = ctx.L

    def geom(gid, el, attr):
        g = graphics.get(gid)
        if g is None:
            pc.error(el.loc, f"Post_Graphic {gid} does not exist; expected a Post_Graphic id", attr)
            return None
        t = str(attr_of(g, "type", default="")).upper()
        if t == "SPHERE":
            mk = attr_of(g, "center_marker_id", "cm_id", "marker_id")
            return dict(kind="sphere", m=marker(g, _key(g, mk, "center_marker_id", "cm_id", "marker_id")),
                        r=_real(g, ("radius",), 0.0, pc), o=np.zeros(3))
        if t in ("BOX", "BOXDEFINEDFROMCENTER", "BOXDEFINEDFROMCORNER"):
            lens = np.array([_real(g, (f"length_{c}",), 0.0, pc) for c in "xyz"])
            if t == "BOXDEFINEDFROMCORNER":
                mk = _key(g, None, "corner_marker_id", "marker_id")
                o = lens / 2
            else:
                mk = _key(g, None, "center_marker_id", "cm_id", "marker_id")
                o = np.zeros(3)
            return dict(kind="box", m=marker(g, mk), half=lens / 2, o=o)
        if t == "PLANE":
            mk = _key(g, None, "ref_marker_id", "rm_id", "marker_id", "center_marker_id")
            return dict(kind="plane", m=marker(g, mk), o=np.zeros(3))
        pc.error(g.loc, f"Post_Graphic type {t or '?'} is not supported for contact; expected "
                 "Sphere, BoxDefinedFromCenter, BoxDefinedFromCorner or Plane", "type")
        return None

    for el in els:
        law = str(attr_of(el, "cnf_type", default="IMPACT")).upper()
        if law != "IMPACT":
            pc.error(el.loc, f"cnf_type {law} is not supported; expected IMPACT", "cnf_type")
            continue
        k = _real(el, ("stiffness",), 0.0, pc)
        e = _real(el, ("exponent",), 1.5, pc)
        dmax = _real(el, ("dmax",), 0.0, pc)
        ds = dmax if dmax > 0 else 1e-3 * L
        gi = [geom(g, el, "i_graphics_id")
              for g in _ids(attr_of(el, "i_graphics_id"), el, "i_graphics_id", pc)]
        gj = [geom(g, el, "j_graphics_id")
              for g in _ids(attr_of(el, "j_graphics_id"), el, "j_graphics_id", pc)]
        if not gi or not gj:
            pc.error(el.loc, "contact needs i_graphics_id and j_graphics_id; expected "
                     "Post_Graphic ids", "i_graphics_id")
            continue
        base = dict(k=k, e=e, ds=ds, cid=el.id, el=el)
        for a in gi:
            for c in gj:
                if a is None or c is None:
                    continue
                pair = (a["kind"], c["kind"])
                if pair in (("plane", "sphere"), ("box", "sphere"), ("plane", "box")):
                    a, c = c, a
                    pair = (a["kind"], c["kind"])
                z3 = np.zeros(3)
                if pair == ("sphere", "plane"):
                    rows.append(dict(base, kind=SPHERE_PLANE, I=a["m"], J=c["m"], rI=a["r"],
                                     rJ=0.0, oI=a["o"], oJ=z3, half=z3))
                elif pair == ("sphere", "sphere"):
                    rows.append(dict(base, kind=SPHERE_SPHERE, I=a["m"], J=c["m"], rI=a["r"],
                                     rJ=c["r"], oI=a["o"], oJ=c["o"], half=z3))
                elif pair == ("sphere", "box"):
                    rows.append(dict(base, kind=SPHERE_BOX, I=a["m"], J=c["m"], rI=a["r"],
                                     rJ=0.0, oI=a["o"], oJ=c["o"], half=c["half"]))
                elif pair == ("box", "plane"):
                    for sx in (-1, 1):
                        for sy in (-1, 1):
                            for sz in (-1, 1):
                                o = a["o"] + np.array([sx, sy, sz]) * a["half"]
                                rows.append(dict(base, kind=CORNER_PLANE, I=a["m"], J=c["m"],
                                                 rI=0.0, rJ=0.0, oI=o, oJ=z3, half=z3))
                else:
                    pc.error(el.loc, f"contact between {pair[0]} and {pair[1]} is not supported; "
                             "expected sphere-plane, sphere-sphere, sphere-box or box-plane",
                             "i_graphics_id")
        ctx.effect("Force_Contact:IMPACT")
    if not rows:
        return
    n = len(rows)
    ctx.add_family(ContactForce.build(
        "contact:IMPACT", np.array([r["I"] for r in rows]), np.array([r["J"] for r in rows]),
        np.full(n, GLOBAL), np.arange(n), element_locs=[r["el"].loc for r in rows],
        kind=np.array([r["kind"] for r in rows]).astype(int), rI=[r["rI"] for r in rows],
        rJ=[r["rJ"] for r in rows], k=[r["k"] for r in rows], e=[r["e"] for r in rows],
        ds=[r["ds"] for r in rows], oI=np.array([r["oI"] for r in rows]),
        oJ=np.array([r["oJ"] for r in rows]), half=np.array([r["half"] for r in rows]),
        contact_ids=np.array([r["cid"] for r in rows], int)))
    ctx.add_frame_hook(contact_frame_hook)


def _key(g, _unused, *names):
    low = {str(k).lower(): v for k, v in g.attrs.items()}
    for nm in names:
        if low.get(nm) is not None:
            # Builder.mk reads el.attrs[attr]: return the attribute name as written
            for k in g.attrs:
                if str(k).lower() == nm:
                    return k
    return names[0]


def contact_frame_hook(model, state):
    """Per-frame contact outputs (one row per contact instance)."""
    fam = next(f for f in model.families if isinstance(f, ContactForce))
    P, A, pos = model.marker_kinematics(state)
    kin = slot_kinematics(fam.markers, fam.slot_ml, fam.slot_kind, P, A, model.marker_body, pos)
    F, delta = fam.contact_state(kin.Y)
    return {"contacts/id": fam.contact_ids,
            "contacts/kind": np.array([KIND_NAMES[k] for k in fam.kind], dtype=str),
            "contacts/force": F, "contacts/penetration": delta}


ELEMENTS = (ElementType(
    "contacts", ("Force_Contact",), compile_contacts,
    rank=80,                    # contact families after the expression forces
    kernels=lambda: (ContactForce,), tileable=lambda: (ContactForce,),
    potential_energy=kernel_potential, time_dependent=static,
    outputs=(OutputGroup("contacts", "Ct", "contact", "contact point",
                         "`Force_Contact`", ("Force_Contact",),
                         ("id", "label", "kind", "force", "penetration"), model_ids=False),),
    fd_tests="tests/reference/test_contact.py"),)
