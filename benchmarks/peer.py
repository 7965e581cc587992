"""Peer side by side: the same physical problems built with Exudyn and solved with its static
solver (``mbs.SolveStatic``), in the same run as poise.

Exudyn is optional (``pip install -e '.[bench]'``); when it cannot be imported every row says so
and the report prints a note. All problems are planar and are built with Exudyn's planar items in
SI units (m, kg, s, N); poise solves the 3-D decks in ``decks/bench``/``poise.gen.chain`` exactly
as ``poise solve`` does. Both sides are judged by the achieved error against the same closed-form
reference (``tests/support/reference.py``: CG positions / model length scale).

Why the model choice matters (diagnosed, not assumed): Exudyn's static solver builds its Newton
matrix from the ODE2 stiffness, the constraint Jacobian C_q and C_qᵀ, but omits the derivative of
the constraint forces, ∂(C_qᵀλ)/∂q (the geometric stiffness of the joints; checked against a
finite-difference Jacobian of Exudyn's own residual, and in Exudyn's ``CSystem::JacobianODE2RHS``,
which skips constraints), and it starts from λ = 0. The planar models have no redundant equations
(four-bar: 8 joint equations for 9 coordinates; chain: 2n + 2 for 3n) and start from configurations
that close every joint exactly, so neither is the cause. Where joint forces supply stiffness to the
mechanism, Newton degrades into a fixed-point iteration: it contracts when ODE2 stiffness dominates
(pendulum in body coordinates: rate ≈ 0.15 per iteration) and does not otherwise (four-bar in body
coordinates: residual ratio above 1 every other iteration, no convergence in 25). A hanging chain
has no ODE2 stiffness in its n − 2 mechanism directions (gravity is linear in body coordinates), so
there Exudyn's Newton matrix is singular.

Models (one rule per problem type). Small linkages (``pendulum_multiturn``, ``fourbar_spring``):
``ObjectKinematicTree`` (Exudyn's minimal-coordinate element: one ``RevoluteZ`` joint angle per
link, gravity applied by the tree, its Jacobian by numerical differentiation, so exact), a loop
closed by one ``GenericJoint`` constraining x and y; rotational spring = ``CoordinateSpringDamper``
on the joint coordinate, translational spring = ``SpringDamper``. Only the closure joint's
geometric stiffness is then missing: the four-bar converges linearly (rate ≈ 0.1), the pendulum
(no constraint at all) quadratically. Chains (``chain_N``): ``NodeRigidBody2D`` /
``ObjectRigidBody2D`` bodies, ``RevoluteJoint2D`` pins, ``LoadMassProportional`` gravity, started
from a circular arc through both pins.

Settings. Linkages: Exudyn's defaults (``newton.relativeTolerance = 1e-8``, ``absoluteTolerance =
1e-10``, ``maxIterations = 25``, ``numberOfLoadSteps = 1``, ``adaptiveStep = True``,
``minimumStepSize = 1e-8``), dense solver. Chains: additionally ``numberOfLoadSteps = 10`` and
``stabilizerODE2term = 100`` s⁻² (≈ g / link length: Exudyn's remedy for unconstrained directions,
a mass-proportional stiffness scaled by (1 − f²) at load factor f), ``EigenSparse`` from 20 links.
Everywhere ``newton.adaptInitialResidual = False``: the default replaces the reference residual
when the first Newton step increases it, which reported penalty-joint variants as converged
2.6e-2 away from the answer. poise runs at its deck settings (``max_imbalance = max_error =
1e-8``).

Also tried on the chains, all failed: ``stabilizerODE2term`` from 1 to 1e6 with 10 to 100 load
steps (a larger stabilizer carries the load ramp further, chain_10 to a last converged
load factor of 0.04, 0.88, 0.997 for 1e2, 1e4, 1e6, chain_100 to 0.001, 0.18, 0.97, but never to
1, where the stabilizer is zero by design); ``linearSolver.ignoreSingularJacobian`` with
``EigenDense`` (full-pivot LU: no convergence either); numerical ODE2
differentiation (constraints are excluded from it); a ``KinematicTree`` with a closure joint (the
end reaction's missing geometric stiffness keeps it from converging); penalty joints
(``CartesianSpringDamper``: exact Jacobian, but the penalty error and the round-off floor of
k·|x| in the residual meet above 1e-6: chain_10 converged 4.6e-6 from the answer at k = 1e8 and
not at all at k = 1e10). The four-bar in body coordinates (``RevoluteJoint2D``) failed with the
stabilizer, singular-Jacobian and numerical-differentiation variants too; with penalty joints it
converged (2.7e-8 from the answer at k = 1e10), a different model that the KinematicTree makes
unnecessary.

The Exudyn model is built by a self-contained script (:data:`SCRIPT`) from a JSON description, so
the same code runs in-process (``exec``) and as a whole process
(``python peer_script.py spec.json``).
"""
from __future__ import annotations

