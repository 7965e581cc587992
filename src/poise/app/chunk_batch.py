"""A chunk of sweep cases solved together (:mod:`poise.solvers.batched`), when it may be.

A group's cases share the deck's structure; when what they change are per-instance parameters
of tileable force elements (a spring's stiffness, a force's value, ...), every case's model is
the group's model with those arrays replaced. :func:`plan_batch` finds out, once per template,
by compiling the deck at an anchor case and at probes moving one parameter each: only
per-instance arrays of tileable, non-constraint families may change, and affinely in the
parameters (checked at a further probe moving them all); the batched evaluation of every probe
must equal its own model's evaluation (residual and Jacobian). Otherwise, or for what the
batched solve does not cover (not one static FIM_S/FIM_D analysis, ``--require-stable``,
compliance, per-case files, user code, a configuration off its constraints, outputs other than
body poses), the chunk is solved case by case as before. Cases the batch does not converge
cleanly (:class:`~poise.solvers.batched.CaseResult` ``alone``) are solved alone, so their
records are the single solve's.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, fields, replace

import numpy as np

from poise.app.cases import apply_case
from poise.app.runner import plan
from poise.core.errors import DeckError, ProblemCollector, UsageError
from poise.deck.checks import check_element, check_specific
from poise.deck.schema import element_schema
from poise.model.compile import compile_model
from poise.model.frame_batch import batchable, chunk_size
from poise.elements.registry import tileable_kernels
from poise.solvers.batched import CaseBatch
from poise.solvers.reach import ASSEMBLY_TOL
from poise.solvers.redundancy import detect_redundancy
from poise.solvers.stability import DENSE_LIMIT

AFFINE_REL = 1e-12            # affine prediction of a probe's arrays, relative
EVAL_REL = 1e-10              # batched vs own evaluation of a probe, relative
POSE_OUTPUTS = ("position", "orientation")


@dataclass(frozen=True)
class BatchPlan:
    """How a template's cases are solved together: the ``model`` (compiled at the anchor
    case), its ``settings``, the anchor values ``v0``, per family index ``{field: (base,
    (per-parameter slopes))}``, the start state and active rows, and ``input_files``."""

    model: object
    settings: object
    keys: tuple
    v0: np.ndarray
    arrays: dict
    state0: object
    active: np.ndarray
    input_files: str = ""

    def fields(self, values: np.ndarray) -> dict:
        """Per family ``{field: (C, n, ...)}`` of cases ``values`` (C, P)."""
        dv = values - self.v0[None]
        out = {}
        for fi, fl in self.arrays.items():
            out[fi] = {}
            for k, (base, slopes) in fl.items():
                a = np.broadcast_to(base, (len(values), *base.shape)).copy()
                for p, s in enumerate(slopes):
                    if s is not None:
                        a += dv[:, p].reshape((-1,) + (1,) * base.ndim) * s[None]
                out[fi][k] = a
        return out


_PLANS: dict = {}


def plan_for(template, anchor: dict):
    """:func:`plan_batch`, cached per template (None: solve case by case)."""
    key = id(template)
    hit = _PLANS.get(key)
    if hit is None or hit[0] is not template:
        if len(_PLANS) > 8:
            _PLANS.clear()
        try:
            p = plan_batch(template, anchor)
        except Exception:  # noqa: BLE001 - anything unexpected: the case-by-case path
            p = None
        hit = _PLANS[key] = (template, p)
    return hit[1]


def plan_batch(template, anchor: dict) -> BatchPlan | None:
    """The :class:`BatchPlan` of ``template``'s cases (module docstring), or None."""
    job = template.job
    model0 = template.model
    if job.case_dir is not None or model0 is None or model0.user_routines \
            or job.layout.n != 1 or job.allow_user_code:
        return None
    if any(o.group != "bodies" or o.dataset not in POSE_OUTPUTS for o in job.outputs):
        return None
    params = list(job.numeric)
    if any(p.tag == "Param_Static" or p.override for p in params):
        return None
    keys = tuple(p.key for p in params)
    try:
        reqs = plan(template.spec, template.overrides)
    except (DeckError, UsageError, ValueError):
        return None
    if len(reqs) != 1 or reqs[0].kind != "static" or reqs[0].commands:
        return None
    s = reqs[0].settings
    if s.method not in ("FIM_S", "FIM_D") or s.require_stable \
            or s.compliance_markers != "none":
        return None
    v0 = np.array([float(anchor[k]) for k in keys], float)
    model = _compile(template, keys, v0)
    if model is None or not batchable(model) or model.nq > DENSE_LIMIT:
        return None                  # (the dense stability classification, as a single solve)
    probes = []
    for p in range(len(keys)):
        h = 0.25 * abs(v0[p]) or 1.0
        if params[p].kind == "int":
            h = max(1.0, round(h))
        v = v0.copy()
        v[p] += h
        probes.append((v, _compile(template, keys, v)))
    vc = v0 + np.array([0.37 * (pv[p] - v0[p]) for p, (pv, _) in enumerate(probes)])
    check = (vc, _compile(template, keys, vc))
    if any(m is None for _, m in probes) or check[1] is None:
        return None
    arrays = _affine(model, v0, probes, check)
    if arrays is None:
        return None
    state0 = model.initial_state()
    try:
        red = detect_redundancy(model, state0)
        phi = model.evaluate(state0, need_jac=False).phi
    except Exception:  # noqa: BLE001 - the single path reports it
        return None
    if phi.size and float(np.max(np.abs(phi) / np.where(model.row_kind == 1, 1.0,
                                                        model.L))) > ASSEMBLY_TOL:
        return None                  # assembly onto the constraints: the single path's
    active = np.ones(model.nc, bool)
    active[np.asarray(red, int)] = False
    bp = BatchPlan(model, s, keys, v0, arrays, state0, active,
                   _input_files(template.spec, model))
    if not _evaluations_agree(bp, [(v0, model), *probes, check]):
        return None
    return bp


