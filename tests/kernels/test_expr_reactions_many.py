"""Expression forces reading constraint reactions at scale: the vectorised ``ReactionFeed``
(d r_reader / d lambda and d r_reader / d q blocks and channel values) on a generated deck with
hundreds of readers and channels (every component 1..8, jflag 0/1, global / rotated-ground /
moving RM markers, joints, jprims, a motion, force elements and resultants): the full KKT
Jacobian against central differences; and a closed-form equilibrium of a force equal to
k * (a joint reaction magnitude / component)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from poise.deck.spec import Expr
from poise.core.errors import SourceLoc
from poise.model.compile import compile_model

from support.builders import DeckBuilder, random_rotation
from support.fd import check_full_jacobian


JOINT_TYPES = ("SPHERICAL", "REVOLUTE", "CYLINDRICAL", "TRANSLATIONAL", "UNIVERSAL", "FIXED",
               "PLANAR", "INLINE", "ORIENTATION", "INPLANE")


def _x(text, attr, tag, id):
    return Expr(text, SourceLoc("<built>", 1, tag, id), attr)


def _vector_attrs(tag, fid, texts, default):
    """The six ``{fx..tz}_expression`` attributes: expressions ``texts`` (component -> text),
    the constant ``default`` for the others."""
    return {f"{a}_expression": _x(texts[a], f"{a}_expression", tag, fid) if a in texts
            else default for a in ("fx", "fy", "fz", "tx", "ty", "tz")}


def many_reader_deck(nb=60, nr=200, per=5, seed=0, forces=0):
    """``nb`` bodies, each tied by one joint (every 7th a jprim) to ground or to an earlier
    body, one REVOLUTE with a Motion_Joint; ``nr`` expression forces (vector two-body / one-body
    and scalar, cycling) each reading ``per`` reaction channels of random joints with random
    component 1..8, jflag and RM (global, a rotated ground marker 11, a moving marker), plus
    resultants FX/FM/TY of joint markers. ``forces`` > 0 adds that many force elements
    (translational/rotational springs, bushings, constant vector and scalar forces) on the
    joints' I markers or other body markers, and about 30 % of the terms read one of them
    (SPDP/BUSH/VFORCE/VTORQ/GFORCE/SFORCE, any component, jflag, RM); resultants at joint
    markers then include them too (a separate random stream: ``forces=0`` is the original
    deck). Returns the DeckBuilder."""
    rng = np.random.default_rng(seed)
    rf = np.random.default_rng(seed + 1000)
    d = DeckBuilder().ground()
    d.marker(11, 1, rng.normal(size=3), random_rotation(rng))
    joints = []                                  # (tag kind, id, I marker, J marker)
    for b in range(2, nb + 2):
        d.body(b, 100 * b, rng.normal(size=3), random_rotation(rng), mass=1.0 + rng.random(),
               inertia=(1.0, 2.0, 3.0))
        for k in (1, 2, 3):
            d.marker(100 * b + k, b, rng.normal(scale=0.5, size=3), random_rotation(rng))
        if b == 2 or rng.random() < 0.5:
            jm = 10000 + b
            d.marker(jm, 1, rng.normal(size=3), random_rotation(rng))
        else:
            jm = 100 * int(rng.integers(2, b)) + 2
        kind = "JPRIM" if b % 7 == 0 else "JOINT"
        jt = "REVOLUTE" if b == 3 else JOINT_TYPES[b % len(JOINT_TYPES)]
        d.add("Constraint_Jprim" if kind == "JPRIM" else "Constraint_Joint", id=b, type=jt,
              i_marker_id=100 * b + 1, j_marker_id=jm)
        joints.append((kind, b, 100 * b + 1, jm))
    d.add("Motion_Joint", id=1, joint_id=3, joint_type="R", val_type="D",
          expr=_x("0.1", "expr", "Motion_Joint", 1))
    nbody = np.arange(2, nb + 2)
    felems = []                                  # (function, id)
    for k in range(forces):
        fid = 5000 + k
        b, o = (int(v) for v in rf.choice(nbody, 2, replace=False))
        mi = 100 * b + int(rf.integers(1, 3))
        mj = 100 * o + int(rf.integers(1, 3)) if rf.random() < 0.7 else 11
        kind = k % 5
        if kind == 0:
            d.add("Force_SpringDamper", id=fid, type="TRANSLATIONAL", i_marker_id=mi,
                  j_marker_id=mj, stiffness=float(rf.uniform(10, 50)), damping=0.0,
                  length=float(rf.uniform(0.1, 1.0)), preload=float(rf.uniform(-1, 1)))
            felems.append(("SPDP", fid))
        elif kind == 1:
            d.add("Force_SpringDamper", id=fid, type="ROTATIONAL", i_marker_id=mi,
                  j_marker_id=mj, stiffness=float(rf.uniform(10, 50)), damping=0.0,
                  length=float(rf.uniform(-0.5, 0.5)), preload=0.0)
            felems.append(("SPDP", fid))
        elif kind == 2:
            kw = {a: float(rf.uniform(5, 20)) for a in ("kx", "ky", "kz", "ktx", "kty", "ktz")}
            kw.update({a: float(rf.uniform(-1, 1)) for a in ("preload_x", "preload_tz")})
            d.add("Force_Bushing", id=fid, i_marker_id=mi, j_marker_id=mj, **kw)
            felems.append(("BUSH", fid))
        elif kind == 3:
            kw = {f"{a}_expression": float(rf.uniform(-2, 2))
                  for a in ("fx", "fy", "fz", "tx", "ty", "tz")}
            d.add("Force_Vector_TwoBody", id=fid, type="FORCEANDTORQUE", i_marker_id=mi,
                  j_floating_marker_id=mj, ref_marker_id=100 * o + 2, **kw)
            felems.append((("VFORCE", "VTORQ", "GFORCE")[k % 3], fid))
        else:
            d.add("Force_Scalar_TwoBody", id=fid, type=("FORCE", "TORQUE")[k % 2],
                  i_marker_id=mi, j_marker_id=mj, val=float(rf.uniform(-3, 3)))
            felems.append(("SFORCE", fid))
    for k in range(nr):
        terms = []
        for _ in range(per):
            if felems and rf.random() < 0.3:
                fn, eid = felems[int(rf.integers(len(felems)))]
                rm = (0, 11, 100 * int(rf.choice(nbody)) + 2)[int(rf.integers(3))]
                terms.append(f"{rf.uniform(-0.05, 0.05):.4f}*{fn}({eid},{int(rf.integers(2))},"
                             f"{int(rf.integers(1, 9))},{rm})")
                continue
            r = rng.random()
            rm = (0, 11, 100 * int(rng.choice(nbody)) + 2)[int(rng.integers(3))]
            comp = int(rng.integers(1, 9))
            c = f"{rng.uniform(-0.05, 0.05):.4f}"
            kind, jid, mi, mj = joints[int(rng.integers(len(joints)))]
            if r < 0.85:
                terms.append(f"{c}*{kind}({jid},{int(rng.integers(2))},{comp},{rm})")
            elif r < 0.92:
                terms.append(f"{c}*MOTION(1,{int(rng.integers(2))},{comp},{rm})")
            else:
                fn = ("FX", "FM", "TY", "TM")[int(rng.integers(4))]
                a, o = (mi, mj) if rng.random() < 0.5 else (mj, mi)   # at J: flipped
                terms.append(f"{c}*{fn}({a},{o if rng.random() < 0.5 else 0},{rm})")
        expr = " + ".join(terms)
        b, o = (int(v) for v in rng.choice(nbody, 2, replace=False))
        fid = 100 + k
        if k % 3 == 0:
            tag = "Force_Vector_TwoBody"
            comps = _vector_attrs(tag, fid, {"fy": expr, "tz": f"0.5*({expr})"}, 0.1)
            d.add(tag, id=fid, type="FORCEANDTORQUE", i_marker_id=100 * b + 3,
                  j_floating_marker_id=100 * o + 3, ref_marker_id=100 * o + 2, **comps)
        elif k % 3 == 1:
            tag = "Force_Vector_OneBody"
            comps = _vector_attrs(tag, fid, {"tx": expr, "fx": f"-({expr})"}, 0.0)
            d.add(tag, id=fid, type="FORCEANDTORQUE", marker_id=100 * b + 3, ref_marker_id=11,
                  **comps)
        else:
            tag = "Force_Scalar_TwoBody"
            d.add(tag, id=fid, type=("FORCE", "TORQUE")[k % 2], i_marker_id=100 * b + 3,
                  j_marker_id=100 * o + 3, val_expression=_x(expr, "val_expression", tag, fid))
    return d


def _state(m, seed):
    rng = np.random.default_rng(seed)
    st = m.retract(m.initial_state(), 0.05 * rng.normal(size=m.nq))
    st.lam = 10.0 * rng.normal(size=m.nc)
    st.t = 0.0
    return st


def _captured(m, st):
    """Evaluate with the Jacobian; returns the evaluation and the arguments ``Model.evaluate``
    passed to ``ReactionFeed.coupling`` ``(model, kept, P, A, row_active, tangents, Dg)``."""
    from poise.elements.reaction_feed import ReactionFeed
    cap = {}
    orig = ReactionFeed.coupling

    def spy(self, *a):
        cap["args"] = a
        return orig(self, *a)
    ReactionFeed.coupling = spy
    try:
        ev = m.evaluate(st)
    finally:
        ReactionFeed.coupling = orig
    return ev, cap["args"]


# ------------------------------------------------------------------ per-entry reference
def _ref_dlam(g, kin, phy, j, ch, flip, ei, ej, P, A, vec):
    """d channel / d lambda (m,) of constraint instance ``j``, one instance at a time; ``vec``
    (6,) the channel's whole (F, T) (the unit vector of |F|, |T|)."""
    from poise.model.compile import GLOBAL
    m = phy.shape[1]
    dF, dT = np.zeros((3, m)), np.zeros((3, m))
    for s in range(len(g.slot_ml)):
        if g.slot_ml[s] != 0:
            continue
        blk = phy[j, :, 3 * s:3 * s + 3].T
        if int(g.slot_kind[j, s]) == 0:
            dF -= blk
        else:
            dT -= np.cross(kin.Y[j, s][:, None], blk, axis=0)
    if flip:
        dF, dT = -dF, -dT - np.cross((P[ei] - P[ej])[:, None], dF, axis=0)
    rm = ch[6] if ch[0] == "EL" else ch[4]
    if rm != GLOBAL:
        dF, dT = A[rm].T @ dF, A[rm].T @ dT
    comp = int(ch[5] if ch[0] == "EL" else ch[3])
    if comp in (1, 5):
        M = dF if comp == 1 else dT
        v = vec[:3] if comp == 1 else vec[3:]
        nv = float(np.linalg.norm(v))
        return (v / nv) @ M if nv > 0 else np.zeros(m)
    return dF[comp - 2] if comp <= 4 else dT[comp - 6]