import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SCRIPT = r'''
import json, sys, time, math
t0 = time.perf_counter()
import exudyn as exu
from exudyn.utilities import (ObjectGround, NodePointGround, NodeRigidBody2D, ObjectRigidBody2D,
    MarkerBodyPosition, MarkerBodyRigid, MarkerBodyMass, MarkerNodeCoordinate, RevoluteJoint2D,
    SpringDamper, CoordinateSpringDamper, LoadMassProportional, NodeGenericODE2,
    ObjectKinematicTree, MarkerKinematicTreeRigid, GenericJoint)
t_import = time.perf_counter() - t0


def build_bodies(mbs, spec, ground, gnode):
    """Maximal coordinates: one NodeRigidBody2D per bar (CG, angle), revolute pins."""
    bodies, nodes, lens = [], [], []
    for b in spec["bars"]:
        (px, py), (qx, qy), m = b["p"], b["q"], b["m"]
        l = math.hypot(qx - px, qy - py)
        th = math.atan2(qy - py, qx - px)
        n = mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[(px + qx) / 2, (py + qy) / 2, th],
                                        initialCoordinates=[0, 0, 0]))
        o = mbs.AddObject(ObjectRigidBody2D(mass=m, inertia=m * l * l / 12.0, nodeNumber=n))
        mbs.AddLoad(LoadMassProportional(markerNumber=mbs.AddMarker(MarkerBodyMass(bodyNumber=o)),
                                         loadVector=[0, -spec["g"], 0]))
        bodies.append(o); nodes.append(n); lens.append(l)

    def marker(a):
        if a[0] == "g":
            return mbs.AddMarker(MarkerBodyPosition(bodyNumber=ground, localPosition=[a[1], a[2], 0]))
        i, s = a[1], a[2]
        return mbs.AddMarker(MarkerBodyPosition(bodyNumber=bodies[i],
                                                localPosition=[s * lens[i] / 2, 0, 0]))
    for a, b in spec["joints"]:
        mbs.AddObject(RevoluteJoint2D(markerNumbers=[marker(a), marker(b)]))
    return lambda: [list(mbs.GetNodeOutput(n, exu.OutputVariableType.Position))[:2] for n in nodes]


def build_tree(mbs, spec, ground, gnode):
    """Minimal coordinates: a planar KinematicTree, link i from point P_i to P_(i+1), joint angle
    i relative to link i-1 (link 0: absolute); optional closure pin of the last link's end."""
    P, masses = spec["points"], spec["masses"]
    n = len(masses)
    ang = [math.atan2(P[i + 1][1] - P[i][1], P[i + 1][0] - P[i][0]) for i in range(n)]
    lens = [math.hypot(P[i + 1][0] - P[i][0], P[i + 1][1] - P[i][1]) for i in range(n)]
    q0 = [ang[0]] + [ang[i] - ang[i - 1] for i in range(1, n)]
    node = mbs.AddNode(NodeGenericODE2(numberOfODE2Coordinates=n, referenceCoordinates=q0,
                                       initialCoordinates=[0] * n, initialCoordinates_t=[0] * n))
    eye = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
    tree = mbs.AddObject(ObjectKinematicTree(
        nodeNumber=node, gravity=[0, -spec["g"], 0], jointTypes=[exu.JointType.RevoluteZ] * n,
        linkParents=list(range(-1, n - 1)), jointTransformations=exu.Matrix3DList([eye] * n),
        jointOffsets=exu.Vector3DList([[P[0][0], P[0][1], 0]] + [[lens[i - 1], 0, 0]
                                                                 for i in range(1, n)]),
        linkInertiasCOM=exu.Matrix3DList([[[0, 0, 0], [0, m * l * l / 12, 0], [0, 0, m * l * l / 12]]
                                          for m, l in zip(masses, lens)]),
        linkCOMs=exu.Vector3DList([[l / 2, 0, 0] for l in lens]), linkMasses=list(masses)))

    def tmarker(i, s):
        return mbs.AddMarker(MarkerKinematicTreeRigid(objectNumber=tree, linkNumber=i,
                                                      localPosition=[s * lens[i], 0, 0]))
    for i, s, (gx, gy), k, l0 in spec.get("tsprings", []):
        mg = mbs.AddMarker(MarkerBodyPosition(bodyNumber=ground, localPosition=[gx, gy, 0]))
        mbs.AddObject(SpringDamper(markerNumbers=[mg, tmarker(i, s)], stiffness=k, damping=0,
                                   referenceLength=l0))
    for i, k, off in spec.get("rsprings", []):
        mg = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=gnode, coordinate=0))
        mt = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=node, coordinate=i))
        mbs.AddObject(CoordinateSpringDamper(markerNumbers=[mg, mt], stiffness=k, damping=0,
                                             offset=off))
    if spec.get("closure") is not None:
        gx, gy = spec["closure"]
        mg = mbs.AddMarker(MarkerBodyRigid(bodyNumber=ground, localPosition=[gx, gy, 0]))
        mbs.AddObject(GenericJoint(markerNumbers=[mg, tmarker(n - 1, 1.0)],
                                   constrainedAxes=[1, 1, 0, 0, 0, 0]))
    cgm = [tmarker(i, 0.5) for i in range(n)]
    return lambda: [list(mbs.GetMarkerOutput(m, exu.OutputVariableType.Position))[:2] for m in cgm]


def solve(spec):
    t0 = time.perf_counter()
    SC = exu.SystemContainer(); mbs = SC.AddSystem()
    ground = mbs.AddObject(ObjectGround())
    gnode = mbs.AddNode(NodePointGround(referenceCoordinates=[0, 0, 0]))
    cg_out = (build_tree if spec["model"] == "tree" else build_bodies)(mbs, spec, ground, gnode)
    mbs.Assemble()
    st = spec["settings"]
    ss = exu.SimulationSettings()
    ss.solution.file.write = False
    ss.staticSolver.verboseMode = spec.get("verbose", 0)
    ss.staticSolver.numberOfLoadSteps = st["load_steps"]
    ss.staticSolver.stabilizerODE2term = st["stabilizer"]
    ss.staticSolver.minimumStepSize = st["min_step"]
    ss.staticSolver.newton.relativeTolerance = st["rtol"]
    ss.staticSolver.newton.absoluteTolerance = st["atol"]
    ss.staticSolver.newton.adaptInitialResidual = st["adapt_initial_residual"]
    if st["sparse"]:
        ss.linearSolver.solverType = exu.LinearSolverType.EigenSparse
    t1 = time.perf_counter()
    msg = ""
    try:
        ok = bool(mbs.SolveStatic(ss, storeSolver=True))
    except Exception as e:          # exudyn raises SolverError when the static solver fails
        ok, msg = False, f"{type(e).__name__}: {e}"
    t2 = time.perf_counter()
    it = steps = lf = None
    try:
        s = mbs.sys["staticSolver"]
        it = int(s.it.newtonStepsCount)
        steps = int(s.it.currentStepIndex)
        lf = float(s.it.currentTime)        # load factor of the last (attempted) step
    except Exception:
        pass
    return dict(converged=ok, message=msg, iterations=it, load_steps=steps, load_factor=lf,
                build_s=t1 - t0,
                solve_s=t2 - t1, cg=cg_out(),
                n_coordinates=len(mbs.systemData.GetODE2Coordinates()),
                n_constraints=len(mbs.systemData.GetAECoordinates()))


if __name__ == "__main__":
    spec = json.loads(open(sys.argv[1]).read())
    out = solve(spec)
    out["import_s"] = t_import
    print(json.dumps(out))
'''

