"""DeckSpec -> Model: resolve references to indices, lay out coordinates, build families.

Only element families present in the deck are compiled (a deck without ``Force_Gravity`` has no
gravity term in its loop); ``Model.active_effects`` lists what was compiled.
"""
from __future__ import annotations

import numpy as np

from poise.deck.spec import DeckSpec, Element, Expr
from poise.errors import ProblemCollector
from poise.families import constraints as C
from poise.families import forces as Fo
from poise.model import units as U
from poise.model.model import Model
from poise.model.rotation import from_313, from_euler_parameters, from_ypr, orthonormalize

_DCM = ("a00", "a10", "a20", "a01", "a11", "a21", "a02", "a12", "a22")
GLOBAL = 0  # compiled marker index of the global frame (marker id 0)


def _num(el: Element, name: str, default=None, pc: ProblemCollector | None = None):
    v = el.attrs.get(name, default)
    if isinstance(v, Expr):
        if pc is not None:
            pc.error(el.loc, f"expression {v.text!r} is not supported here yet; expected a number",
                     name)
        return default if default is not None else 0.0
    return v


def unit_info(spec: DeckSpec):
    """(mass_factor, description) from Param_Unit / UNITS (N-kg-m-s when absent)."""
    el = next((e for e in spec.model if e.tag in ("Param_Unit", "UNITS")), None)
    names = dict(U.DEFAULT)
    if el is None:
        f = 1.0
    else:
        for key in ("force", "mass", "length", "time"):
            v = el.attrs.get(f"{key}_unit", el.attrs.get(key))
            if v:
                names[key] = str(v).upper()
        if el.attrs.get("mass_mult_factor") is not None and not any(
                el.attrs.get(f"{k}_unit") or el.attrs.get(k) for k in names):
            f = float(el.attrs["mass_mult_factor"])
        else:
            f = U.mass_factor(names["force"], names["mass"], names["length"], names["time"])
    desc = " ".join(f"{k}={names[k]}" for k in ("force", "mass", "length", "time"))
    return f, desc


def _orientation(el: Element) -> np.ndarray | None:
    a = el.attrs
    if any(k in a for k in _DCM):
        M = np.array([[a.get("a00", 1.0), a.get("a01", 0.0), a.get("a02", 0.0)],
                      [a.get("a10", 0.0), a.get("a11", 1.0), a.get("a12", 0.0)],
                      [a.get("a20", 0.0), a.get("a21", 0.0), a.get("a22", 1.0)]], float)
        return orthonormalize(M)
    if any(k in a for k in ("e0", "e1", "e2", "e3")):
        return from_euler_parameters(a.get("e0", 1.0), a.get("e1", 0.0), a.get("e2", 0.0),
                                     a.get("e3", 0.0))
    if any(k in a for k in ("psi", "theta", "phi")):
        return from_313(a.get("psi", 0.0), a.get("theta", 0.0), a.get("phi", 0.0))
    if any(k in a for k in ("yaw", "pitch", "roll")):
        return from_ypr(a.get("yaw", 0.0), a.get("pitch", 0.0), a.get("roll", 0.0))
    return None