def _matches(ch, g, key, ei, ej):
    """None if constraint element ``key`` (markers ei, ej) is not in channel ``ch``, else the
    flip (its action taken on J)."""
    if ch[0] == "EL":
        return bool(ch[4]) if (g.group,) + key == tuple(ch[1:4]) else None
    mi, mj = ch[1], ch[2]
    if ei == mi and (mj < 0 or ej == mj):
        return False
    if ej == mi and (mj < 0 or ei == mj):
        return True
    return None


def _reference_coupling(m, kept, P, A, vecs, row_active, tangents):
    """Dense (N, N) d r / d lambda of the reader families, one Python iteration per (reader
    instance, channel, constraint instance) as ReactionFeed.coupling did before it was batched
    (``vecs`` (C, 6): every channel's (F, T), see :func:`_reference_values`)."""
    from poise.elements.kernel import local_residual_tangent
    from poise.elements.forces import apply_two_body
    feed = m.reaction_feed
    owners = feed.info.owners
    inv = {g: {o: key for key, o in om.items()} for g, om in owners.items()}
    out = np.zeros((m.N, m.N))
    for ri, f in enumerate(m.families):
        if not getattr(f, "reads_reactions", False):
            continue
        kin = kept[ri][1]
        dFs, dTs = f.scalar_chain(kin.Y, tangents[ri][5]["d_reaction"])
        for i in range(f.n):
            for u, c in enumerate(f.rcols[i]):
                if c < 0:
                    continue
                drho = apply_two_body(kin.Y, dFs[:, :, u], dTs[:, :, u], None, None,
                                      f.action_only, False)[0]
                rl = local_residual_tangent(kin, drho, None, f.slot_ml, f.K, False, None,
                                            0)[0][i]
                rows = f.gcol[i, :6 * f.K]
                for fi, g in enumerate(m.families):
                    if not g.is_constraint or getattr(g, "group", None) not in inv:
                        continue
                    for j, o in enumerate(np.asarray(g.owner).ravel()):
                        key = inv[g.group].get(int(o))
                        if key is None:
                            continue
                        ei, ej = feed.info.markers[key]
                        flip = _matches(feed.channels[c], g, key, ei, ej)
                        if flip is None:
                            continue
                        dch = _ref_dlam(g, kept[fi][1], kept[fi][3], j, feed.channels[c], flip,
                                        ei, ej, P, A, vecs[c]) * row_active[g.crow[j]]
                        ok = rows >= 0
                        np.add.at(out, np.ix_(rows[ok], m.nq + g.crow[j]),
                                  rl[ok, None] * dch[None, :])
    return out