#: Static solver settings per problem type (see the module docstring for why).
LINKAGE_SETTINGS = dict(load_steps=1, stabilizer=0.0, min_step=1e-8, rtol=1e-8, atol=1e-10,
                        adapt_initial_residual=False, sparse=False)


def chain_settings(n: int) -> dict:
    return dict(LINKAGE_SETTINGS, load_steps=10, stabilizer=100.0, sparse=n >= 20)


#: Shown in the table when Exudyn fails on a chain (diagnosis in the module docstring).
CHAIN_REASON = ("Exudyn's static Newton matrix omits the joints' geometric stiffness ∂(C_qᵀλ)/∂q, "
                "the chain's only stiffness in its n − 2 mechanism directions: the iteration "
                "stops contracting once the joint forces outweigh the stabilizer, and the matrix "
                "is singular at load factor 1, where the stabilizer is zero")


# --------------------------------------------------------------------------- problems
def _ref():
    from benchmarks.wp import _reference_module
    return _reference_module()


def problem_pendulum(ref):
    p = ref.PENDULUM_PARAMS
    assert p["theta0"] == 0.0       # the tree's joint coordinate is the spring's AZ from 0
    # 400 mm bar, 2 kg, hinge at the origin, input along +X; rotational spring k = 2e4 N mm/rad
    spec = dict(model="tree", g=9.81, points=[[0.0, 0.0], [p["length"] / 1000.0, 0.0]],
                masses=[p["mass"]], rsprings=[[0, p["k"] / 1000.0, p["ref_angle"]]],
                settings=dict(LINKAGE_SETTINGS))
    cg_ref = {0: ref.pendulum_multiturn()["cg"][:2]}
    return dict(name="pendulum_multiturn", spec=spec, ref=cg_ref, L=400.0,
                deck="decks/bench/pendulum_multiturn.xml",
                model="KinematicTree (1 RevoluteZ link) + CoordinateSpringDamper on the joint "
                      "angle; no constraint")