def _compile(template, keys, values):
    job = template.job
    spec, _ = apply_case(template.spec, list(job.numeric), dict(zip(keys, values.tolist())))
    try:
        return compile_model(spec, user_code="refuse")
    except Exception:  # noqa: BLE001 - a probe that does not compile: no batch
        return None


def _plain(v) -> bool:
    return isinstance(v, (int, float, str, bool, np.integer, np.floating)) or v is None


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and \
            a.shape == b.shape and a.dtype == b.dtype and bool(np.array_equal(a, b))
    if _plain(a) and _plain(b):
        return a == b or (isinstance(a, float) and isinstance(b, float)
                          and math.isnan(a) and math.isnan(b))
    return True                       # other objects: the evaluation check decides


def _affine(model, v0, probes, check):
    """Per family ``{field: (base, slopes)}`` of the arrays that change, or None when
    anything else changes or an array is not affine in the parameters."""
    tile = tileable_kernels()
    for f in fields(model):
        if f.name == "families":
            continue
        a = getattr(model, f.name)
        if any(not _same(a, getattr(m, f.name)) for _, m in (*probes, check)):
            return None
    out: dict = {}
    for fi, fam in enumerate(model.families):
        others = [m.families[fi] for _, m in (*probes, check)]
        if any(type(o) is not type(fam) for o in others):
            return None
        for f in fields(fam):
            a = getattr(fam, f.name)
            if all(_same(a, getattr(o, f.name)) for o in others):
                continue
            if not isinstance(a, np.ndarray) or a.ndim == 0 or a.shape[0] != fam.n \
                    or fam.is_constraint or type(fam) not in tile \
                    or a.dtype.kind != "f" or f.name in ("markers", "gcol", "crow"):
                return None
            slopes = []
            for p, (v, m) in enumerate(probes):
                d = np.asarray(getattr(m.families[fi], f.name), float) - a
                slopes.append(d / (v[p] - v0[p]) if np.any(d) else None)
            vc, mc = check
            pred = a + sum((vc[p] - v0[p]) * s for p, s in enumerate(slopes) if s is not None)
            act = np.asarray(getattr(mc.families[fi], f.name), float)
            if not np.all(np.abs(pred - act) <= AFFINE_REL * max(1.0, float(np.abs(act).max()))):
                return None
            out.setdefault(fi, {})[f.name] = (a.copy(), tuple(slopes))
    return out