def _reference_values(m, channels, info, loads, P, A):
    """Channel values and (C, 6) (F, T) vectors, one channel (and, for resultants, one element)
    at a time."""
    from poise.model.compile import GLOBAL
    owners = info.owners
    out = np.zeros(len(channels))
    vecs = np.zeros((len(channels), 6))
    for k, ch in enumerate(channels):
        Fs, Ts = np.zeros(3), np.zeros(3)
        for group, omap in owners.items():
            if group not in loads:
                continue
            for key, o in omap.items():
                ei, ej = info.markers[key]
                if ch[0] == "EL":
                    flip = bool(ch[4]) if (group,) + key == tuple(ch[1:4]) else None
                else:
                    flip = _matches(ch, None, key, ei, ej)
                if flip is None:
                    continue
                F, T = loads[group][0][o], loads[group][1][o]
                if flip:
                    F, T = -F, -T - np.cross(P[ei] - P[ej], F)
                Fs, Ts = Fs + F, Ts + T
        rm = ch[6] if ch[0] == "EL" else ch[4]
        if rm != GLOBAL:
            Fs, Ts = Fs @ A[rm], Ts @ A[rm]
        comp = int(ch[5] if ch[0] == "EL" else ch[3])
        v = vecs[k] = np.r_[Fs, Ts]
        out[k] = (np.linalg.norm(v[:3]) if comp == 1 else np.linalg.norm(v[3:]) if comp == 5
                  else v[comp - 2] if comp <= 4 else v[comp - 3])
    return out, vecs


