"""Compile force elements (springs, bushings, vector and scalar forces) into force families."""
from __future__ import annotations

import numpy as np

from poise.deck.spec import Expr
from poise.elements import forces as Fo
from poise.elements.context import GLOBAL, num as _num
from poise.elements.registry import ElementType, FDCase
from poise.core.user_routines import uses_user_routine


def compile_forces(spec, ctx):
    b = ctx.b
    fams, outputs = ctx.families, ctx.outputs
    angle = ctx.angle
    pc = ctx.pc
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
        if uses_user_routine(el):          # Python SFOSUB: compiled by compile_user
            force_rows.append(el)
            ctx.user_forces = getattr(ctx, "user_forces", []) + [(len(force_rows) - 1, el)]
            b.effects.append(f"Force_Scalar_TwoBody:{t}:python")
            continue
        I, J = b.mk(el, "i_marker_id"), b.mk(el, "j_marker_id")
        val = el.attrs.get("val", el.attrs.get("val_expression", 0.0))
        if isinstance(val, Expr):          # expression force: compiled by compile_expr
            force_rows.append(el)
            ctx.expr_forces.append((len(force_rows) - 1, el))
            b.effects.append(f"Force_Scalar_TwoBody:{t}")
            continue
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
        def g(n, el=el):
            return float(_num(el, n, 0.0, pc) or 0.0)
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
            if uses_user_routine(el):      # Python GFOSUB: compiled by compile_user
                force_rows.append(el)
                ctx.user_forces = getattr(ctx, "user_forces", []) + [(len(force_rows) - 1, el)]
                b.effects.append(f"{tag}:python")
                continue
            if any(isinstance(el.attrs.get(f"{nm}_expression"), Expr)
                   for nm in ("fx", "fy", "fz", "tx", "ty", "tz")):
                force_rows.append(el)      # expression force: compiled by compile_expr
                ctx.expr_forces.append((len(force_rows) - 1, el))
                b.effects.append(tag)
                continue
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


_VEC = ("Force_Vector_TwoBody", "Force_Vector_OneBody")


def _fd_cases():
    def case(name, tag, **attrs):
        jm = "j_floating_marker_id" if tag == "Force_Vector_TwoBody" else "j_marker_id"
        return FDCase(name, ((tag, attrs),), marker_attrs=("i_marker_id", jm))
    return (
        case("spring_translational", "Force_SpringDamper", type="TRANSLATIONAL",
             stiffness=30.0, damping=1.0, length=0.7, preload=2.0),
        case("spring_rotational", "Force_SpringDamper", type="ROTATIONAL", stiffness=30.0,
             damping=1.0, length=7.0, preload=2.0),
        case("bushing", "Force_Bushing", kx=10.0, ky=20.0, kz=30.0, ktx=4.0, kty=5.0,
             ktz=6.0, preload_x=1.0, preload_tz=2.0),
        case("scalar_force", "Force_Scalar_TwoBody", type="FORCE", val=3.0),
        case("scalar_force_action_only", "Force_Scalar_TwoBody", type="FORCE", val=3.0,
             is_action_only=True),
        case("scalar_torque", "Force_Scalar_TwoBody", type="TORQUE", val=3.0),
        case("vector_twobody", "Force_Vector_TwoBody", type="FORCEANDTORQUE", fx_expression=1.0,
             fy_expression=2.0, fz_expression=-3.0, tx_expression=0.5, ty_expression=-1.0,
             tz_expression=2.0, ref_marker_id=32))


_KERNELS = lambda: (Fo.LineForce, Fo.AxisForce, Fo.AxisTorque, Fo.Bushing,  # noqa: E731
                    Fo.VectorForce)
ELEMENTS = (ElementType(
    "forces", ("Force_SpringDamper", "Force_Scalar_TwoBody", "Force_Bushing") + _VEC,
    compile_forces,
    after=("joints",),          # force families after the joint families (model layout)
    kernels=_KERNELS, tileable=_KERNELS, potential_energy=True,
    outputs={"forces": None}, datasets=("id", "tag", "force", "torque"),
    reactions={"SFORCE": ("forces", ("Force_Scalar_TwoBody",)), "VFORCE": ("forces", _VEC),
               "VTORQ": ("forces", _VEC), "GFORCE": ("forces", _VEC),
               "BUSH": ("forces", ("Force_Bushing",)), "SPDP": ("forces", ("Force_SpringDamper",))},
    reaction_aliases={"FORCE_SCALAR_TWOBODY": "SFORCE", "FORCE_VECTOR_TWOBODY": "GFORCE",
                      "FORCE_VECTOR_ONEBODY": "GFORCE", "FORCE_BUSHING": "BUSH",
                      "BUSHING": "BUSH", "FORCE_SPRINGDAMPER": "SPDP", "SPRINGDAMPER": "SPDP"},
    fd_cases=_fd_cases),)