class _Builder:
    def __init__(self, spec: DeckSpec):
        self.spec = spec
        self.pc = ProblemCollector()
        self.effects: list[str] = []

    # ---------------------------------------------------------------- markers
    def markers(self):
        els = [e for e in self.spec.model if e.tag == "Reference_Marker"]
        byid = {e.id: e for e in els}
        glob: dict[int, tuple] = {}

        def resolve(mid, stack=()):
            if mid in glob:
                return glob[mid]
            el = byid[mid]
            p = np.array([_num(el, "pos_x", 0.0, self.pc), _num(el, "pos_y", 0.0, self.pc),
                          _num(el, "pos_z", 0.0, self.pc)], float)
            R = _orientation(el)
            rm = el.attrs.get("rm_id")
            if rm:
                if rm in stack or rm not in byid:
                    self.pc.error(el.loc, f"rm_id {rm} is circular or unknown; expected an "
                                  "existing marker", "rm_id")
                    glob[mid] = (p, np.eye(3) if R is None else R)
                    return glob[mid]
                pr, Rr = resolve(rm, stack + (mid,))
                p = pr + Rr @ p
                R = Rr if R is None else Rr @ R
            glob[mid] = (p, np.eye(3) if R is None else R)
            return glob[mid]

        for e in els:
            resolve(e.id)
        self.marker_els = els
        self.marker_glob = glob

    # ---------------------------------------------------------------- bodies
    def bodies(self, mfac):
        spec = self.spec
        rig = [e for e in spec.model if e.tag in ("Body_Rigid", "Body_Point")]
        moving = [e for e in rig if not (e.tag == "Body_Rigid" and e.attrs.get("isground"))]
        ground_ids = {e.id for e in rig if e.tag == "Body_Rigid" and e.attrs.get("isground")}
        self.body_index = {e.id: i for i, e in enumerate(moving)}
        self.ground_ids = ground_ids
        nb = len(moving)
        kind = np.array([0 if e.tag == "Body_Rigid" else 1 for e in moving], int)
        pos = np.zeros((nb, 3))
        rot = np.tile(np.eye(3), (nb, 1, 1))
        mass = np.zeros(nb)
        inertia = np.zeros((nb, 3, 3))
        off = np.zeros(nb, int)
        coord = []
        o = 0
        for i, e in enumerate(moving):
            off[i] = o
            cg = e.attrs.get("cg_id")
            if cg not in self.marker_glob:
                self.pc.error(e.loc, f"cg_id {cg} is not a Reference_Marker; expected a marker id",
                              "cg_id")
                p, R = np.zeros(3), np.eye(3)
            else:
                p, R = self.marker_glob[cg]
            pos[i] = p
            if kind[i] == 0:
                rot[i] = R
            m = float(_num(e, "mass", 0.0, self.pc) or 0.0)
            mass[i] = m * mfac
            names = ["Fx", "Fy", "Fz"] + (["Tx", "Ty", "Tz"] if kind[i] == 0 else [])
            for nm in names:
                coord.append(f"{e.loc.prefix()[:-1]} {nm}")
            o += 6 if kind[i] == 0 else 3
            if kind[i] == 0:
                inertia[i] = self._inertia(e, m, p, R) * mfac
        self.moving = moving
        self.nq = o
        return dict(body_id=np.array([e.id for e in moving], int),
                    body_label=[str(e.attrs.get("label", "")) for e in moving],
                    body_kind=kind, body_mass=mass, body_inertia=inertia, body_off=off,
                    init_pos=pos, init_rot=rot, coord_info=coord)

    def _inertia(self, e, m, p_cg, R_cg):
        a = e.attrs
        keys = ("inertia_xx", "inertia_yy", "inertia_zz", "inertia_xy", "inertia_yz", "inertia_xz")
        if not any(k in a for k in keys):
            self.pc.warn(e.loc, "no inertia given; using m*(0.1*L)^2 (only the stability "
                         "regularisation and MKEAM use it)")
            self._needs_default_inertia = getattr(self, "_needs_default_inertia", []) + [e.id]
            return np.zeros((3, 3))
        xx, yy, zz, xy, yz, xz = (float(_num(e, k, 0.0, self.pc) or 0.0) for k in keys)
        Jl = np.array([[xx, -xy, -xz], [-xy, yy, -yz], [-xz, -yz, zz]])
        im = a.get("im_id") or a.get("cg_id")
        p_im, R_im = self.marker_glob.get(im, (p_cg, R_cg))
        Jg = R_im @ Jl @ R_im.T
        d = p_cg - p_im
        Jcg = Jg - m * (d @ d * np.eye(3) - np.outer(d, d))
        return R_cg.T @ Jcg @ R_cg

    def marker_arrays(self, body_pos, body_rot):
        els = self.marker_els
        nb = len(self.moving)
        ids = [0] + [e.id for e in els]
        mb = [nb]
        s0 = [np.zeros(3)]
        A0 = [np.eye(3)]
        self.marker_index = {0: GLOBAL}
        for k, e in enumerate(els):
            self.marker_index[e.id] = k + 1
            p, R = self.marker_glob[e.id]
            bid = e.attrs.get("body_id")
            if bid in self.body_index:
                b = self.body_index[bid]
                mb.append(b)
                s0.append(body_rot[b].T @ (p - body_pos[b]))
                A0.append(body_rot[b].T @ R)
            else:
                if bid not in self.ground_ids:
                    self.pc.error(e.loc, f"body_id {bid} is not a body; expected the id of a "
                                  "Body_Rigid or Body_Point", "body_id")
                mb.append(nb)
                s0.append(p)
                A0.append(R)
        P = np.array([self.marker_glob[e.id][0] for e in els]) if els else np.zeros((1, 3))
        c = P.mean(axis=0)
        L = float(np.max(np.linalg.norm(P - c, axis=1))) if len(P) else 1.0
        self.L = L if L > 0 else 1.0
        return dict(marker_id=np.array(ids, int), marker_body=np.array(mb, int),
                    marker_s0=np.array(s0), marker_A0=np.array(A0))

    def mk(self, el, attr, required=True):
        mid = el.attrs.get(attr)
        if mid is None:
            if required:
                self.pc.error(el.loc, "missing marker reference; expected a marker id", attr)
            return GLOBAL
        if mid not in self.marker_index:
            self.pc.error(el.loc, f"marker {mid} does not exist; expected a Reference_Marker id",
                          attr)
            return GLOBAL
        return self.marker_index[mid]