def problem_fourbar(ref):
    s = ref.fourbar_input()
    P = {k: np.asarray(v[:2]) / 1000.0 for k, v in s["points"].items()}
    fp = ref.FOURBAR_PARAMS
    # tree A -> B -> C -> D (crank, coupler, rocker run from C to D), end D pinned to ground;
    # spring from the rocker at C (start of link 2) to ground at A
    spec = dict(model="tree", g=9.81, points=[list(P[k]) for k in "ABCD"],
                masses=[fp["m_crank"], fp["m_coupler"], fp["m_rocker"]], closure=list(P["D"]),
                tsprings=[[2, 0.0, list(P["A"]), fp["k"] * 1000.0, fp["free_length"] / 1000]],
                settings=dict(LINKAGE_SETTINGS))
    eq = ref.fourbar_equilibrium()["cg"]
    cg_ref = {0: eq["crank"][:2], 1: eq["coupler"][:2], 2: eq["rocker"][:2]}
    return dict(name="fourbar_spring", spec=spec, ref=cg_ref, L=400.0,
                deck="decks/bench/fourbar_spring.xml",
                model="KinematicTree crank–coupler–rocker (3 RevoluteZ) + GenericJoint (x, y) "
                      "closing the loop at D + SpringDamper A–C")


def problem_chain(ref, n):
    a = 100.0
    span = 0.8 * n * a
    pts = ref.chain_arc(n, a, span)[:, :2] / 1000.0
    bars = [dict(p=list(pts[k]), q=list(pts[k + 1]), m=1.0) for k in range(n)]
    joints = [[["g", 0, 0], ["b", 0, -1]]]
    joints += [[["b", k - 1, 1], ["b", k, -1]] for k in range(1, n)]
    joints += [[["g", span / 1000.0, 0], ["b", n - 1, 1]]]
    spec = dict(model="bodies", g=9.81, bars=bars, joints=joints, settings=chain_settings(n))
    cg = ref.catenary(n)["cg"]
    return dict(name=f"chain_{n}", spec=spec, ref={k: cg[k][:2] for k in range(n)}, L=span,
                deck=None, n=n, reason=CHAIN_REASON,
                model=f"{n} RigidBody2D + {n + 1} RevoluteJoint2D (start: circular arc through "
                      "both pins, every joint closed)")