def _dense_blocks(N, blocks, values):
    out = np.zeros((N, N))
    for (r, c), v in zip(blocks, values):
        r, c, v = (np.asarray(a).ravel() for a in (r, c, v))
        ok = (r >= 0) & (c >= 0)
        np.add.at(out, (r[ok], c[ok]), v[ok])
    return out


@pytest.fixture(scope="module")
def many():
    m = compile_model(many_reader_deck(nb=30, nr=200, per=5, seed=0).spec)
    return m, _state(m, 1)


def test_many_readers_grouped_and_equal_to_per_entry_reference(many):
    """2600+ (reader instance, channel, constraint instance) entries in a handful of groups;
    the batched blocks and channel values equal the per-entry loops to round-off."""
    from poise.solvers.outputs import loads_of
    m, st = many
    feed = m.reaction_feed
    E = feed.entries
    chans = feed.channels
    kinds = {(chans[c][0], chans[c][1] if chans[c][0] == "EL" else bool(fl))
             for c, fl in E[:, [3, 6]]}
    assert {("EL", "joints"), ("EL", "jprims"), ("EL", "motions"), ("RES", False),
            ("RES", True)} <= kinds                               # resultants taken at I and J
    comps = {chans[c][5] if chans[c][0] == "EL" else chans[c][3] for c in E[:, 3]}
    assert comps == set(range(1, 9)) and E[:, 6].any() and not E[:, 6].all()
    rms = {chans[c][6] if chans[c][0] == "EL" else chans[c][4] for c in E[:, 3]}
    ground_rm = int(np.nonzero(np.asarray(m.marker_id) == 11)[0][0])
    assert 0 in rms and ground_rm in rms and len(rms) > 10
    assert len(E) > 2000
    n_pairs = sum(getattr(f, "reads_reactions", False) for f in m.families) * \
        sum(getattr(f, "group", None) is not None for f in m.families)
    assert len(feed.groups) <= n_pairs

    ev, args = _captured(m, st)
    _, kept, P, A, row_active, tangents = args[:6]
    loads = loads_of(m, kept.values())
    vals, _ = feed.values(m, kept.values(), P, A)
    ref_v, vecs = _reference_values(m, chans, feed.info, loads, P, A)
    np.testing.assert_allclose(vals, ref_v, rtol=0, atol=1e-13 * np.abs(ref_v).max())

    new = feed.coupling(*args)
    blocks = feed.blocks                        # the pattern registered with the model
    assert len(new) == len(blocks)
    got = _dense_blocks(m.N, blocks, new)
    ref = _reference_coupling(m, kept, P, A, vecs, row_active, tangents)
    scale = np.abs(ref).max()
    assert scale > 1e-3
    # the multiplier columns (the coordinate columns: central differences below)
    np.testing.assert_allclose(got[:, m.nq:], ref[:, m.nq:], rtol=0, atol=1e-13 * scale)


