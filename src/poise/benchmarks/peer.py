"""Peer side by side: the same physical problems built with Exudyn and solved with its static
solver (``mbs.SolveStatic``), in the same run as poise.

Exudyn is optional (``pip install -e '.[bench]'``); when it cannot be imported every row says so
and the report prints a note. The problems are planar, so they are built with Exudyn's planar
items (``NodeRigidBody2D`` / ``ObjectRigidBody2D``, ``RevoluteJoint2D``, ``CoordinateSpringDamper``
for the rotational spring, ``SpringDamper`` for the translational one, ``LoadMassProportional``
for gravity) in SI units (m, kg, s, N): 3 coordinates per body instead of poise's 6 and no
redundant out-of-plane equations, which favours the peer. poise solves the 3-D decks in
``decks/bench``/``poise.gen.chain`` exactly as ``poise solve`` does.

Settings (Exudyn's recommended static settings = its defaults, except the sparse solver):
``newton.relativeTolerance = 1e-8`` (default), ``absoluteTolerance = 1e-10`` (default),
``maxIterations = 25`` (default), ``numberOfLoadSteps = 1``, ``adaptiveStep = True`` (default:
load-step halving on failure), ``linearSolver.solverType = EigenSparse`` (recommended for large
systems; the default dense solver is O(n^3)), ``writeSolutionToFile = False``. poise runs at its
deck settings (``max_imbalance = max_error = 1e-8``). Both are judged by the achieved error against
the same closed-form reference (CG positions / model length scale).

The Exudyn model is built by a self-contained script (:data:`SCRIPT`) from a JSON description, so
the same code runs in-process (``exec``) and as a whole process (``python -c``).
"""
from __future__ import annotations

import json
import math
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
    MarkerBodyPosition, MarkerBodyMass, MarkerNodeCoordinate, RevoluteJoint2D, SpringDamper,
    CoordinateSpringDamper, LoadMassProportional)
t_import = time.perf_counter() - t0

def solve(spec):
    t0 = time.perf_counter()
    SC = exu.SystemContainer(); mbs = SC.AddSystem()
    ground = mbs.AddObject(ObjectGround())
    gnode = mbs.AddNode(NodePointGround(referenceCoordinates=[0, 0, 0]))
    bodies, nodes, lens = [], [], []
    for b in spec["bars"]:
        (px, py), (qx, qy), m = b["p"], b["q"], b["m"]
        l = math.hypot(qx - px, qy - py)
        th = math.atan2(qy - py, qx - px) if b.get("theta") is None else b["theta"]
        n = mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[(px + qx) / 2, (py + qy) / 2, th],
                                        initialCoordinates=[0, 0, 0]))
        o = mbs.AddObject(ObjectRigidBody2D(physicsMass=m, inertia=m * l * l / 12.0, nodeNumber=n))
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
    for a, b, k, l0 in spec.get("tsprings", []):
        mbs.AddObject(SpringDamper(markerNumbers=[marker(a), marker(b)], stiffness=k, damping=0,
                                   referenceLength=l0))
    for i, k, off in spec.get("rsprings", []):
        mg = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=gnode, coordinate=0))
        mt = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=nodes[i], coordinate=2))
        mbs.AddObject(CoordinateSpringDamper(markerNumbers=[mg, mt], stiffness=k, damping=0,
                                             offset=off))
    mbs.Assemble()
    ss = exu.SimulationSettings()
    ss.solutionSettings.writeSolutionToFile = False
    ss.staticSolver.verboseMode = 0
    ss.staticSolver.numberOfLoadSteps = spec.get("load_steps", 1)
    ss.staticSolver.stabilizerODE2term = spec.get("stabilizer", 0.0)
    ss.staticSolver.minimumStepSize = spec.get("min_step", 1e-3)
    ss.staticSolver.verboseMode = spec.get("verbose", 0)
    ss.staticSolver.newton.relativeTolerance = spec.get("rtol", 1e-8)
    ss.staticSolver.newton.absoluteTolerance = spec.get("atol", 1e-10)
    if spec.get("sparse", True):
        ss.linearSolver.solverType = exu.LinearSolverType.EigenSparse
    t1 = time.perf_counter()
    msg = ""
    try:
        ok = bool(mbs.SolveStatic(ss, storeSolver=True))
    except Exception as e:          # exudyn raises SolverError when the static solver fails
        ok, msg = False, f"{type(e).__name__}: {e}"
    t2 = time.perf_counter()
    it = None
    try:
        s = mbs.sys["staticSolver"]
        it = int(s.it.newtonStepsCount)
        steps = int(s.it.currentStepIndex)
    except Exception:
        steps = None
    q = mbs.systemData.GetODE2Coordinates()
    cg = []
    for k, n in enumerate(nodes):
        r = mbs.GetNodeOutput(n, exu.OutputVariableType.Position)
        cg.append([float(r[0]), float(r[1])])
    return dict(converged=ok, message=msg, iterations=it, load_steps=steps, build_s=t1 - t0,
                solve_s=t2 - t1, cg=cg, n_coordinates=len(q))