def _peer_error(out, prob) -> float | None:
    if not out.get("cg"):
        return None
    e = 0.0
    for k, xr in prob["ref"].items():
        x = np.asarray(out["cg"][k]) * 1000.0
        e = max(e, float(np.max(np.abs(x - xr))))
    return e / prob["L"]


def _stats(xs):
    xs = [x for x in xs if x is not None]
    if not xs:
        return None
    return dict(median=statistics.median(xs), min=min(xs), max=max(xs), n=len(xs))


def exudyn_available() -> tuple[bool, str]:
    try:
        import exudyn
        return True, f"exudyn {exudyn.__version__}"
    except Exception as e:          # ImportError, or a broken binary wheel
        return False, f"exudyn not importable ({type(e).__name__}: {e}); install the 'bench' extra"


#: The mandated dependencies of a ``poise solve`` process: numpy (everything), lxml (deck
#: parsing), h5py (results file). Whole-process time of importing just these is a floor no change
#: to poise can go below.
FLOOR_IMPORTS = "import numpy, h5py, lxml.etree"
#: The same floor set up as a poise process is: ``poise/__init__`` sets OPENBLAS_NUM_THREADS=1
#: before numpy is imported (no BLAS thread pool to start) and ``poise`` ends its process with
#: ``os._exit`` after the exit handlers (``poise_cli.main.end_process``).
FLOOR_AS_POISE = ('import os; os.environ.setdefault("OPENBLAS_NUM_THREADS", "1"); '
                  f'{FLOOR_IMPORTS}; os._exit(0)')


#: numpy alone, set up as a poise process: the one import both sides need (Exudyn imports numpy).
NUMPY_AS_POISE = ('import os; os.environ.setdefault("OPENBLAS_NUM_THREADS", "1"); import numpy; '
                  'os._exit(0)')
#: The peer's own import floor: what its script imports before it builds anything.
PEER_IMPORTS = "import json, math, exudyn, exudyn.utilities"


#: The least any ``poise solve`` process must do with the mandated stack, set up as poise: the
#: imports above plus click (the CLI), reading the deck with lxml, and writing an HDF5 file
#: (one dataset) with fsync; formatted with ``deck`` and ``out``.
MANDATED = ('import os; os.environ.setdefault("OPENBLAS_NUM_THREADS", "1"); '
            'import numpy, h5py, lxml.etree, click; lxml.etree.parse({deck!r}); '
            'f = h5py.File({out!r}, "w"); f["x"] = numpy.zeros(3); f.close(); '
            'fd = os.open({out!r}, os.O_RDONLY); os.fsync(fd); os._exit(0)')


def floor_commands(deck: Path, out: Path, peer: bool) -> dict:
    """``python -c`` commands of the floors: ``normal`` (:data:`FLOOR_IMPORTS`), ``as_poise``
    (:data:`FLOOR_AS_POISE`), ``numpy`` (:data:`NUMPY_AS_POISE`), ``mandated``
    (:data:`MANDATED`) and, when ``peer``, the peer script's imports (``peer``)."""
    codes = {"normal": FLOOR_IMPORTS, "as_poise": FLOOR_AS_POISE, "numpy": NUMPY_AS_POISE,
             "mandated": MANDATED.format(deck=str(deck), out=str(out))}
    if peer:
        codes["peer"] = PEER_IMPORTS
    return {k: [sys.executable, "-c", c] for k, c in codes.items()}