def test_many_readers_full_jacobian_matches_central_differences(many):
    """Every column of the KKT Jacobian (coordinates and multipliers; the channels' d/dq at
    fixed multipliers: torque levers, jflag=1 transfer, moving RM, moving J, resultants, |F|,
    |T|) against central differences of the residual."""
    m, st = many
    check_full_jacobian(m, st)


def test_many_readers_with_force_elements_full_jacobian():
    """Channels of force elements (springs, rotational springs, bushings, vector and scalar
    forces; SPDP/BUSH/VFORCE/VTORQ/GFORCE/SFORCE and resultants including them) derive from
    the force families' own d rho / d y: the whole Jacobian against central differences."""
    m = compile_model(many_reader_deck(nb=20, nr=80, per=5, seed=3, forces=25).spec)
    feed = m.reaction_feed
    contrib = {m.families[g.fi].name for g in feed.groups}
    assert {"forces:LineForce", "forces:AxisTorque", "forces:Bushing",
            "forces:VectorForce"} <= contrib
    check_full_jacobian(m, _state(m, 2))


# ------------------------------------------------------------------ closed form
CLOSED_FORM = """<?xml version="1.0" encoding="UTF-8"?>
<MotionSolve>
  <Model>
    <Param_Unit force_unit="NEWTON" mass_unit="KILOGRAM" length_unit="MILLIMETER" time_unit="SECOND"/>
    <Param_Static method="FIM_S" max_num_iter="100" max_imbalance="1.0E-10" max_error="1.0E-10"/>
    <Body_Rigid id="1" isground="TRUE" cg_id="100"/>
    <Reference_Marker id="100" body_id="1" pos_x="0." pos_y="0." pos_z="0."/>
    <Reference_Marker id="101" body_id="1" pos_x="0." pos_y="0." pos_z="0."/>
    <Reference_Marker id="102" body_id="1" pos_x="50." pos_y="-30." pos_z="7."
        a00="0." a10="1." a20="0." a01="-1." a11="0." a21="0." a02="0." a12="0." a22="1."/>
    <Body_Rigid id="2" cg_id="200" mass="3.0" inertia_xx="10." inertia_yy="10000."
        inertia_zz="10000." inertia_xy="0." inertia_yz="0." inertia_xz="0."/>
    <Reference_Marker id="200" body_id="2" pos_x="100." pos_y="0." pos_z="0."/>
    <Reference_Marker id="201" body_id="2" pos_x="0." pos_y="0." pos_z="0."/>
    <Reference_Marker id="202" body_id="2" pos_x="200." pos_y="0." pos_z="0."/>
    <Constraint_Joint id="1" type="REVOLUTE" i_marker_id="201" j_marker_id="101"/>
    <Force_SpringDamper id="2" type="ROTATIONAL" i_marker_id="201" j_marker_id="101"
        stiffness="4000." damping="0." length="0."/>
    <Force_Vector_OneBody id="3" type="FORCEONLY" marker_id="202" ref_marker_id="0"
        fx_expression="C*JOINT(1,1,1,102)" fy_expression="K*JOINT(1,1,3,102)" fz_expression="0."/>
    <Force_Gravity grav_x="0." grav_y="-9810." grav_z="0."/>
    <Post_Request id="1" type="EXPRESSION" expr1="JOINT(1,0,2,0)" expr2="JOINT(1,0,3,0)"
        expr3="VFORCE(3,0,2,0)" expr4="VFORCE(3,0,3,0)" expr5="AZ(201,101)"
        expr6="FM(101,201,102)" expr7="FX(101,201,102)" expr8="NULL"/>
  </Model>
  <Command>
    <Simulate analysis_type="Static"/>
    <Stop/>
  </Command>
</MotionSolve>
"""