if __name__ == "__main__":
    spec = json.loads(open(sys.argv[1]).read())
    out = solve(spec)
    out["import_s"] = t_import
    print(json.dumps(out))
'''


# --------------------------------------------------------------------------- problems
def _ref():
    from poise.benchmarks.wp import _reference_module
    return _reference_module()


def problem_pendulum(ref):
    p = ref.PENDULUM_PARAMS if hasattr(ref, "PENDULUM_PARAMS") else None
    # 400 mm bar, 2 kg, hinge at the origin, input along +X; rotational spring k = 2e4 N mm/rad
    spec = dict(g=9.81, bars=[dict(p=[0, 0], q=[0.4, 0], m=2.0)],
                joints=[[["g", 0, 0], ["b", 0, -1]]],
                rsprings=[[0, 20.0, 6 * math.pi + 1.0]], sparse=False)
    cg_ref = {0: ref.pendulum_multiturn()["cg"][:2]}
    del p
    return dict(name="pendulum_multiturn", spec=spec, ref=cg_ref, L=400.0,
                deck="decks/bench/pendulum_multiturn.xml")


def problem_fourbar(ref):
    s = ref.fourbar_input()
    P = {k: np.asarray(v[:2]) / 1000.0 for k, v in s["points"].items()}
    fp = ref.FOURBAR_PARAMS
    spec = dict(g=9.81, bars=[dict(p=list(P["A"]), q=list(P["B"]), m=fp["m_crank"]),
                              dict(p=list(P["B"]), q=list(P["C"]), m=fp["m_coupler"]),
                              dict(p=list(P["D"]), q=list(P["C"]), m=fp["m_rocker"])],
                joints=[[["g", 0, 0], ["b", 0, -1]], [["b", 0, 1], ["b", 1, -1]],
                        [["b", 1, 1], ["b", 2, 1]], [["g", 0.4, 0], ["b", 2, -1]]],
                tsprings=[[["b", 2, 1], ["g", 0, 0], fp["k"] * 1000.0, fp["free_length"] / 1000]],
                sparse=False)
    eq = ref.fourbar_equilibrium()["cg"]
    cg_ref = {0: eq["crank"][:2], 1: eq["coupler"][:2], 2: eq["rocker"][:2]}
    return dict(name="fourbar_spring", spec=spec, ref=cg_ref, L=400.0,
                deck="decks/bench/fourbar_spring.xml")


def problem_chain(ref, n):
    a = 100.0
    span = 0.8 * n * a
    pts = ref.chain_arc(n, a, span)[:, :2] / 1000.0
    bars = [dict(p=list(pts[k]), q=list(pts[k + 1]), m=1.0) for k in range(n)]
    joints = [[["g", 0, 0], ["b", 0, -1]]]
    joints += [[["b", k - 1, 1], ["b", k, -1]] for k in range(1, n)]
    joints += [[["g", span / 1000.0, 0], ["b", n - 1, 1]]]
    spec = dict(g=9.81, bars=bars, joints=joints, sparse=n >= 20)
    cg = ref.catenary(n)["cg"]
    return dict(name=f"chain_{n}", spec=spec, ref={k: cg[k][:2] for k in range(n)}, L=span,
                deck=None, n=n)


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


def import_floor(repeat: int) -> dict:
    """Whole-process wall time of ``python -c FLOOR_IMPORTS`` (``normal``) and of
    ``python -c FLOOR_AS_POISE`` (``as_poise``), measured like the poise and peer processes
    (:func:`poise.bench._wall`)."""
    from poise.bench import _wall
    out = {}
    for key, code in (("normal", FLOOR_IMPORTS), ("as_poise", FLOOR_AS_POISE)):
        out[key], _ = _wall([sys.executable, "-c", code], repeat)
    return dict(command=f'python -c "{FLOOR_IMPORTS}"', command_as_poise=FLOOR_AS_POISE, **out)


def _poise_point(deck: Path, repeat: int):
    """poise in-process at deck settings (warm-up + repeat); returns stats and the result."""
    from poise.api import run_deck
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
    from poise.bench import _poise_cmd, _wall
    from poise.benchmarks.wp import DECKS, deck_error
    from poise.gen.chain import build_chain_deck
    rows = []
    ns: dict = {}
    if ok:
        exec(compile(SCRIPT, "<exudyn-peer>", "exec"), ns)
    floor = import_floor(repeat)
    log(f"import floor ({FLOOR_IMPORTS}): {floor['normal']['median']:.3g} s, set up as a poise "
        f"process {floor['as_poise']['median']:.3g} s")
    with tempfile.TemporaryDirectory(prefix="poise-peer-") as td:
        tdp = Path(td)
        for prob in probs:
            row = dict(bench="peer", problem=prob["name"], peer=note, peer_available=ok)
            # ---- poise
            if prob["deck"]:
                deck = Path(__file__).resolve().parents[3] / prob["deck"]
                ref_fn = DECKS[prob["name"]][3]
            else:
                deck = tdp / f"{prob['name']}.xml"
                deck.write_text(build_chain_deck(prob["n"], "revolute"))
                from poise.benchmarks.wp import _ref_chain
                ref_fn = _ref_chain(prob["n"])
            rep = repeat if prob.get("n", 0) < 1000 else max(3, repeat // 2)
            st, tot, res = _poise_point(deck, rep)
            an = res.analyses[0]
            row["poise"] = dict(status=an.status, solve_s=st, total_s=tot,
                                iterations=int(np.sum(an.datasets["frames/iterations"])),
                                error=deck_error(res, ref_fn, ref), counts=dict(res.counts))
            pw, rc = _wall(_poise_cmd() + ["solve", str(deck), "-o", str(tdp / "o.h5")], rep)
            row["poise"]["process_s"] = pw
            row["poise"]["process_rc"] = rc
            # ---- peer
            if ok:
                specf = tdp / "spec.json"
                specf.write_text(json.dumps(prob["spec"]))
                ns["solve"](prob["spec"])                       # warm-up
                outs = [ns["solve"](prob["spec"]) for _ in range(rep)]
                o = outs[-1]
                row["exudyn"] = dict(converged=o["converged"], message=o["message"],
                                     iterations=o["iterations"], load_steps=o["load_steps"],
                                     n_coordinates=o["n_coordinates"],
                                     solve_s=_stats([x["solve_s"] for x in outs]),
                                     build_s=_stats([x["build_s"] for x in outs]),
                                     error=_peer_error(o, prob) if o["converged"] else None,
                                     error_unconverged=_peer_error(o, prob))
                script = tdp / "peer_script.py"
                script.write_text(SCRIPT)
                pw, rc = _wall([sys.executable, str(script), str(specf)], rep)
                row["exudyn"]["process_s"] = pw
                row["exudyn"]["process_rc"] = rc
                ps, es = row["poise"]["solve_s"]["median"], row["exudyn"]["solve_s"]["median"]
                row["solve_ratio"] = ps / es if es > 0 else None
                row["process_ratio"] = (row["poise"]["process_s"]["median"] /
                                        row["exudyn"]["process_s"]["median"])
            if not prob.get("n"):       # small decks: the floor next to the whole-process ratio
                row["import_floor"] = floor
                fl, fp = floor["normal"]["median"], floor["as_poise"]["median"]
                row["poise_above_floor_s"] = row["poise"]["process_s"]["median"] - fp
                if ok:
                    pe = row["exudyn"]["process_s"]["median"]
                    row["floor_ratio"], row["floor_as_poise_ratio"] = fl / pe, fp / pe
            log(f"peer {prob['name']}: poise {row['poise']['solve_s']['median']:.3g} s err "
                f"{row['poise']['error']:.1e}" + (
                    f"; exudyn {'ok' if row['exudyn']['converged'] else 'FAILED'} "
                    f"{row['exudyn']['solve_s']['median']:.3g} s it {row['exudyn']['iterations']} "
                    f"err {row['exudyn']['error_unconverged']:.1e}; process "
                    f"{row['poise']['process_s']['median']:.3g} vs "
                    f"{row['exudyn']['process_s']['median']:.3g} s" if ok else f"; {note}"))
            rows.append(row)
    return rows


def _fmt(x):
    return "—" if x is None else (f"{x:.3g}")


if __name__ == "__main__":
    for r in run(quick="--quick" in sys.argv, repeat=3):
        print(json.dumps(r, default=float))