def _evaluations_agree(bp: BatchPlan, points) -> bool:
    """The batched evaluation of each probe equals its own model's, at a state with
    non-zero multipliers (residual and Jacobian, every row)."""
    vals = np.array([v for v, _ in points])
    batch = CaseBatch(bp.model, bp.settings, bp.fields(vals), np.ones(bp.model.nc, bool))
    st = bp.state0.copy()
    st.lam = np.linspace(0.5, 1.5, bp.model.nc) * bp.model.L
    r, phi, J = batch.evaluate(np.arange(len(points)), [st] * len(points), True)
    for k, (_, m) in enumerate(points):
        ev = m.evaluate(st, need_jac=True)
        Jk = ev.J.toarray() if hasattr(ev.J, "toarray") else np.asarray(ev.J)
        sr = max(1.0, float(np.abs(ev.r).max(initial=0.0)))
        sj = max(1.0, float(np.abs(Jk).max(initial=0.0)))
        if not (np.abs(r[k] - ev.r).max(initial=0.0) <= EVAL_REL * sr
                and np.abs(phi[k] - ev.phi).max(initial=0.0) <= EVAL_REL * bp.model.L
                and np.abs(J[k] - Jk).max(initial=0.0) <= EVAL_REL * sj):
            return False
    return True


def _input_files(spec, model) -> str:
    inputs = {**spec.input_files, **(getattr(model, "input_files", None) or {})}
    return json.dumps(inputs, sort_keys=True) if inputs else ""


class CaseChecks:
    """The per-element checks the validator runs on the elements a case changes (schema
    values, element-specific rules such as a translational spring's length >= 0): a case
    with any problem or warning is solved alone, which reports it as the single solve does."""

    def __init__(self, template):
        spec = template.spec
        self.params = list(template.job.numeric)
        self.markers = {e.id: e for e in spec.model if e.tag == "Reference_Marker"}
        self.elements = {}
        for p in self.params:
            el = next((e for e in spec.model if e.tag == p.tag and (p.id is None or e.id == p.id)),
                      None)
            if el is not None:
                self.elements.setdefault(id(el), (el, []))[1].append(p)

    def ok(self, values: dict) -> bool:
        pc = ProblemCollector()
        for el, params in self.elements.values():
            case = replace(el, attrs={**el.attrs, **{p.attr: values[p.key] for p in params}})
            check_element(pc, case, element_schema(el.tag))
            check_specific(pc, case, self.markers)
        return not (pc.problems or pc.warnings)


def solve_batched(template, cases, record, alone) -> list:
    """Records of ``cases`` (``[(case number, values)]``): the batch's where it converged
    cleanly, ``alone(index, values)`` (the single-case path) for the others. ``record``
    builds a :class:`~poise.app.chunks.CaseRecord` from ``(index, result, wall, outputs)``."""
    if not cases:
        return []
    bp = plan_for(template, cases[0][1])
    if bp is None:
        return [alone(i, v) for i, v in cases]
    checks = CaseChecks(template)
    ok = [checks.ok(v) for _, v in cases]
    if not all(ok):                    # problems: those cases alone, the others together
        good = [c for c, k in zip(cases, ok) if k]
        done = {i: r for (i, _), r in zip(good, solve_batched(template, good, record, alone)
                                          if len(good) > 1 else [alone(*c) for c in good])}
        return [done[i] if i in done else alone(i, v) for i, v in cases]
    t0 = time.perf_counter()
    vals = np.array([[float(v[k]) for k in bp.keys] for _, v in cases], float).reshape(
        len(cases), len(bp.keys))
    res = []
    step = chunk_size(bp.model)            # dense (C, N, N) Jacobians: bounded memory
    for a in range(0, len(cases), step):
        batch = CaseBatch(bp.model, bp.settings, bp.fields(vals[a:a + step]), bp.active)
        res += batch.solve(bp.state0, len(vals[a:a + step]))
    wall = (time.perf_counter() - t0) / len(cases)
    out = []
    job = template.job
    body = {int(b): k for k, b in enumerate(np.asarray(bp.model.body_id))}
    for (i, v), c in zip(cases, res):
        if c.alone:
            out.append(alone(i, v))
            continue
        outs = {}
        for o in job.outputs:
            k = body.get(int(o.id))
            if k is None:
                continue
            a = c.state.pos[k] if o.dataset == "position" else c.state.rot[k]
            outs[o.text] = np.asarray(a, float)[None]
        out.append(record(i, c, wall, outs, bp.input_files))
    return out


__all__ = ["BatchPlan", "plan_batch", "plan_for", "solve_batched"]