def batch_per_deck(deck: Path, tmp: Path, copies: int = 40, repeat: int = 3) -> dict:
    """``poise batch`` over ``copies`` copies of ``deck``: wall time per deck with one worker
    (``-j 1``: the whole CPU cost a CI job pays per deck when it hands poise the list) and with
    one worker per CPU (``-j 0``), process start to every results file and summary written."""
    from benchmarks.chain import _poise_cmd, _wall
    d = tmp / "batch-decks"
    d.mkdir(exist_ok=True)
    paths = []
    for k in range(copies):
        q = d / f"{deck.stem}_{k:03d}.xml"
        q.write_bytes(deck.read_bytes())
        paths.append(str(q))
    out = dict(copies=copies)
    for jobs in (1, 0):
        cmd = _poise_cmd() + ["batch", *paths, "--out-dir", str(tmp / "batch-out"), "--force",
                              "-q", "-j", str(jobs)]
        st, rc = _wall(cmd, repeat)
        out[f"j{jobs}"] = {k: (v / copies if k != "n" else v) for k, v in st.items()}
        out[f"j{jobs}_rc"] = rc
    return out


def _poise_point(deck: Path, repeat: int):
    """poise in-process at deck settings (warm-up + repeat); returns stats and the result."""
    from poise.app.api import run_deck
    run_deck(str(deck))
    solves, walls, res = [], [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        res = run_deck(str(deck))
        walls.append(time.perf_counter() - t0)
        solves.append(res.timings["solve"])
    return _stats(solves), _stats(walls), res


def run(quick: bool = False, repeat: int = 5, log=print) -> list[dict]:
    ok, note = exudyn_available()
    ref = _ref()
    sizes = (10, 100) if quick else (10, 100, 1000)
    probs = [problem_pendulum(ref), problem_fourbar(ref)] + [problem_chain(ref, n) for n in sizes]
    from benchmarks.chain import _poise_cmd, _wall, _walls
    from benchmarks.wp import DECKS, deck_error
    from poise.gen.chain import build_chain_deck
    rows = []
    ns: dict = {}
    if ok:
        exec(compile(SCRIPT, "<exudyn-peer>", "exec"), ns)
    with tempfile.TemporaryDirectory(prefix="poise-peer-") as td:
        tdp = Path(td)
        for prob in probs:
            row = dict(bench="peer", problem=prob["name"], peer=note, peer_available=ok)
            # ---- poise
            if prob["deck"]:
                deck = Path(__file__).resolve().parents[1] / prob["deck"]
                ref_fn = DECKS[prob["name"]][3]
            else:
                deck = tdp / f"{prob['name']}.xml"
                deck.write_text(build_chain_deck(prob["n"], "revolute"))
                from benchmarks.wp import _ref_chain
                ref_fn = _ref_chain(prob["n"])
            rep = repeat if prob.get("n", 0) < 1000 else max(3, repeat // 2)
            st, tot, res = _poise_point(deck, rep)
            an = res.analyses[0]
            row["poise"] = dict(status=an.status, solve_s=st, total_s=tot,
                                iterations=int(np.sum(an.datasets["frames/iterations"])),
                                error=deck_error(res, ref_fn, ref), counts=dict(res.counts))
            small = not prob.get("n")
            poise_cmd = _poise_cmd() + ["solve", str(deck), "-o", str(tdp / "o.h5")]
            if not small:
                pw, rc = _wall(poise_cmd, rep)
                row["poise"]["process_s"] = pw
                row["poise"]["process_rc"] = rc
            # ---- peer
            if ok:
                specf = tdp / "spec.json"
                specf.write_text(json.dumps(prob["spec"]))
                ns["solve"](prob["spec"])                       # warm-up
                outs = [ns["solve"](prob["spec"]) for _ in range(rep)]
                o = outs[-1]
                conv = all(x["converged"] for x in outs)
                row["exudyn"] = dict(converged=conv, message=o["message"],
                                     iterations=o["iterations"], load_steps=o["load_steps"],
                                     load_factor=o["load_factor"], n_coordinates=o["n_coordinates"],
                                     n_constraints=o["n_constraints"], model=prob["model"],
                                     settings=prob["spec"]["settings"],
                                     reason=None if conv else prob.get("reason"),
                                     solve_s=_stats([x["solve_s"] for x in outs]),
                                     build_s=_stats([x["build_s"] for x in outs]),
                                     error=_peer_error(o, prob) if conv else None,
                                     error_unconverged=_peer_error(o, prob))
                script = tdp / "peer_script.py"
                script.write_text(SCRIPT)
                peer_cmd = [sys.executable, str(script), str(specf)]
                if not small:
                    pw, rc = _wall(peer_cmd, rep)
                    row["exudyn"]["process_s"] = pw
                    row["exudyn"]["process_rc"] = rc
            if small:   # whole processes of both sides and the floors, interleaved
                cmds = {"poise": poise_cmd, **({"exudyn": peer_cmd} if ok else {}),
                        **floor_commands(deck, tdp / "floor.h5", ok)}
                w = _walls(cmds, max(rep, 11))
                row["poise"]["process_s"], row["poise"]["process_rc"] = w.pop("poise")
                if ok:
                    row["exudyn"]["process_s"], row["exudyn"]["process_rc"] = w.pop("exudyn")
                row["import_floor"] = dict(
                    command=f'python -c "{FLOOR_IMPORTS}"', command_as_poise=FLOOR_AS_POISE,
                    command_numpy=NUMPY_AS_POISE, command_peer=PEER_IMPORTS,
                    command_mandated=MANDATED.format(deck=prob["deck"], out="out.h5"),
                    **{k: v[0] for k, v in w.items()})
            if ok:
                ps, es = row["poise"]["solve_s"]["median"], row["exudyn"]["solve_s"]["median"]
                # ratios only where both sides reached the answer (a time to failure is no match)
                row["solve_ratio"] = ps / es if conv and es > 0 else None
                row["process_ratio"] = (row["poise"]["process_s"]["median"] /
                                        row["exudyn"]["process_s"]["median"]) if conv else None
            if small:                   # small decks: the floors next to the whole-process ratio
                floor = row["import_floor"]
                fl, fp = floor["normal"]["median"], floor["as_poise"]["median"]
                row["poise_above_floor_s"] = row["poise"]["process_s"]["median"] - fp
                row["batch"] = batch_per_deck(deck, tdp, repeat=max(1, min(3, repeat)))
                if ok:
                    pe = row["exudyn"]["process_s"]["median"]
                    row["floor_ratio"], row["floor_as_poise_ratio"] = fl / pe, fp / pe
                    row["numpy_ratio"] = floor["numpy"]["median"] / pe
                    row["mandated_ratio"] = floor["mandated"]["median"] / pe
                    row["peer_above_floor_s"] = pe - floor["peer"]["median"]
                    row["batch_ratio"] = {j: row["batch"][j]["median"] / pe
                                          for j in ("j1", "j0")}
            log(f"peer {prob['name']}: poise {row['poise']['solve_s']['median']:.3g} s err "
                f"{row['poise']['error']:.1e}" + (
                    f"; exudyn {'ok' if row['exudyn']['converged'] else 'FAILED'} "
                    f"{row['exudyn']['solve_s']['median']:.3g} s it {row['exudyn']['iterations']} "
                    f"err {row['exudyn']['error_unconverged']:.1e}; process "
                    f"{row['poise']['process_s']['median']:.3g} vs "
                    f"{row['exudyn']['process_s']['median']:.3g} s" if ok else f"; {note}"))
            rows.append(row)
    return rows


def caption() -> list[str]:
    """The report's caption: the module docstring's paragraphs after the first one, unwrapped,
    each followed by a blank line (markdown paragraphs)."""
    out = []
    for par in __doc__.split("\n\n")[1:]:
        out += [" ".join(par.split()), ""]
    return out


def settings_text(st: dict) -> str:
    return (f"load steps {st['load_steps']}, stabilizerODE2term {st['stabilizer']:g}, "
            f"rtol {st['rtol']:g}, atol {st['atol']:g}, adaptInitialResidual "
            f"{st['adapt_initial_residual']}, {'EigenSparse' if st['sparse'] else 'dense'}")


def _fmt(x):
    return "—" if x is None else (f"{x:.3g}")


if __name__ == "__main__":
    for r in run(quick="--quick" in sys.argv, repeat=3):
        print(json.dumps(r, default=float))