@pytest.mark.parametrize("c,k", [(0.3, 0.5), (0.6, -0.8)])
def test_force_equal_to_k_times_joint_reaction_closed_form(tmp_path, c, k):
    """A 3 kg bar (CG 100 mm, tip 200 mm) on a REVOLUTE about global Z, rotational spring
    k_t = 4000 N mm/rad, gravity -Y (W = 29.43 N). A tip force reads the hinge reaction on the
    ground (jflag=1, -R) resolved in a ground marker RM rotated +90 deg about Z (x_RM = +Y,
    y_RM = -X):  fx = C |R|,  fy = K (-R).y_RM = K R_x.  Statics of the bar: R + f - W y = 0,
    so R = (-fx, W - fy), fy = -K fx and fx = C sqrt(fx^2 + (W + K fx)^2), whose positive root
    is  fx = C W (C K + sqrt(1 - C^2)) / (1 - C^2 (1 + K^2)).  The angle solves the moment
    balance about the hinge  -k_t th + l cos(th) fy - l sin(th) fx - a W cos(th) = 0."""
    from poise.app.runner import run
    W, kt, ell, a = 3.0 * 9.81, 4000.0, 200.0, 100.0
    fx = c * W * (c * k + math.sqrt(1.0 - c * c)) / (1.0 - c * c * (1.0 + k * k))
    fy = -k * fx
    th = brentq(lambda t: -kt * t + ell * math.cos(t) * fy - ell * math.sin(t) * fx
                - a * W * math.cos(t), -1.5, 1.5, xtol=1e-15)
    p = tmp_path / "closed.xml"
    p.write_text(CLOSED_FORM.replace("C*", f"{c!r}*").replace("K*", f"{k!r}*"))
    ar = run(str(p)).analyses[0]
    assert ar.status == "converged", ar.message
    d = ar.datasets
    np.testing.assert_allclose(d["bodies/position"][0, 0],
                               [100 * math.cos(th), 100 * math.sin(th), 0.0], atol=1e-8)
    r = d["requests/values"][0, 0]
    R = np.hypot(fx, W - fy)
    # R on the bar; forces read back; angle; resultant on the ground marker 101 (the hinge's J:
    # -R, the spring adds no force) along x_RM = +Y: -(W - fy)
    np.testing.assert_allclose(r[:7], [-fx, W - fy, fx, fy, th, R, fy - W], rtol=1e-9,
                               atol=1e-8)
    assert len(d["iterations/imbalance"]) <= 12