def compile_model(spec: DeckSpec) -> Model:
    """Compile a validated :class:`DeckSpec` into a :class:`Model`.

    Raises
    ------
    poise.errors.DeckError
        For problems only visible at this stage (unsupported joint types, expressions where
        numbers are needed, ...), all collected.
    """
    b = _Builder(spec)
    mfac, udesc = unit_info(spec)
    b.markers()
    bodies = b.bodies(mfac)
    markers = b.marker_arrays(bodies["init_pos"], bodies["init_rot"])
    for bid in getattr(b, "_needs_default_inertia", []):
        i = b.body_index[bid]
        bodies["body_inertia"][i] = bodies["body_mass"][i] * (0.1 * b.L) ** 2 * np.eye(3)

    rows: list[dict] = []
    fams = []
    outputs: dict = {}
    angles: list[tuple[int, int, int]] = []

    def angle(I, J, axis):
        angles.append((I, J, axis))
        return len(angles) - 1

    # ------------------------------------------------------------ constraints
    for tag, group in (("Constraint_Joint", "joints"), ("Constraint_Jprim", "jprims")):
        els = spec.elements(tag)
        if not els:
            continue
        acc = {"point": [], "perp": [], "plane": []}
        ids = []
        for k, el in enumerate(els):
            jt = str(el.attrs.get("type", "")).upper()
            eqs = C.JOINT_EQUATIONS.get(jt)
            if eqs is None:
                b.pc.error(el.loc, f"joint type {jt} is not supported yet; supported: "
                           + ", ".join(sorted(C.JOINT_EQUATIONS)), "type")
                continue
            I = b.mk(el, "i_marker_id")
            J = b.mk(el, "j_marker_id")
            ids.append(el.id)
            names = C.equation_names(eqs)
            ni = 0
            for e in eqs:
                if e[0] == "point":
                    r0 = len(rows)
                    for nm in names[ni:ni + 3]:
                        rows.append(_row(el, nm, "trans", group, len(ids) - 1))
                    acc["point"].append((I, J, len(ids) - 1, [r0, r0 + 1, r0 + 2]))
                    ni += 3
                else:
                    r0 = len(rows)
                    rows.append(_row(el, names[ni], "rot" if e[0] == "perp" else "trans", group,
                                     len(ids) - 1))
                    acc[e[0]].append((I, J, len(ids) - 1, [r0], e))
                    ni += 1
            b.effects.append(f"{tag}:{jt}")
        outputs[group] = dict(tag=tag, ids=np.array(ids, int))
        if acc["point"]:
            a = acc["point"]
            f = C.Coincident.build(f"{group}:coincident", np.array([x[0] for x in a]),
                                   np.array([x[1] for x in a]), [x[2] for x in a])
            f.crow = np.array([x[3] for x in a], int)
            f.group = group
            fams.append(f)
        if acc["perp"]:
            a = acc["perp"]
            e4 = [x[4] for x in a]
            f = C.Perpendicular.build(
                f"{group}:perpendicular", np.array([x[0] for x in a]), np.array([x[1] for x in a]),
                [e[1] for e in e4], [e[2] for e in e4],
                [e[3] if len(e) > 3 else 1 for e in e4], [e[4] if len(e) > 3 else 1 for e in e4],
                [1.0 if len(e) > 3 else 0.0 for e in e4], [x[2] for x in a])
            f.crow = np.array([x[3] for x in a], int)
            f.group = group
            fams.append(f)
        if acc["plane"]:
            a = acc["plane"]
            f = C.InPlane.build(f"{group}:inplane", np.array([x[0] for x in a]),
                                np.array([x[1] for x in a]), [x[4][1] for x in a],
                                [x[2] for x in a])
            f.crow = np.array([x[3] for x in a], int)
            f.group = group
            fams.append(f)

    # ------------------------------------------------------------ forces
    force_rows = []   # (tag, id, loc) per force element, output group "forces"
    per_type: dict[str, list] = {}

    def add(kind, el, **kw):
        force_rows.append(el)
        per_type.setdefault(kind, []).append(dict(owner=len(force_rows) - 1, el=el, **kw))

    pc = b.pc
    for el in spec.elements("Force_SpringDamper"):
        t = str(el.attrs.get("type", "TRANSLATIONAL")).upper()
        I, J = b.mk(el, "i_marker_id"), b.mk(el, "j_marker_id")
        k = _num(el, "stiffness", 0.0, pc)
        pre = _num(el, "preload", 0.0, pc)
        if t == "ROTATIONAL":
            L0 = _num(el, "length", None, pc)
            if L0 is None:
                L0 = _num(el, "angle", 0.0, pc)
            add("AxisTorque", el, I=I, J=J, R=GLOBAL, k=k, length=L0, preload=pre, ax=False,
                ang=angle(I, J, 2))
        else:
            add("LineForce", el, I=I, J=J, R=GLOBAL, k=k, length=_num(el, "length", 0.0, pc),
                preload=pre, ax=False)
        b.effects.append(f"Force_SpringDamper:{t}")
    for el in spec.elements("Force_Scalar_TwoBody"):
        t = str(el.attrs.get("type", "FORCE")).upper()
        I, J = b.mk(el, "i_marker_id"), b.mk(el, "j_marker_id")
        val = el.attrs.get("val", el.attrs.get("val_expression", 0.0))
        if isinstance(val, Expr):
            pc.error(el.loc, "expressions are not supported yet (coming with the expression "
                     "language); expected a number", "val_expression")
            val = 0.0
        ao = bool(el.attrs.get("is_action_only", False))
        if t == "TORQUE":
            add("AxisTorque", el, I=I, J=J, R=GLOBAL, k=0.0, length=0.0, preload=val, ax=ao,
                ang=angle(I, J, 2))
        elif ao:
            add("AxisForce", el, I=I, J=J, R=GLOBAL, value=val, ax=True)
        else:
            add("LineForce", el, I=I, J=J, R=GLOBAL, k=0.0, length=0.0, preload=val, ax=False)
        b.effects.append(f"Force_Scalar_TwoBody:{t}")
    for el in spec.elements("Force_Bushing"):
        I, J = b.mk(el, "i_marker_id"), b.mk(el, "j_marker_id")
        g = lambda n: float(_num(el, n, 0.0, pc) or 0.0)  # noqa: E731
        add("Bushing", el, I=I, J=J, R=GLOBAL, ax=False,
            kt3=[g("kx"), g("ky"), g("kz")], kr3=[g("ktx"), g("kty"), g("ktz")],
            f0=[g("preload_x"), g("preload_y"), g("preload_z")],
            t0=[g("preload_tx"), g("preload_ty"), g("preload_tz")],
            ang=[angle(I, J, 0), angle(I, J, 1), angle(I, J, 2)])
        b.effects.append("Force_Bushing")
    for tag in ("Force_Vector_OneBody", "Force_Vector_TwoBody"):
        for el in spec.elements(tag):
            one = tag.endswith("OneBody")
            I = b.mk(el, "marker_id" if one else "i_marker_id")
            J = GLOBAL if one else b.mk(el, "j_floating_marker_id")
            R = b.mk(el, "ref_marker_id", required=False)
            t = str(el.attrs.get("type", "FORCEANDTORQUE")).upper()
            comp = []
            for nm in ("fx", "fy", "fz", "tx", "ty", "tz"):
                v = el.attrs.get(f"{nm}_expression", el.attrs.get(nm, 0.0))
                if isinstance(v, Expr):
                    pc.error(el.loc, "expressions are not supported yet (coming with the "
                             "expression language); expected a number", f"{nm}_expression")
                    v = 0.0
                comp.append(float(v or 0.0))
            if t == "FORCEONLY":
                comp[3:] = [0.0] * 3
            elif t == "TORQUEONLY":
                comp[:3] = [0.0] * 3
            add("VectorForce", el, I=I, J=J, R=R, fc=comp[:3], tc=comp[3:], ax=one)
            b.effects.append(tag)

    classes = {"LineForce": Fo.LineForce, "AxisForce": Fo.AxisForce, "AxisTorque": Fo.AxisTorque,
               "Bushing": Fo.Bushing, "VectorForce": Fo.VectorForce}
    for kind, items in per_type.items():
        cls = classes[kind]
        params = {}
        for key in items[0]:
            if key in ("owner", "el", "I", "J", "R", "ax", "ang"):
                continue
            params[key] = np.array([it[key] for it in items], float)
        f = cls.build(f"forces:{kind}", np.array([it["I"] for it in items]),
                      np.array([it["J"] for it in items]), np.array([it["R"] for it in items]),
                      [it["owner"] for it in items], action_only=[it["ax"] for it in items],
                      **params)
        if "ang" in items[0]:
            f.angle_index = np.array([it["ang"] for it in items], int)
        f.element_locs = [it["el"].loc for it in items]
        f.group = "forces"
        fams.append(f)
    if force_rows:
        outputs["forces"] = dict(tag=np.array([e.tag for e in force_rows]),
                                 ids=np.array([e.id for e in force_rows], int))

    # ------------------------------------------------------------ gravity
    grav = np.zeros(3)
    gels = [e for e in spec.model if e.tag == "Force_Gravity"]
    if gels:
        el = gels[-1]
        grav = np.array([_num(el, "grav_x", 0.0, pc), _num(el, "grav_y", 0.0, pc),
                         _num(el, "grav_z", 0.0, pc)], float)
        b.effects.insert(0, "gravity")

    pc.raise_if_any()

    # ------------------------------------------------------------ layout
    nb = len(b.moving)
    kinds = bodies["body_kind"]
    off = bodies["body_off"]
    mb = markers["marker_body"]
    for f in fams:
        cols = []
        for k in range(f.K):
            bi = mb[f.markers[:, k]]
            ground = bi >= nb
            bsafe = np.minimum(bi, max(nb - 1, 0))
            base = off[bsafe] if nb else np.zeros_like(bi)
            c = base[:, None] + np.arange(6)[None, :]
            c[ground] = -1
            if nb:
                point = (kinds[bsafe] == 1) & ~ground
                c[point, 3:] = -1
            cols.append(c)
        f.gcol = np.concatenate(cols, axis=1)
    nc = len(rows)
    effects = list(dict.fromkeys(b.effects))
    model = Model(
        **bodies, **markers, families=fams, nq=b.nq, nc=nc, row_info=rows,
        angle_I=np.array([a[0] for a in angles], int), angle_J=np.array([a[1] for a in angles], int),
        angle_axis=np.array([a[2] for a in angles], int), gravity=grav, L=b.L,
        gravity_on=bool(gels) and np.any(grav != 0), active_effects=effects, outputs=outputs,
        units=udesc,
    )
    model.spec_warnings = list(pc.warnings)
    model.finalize()
    return model


def _row(el: Element, equation: str, kind: str, group: str, owner: int) -> dict:
    return dict(tag=el.tag, id=el.id, equation=equation, line=el.loc.line, file=el.loc.file,
                kind=kind, group=group, owner=owner)
