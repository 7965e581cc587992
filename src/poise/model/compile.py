"""DeckSpec -> Model: resolve references to indices, lay out coordinates, build families.

Markers and bodies are resolved here; element families come from the ``compile(spec, ctx)``
of every registered element type (:mod:`poise.elements.registry`), in dependency order.

Only element families present in the deck are compiled (a deck without ``Force_Gravity`` has no
gravity family); ``Model.active_effects`` lists what was compiled. What makes the solution
depend on time comes from the element types' declarations (``registry.time_sources``).
"""
from __future__ import annotations

import re
from operator import itemgetter

import numpy as np

from poise.deck.schema import element_schema
from poise.deck.spec import DeckSpec, Element
from poise.core.errors import ProblemCollector
from poise.elements.context import GLOBAL, CompileContext, Geometry, MarkerPoses, num as _num
from poise.elements.registry import element_types
from poise.elements.rows import CoordNames
from poise.elements.resolver import check_variables
from poise.model import units as U
from poise.model.layout import build_model
from poise.model.model import Model
from poise.elements.rotation import from_313, from_euler_parameters, from_ypr, orthonormalize

_DCM = ("a00", "a10", "a20", "a01", "a11", "a21", "a02", "a12", "a22")


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


_POS = ("pos_x", "pos_y", "pos_z")
_DCM_ROWS = ("a00", "a01", "a02", "a10", "a11", "a12", "a20", "a21", "a22")   # row-major
_DCM_ROWS_DEFAULT = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)


def _values(attrs: list, names: tuple, defaults: tuple) -> list:
    """``[(a.get(n0, d0), a.get(n1, d1), ...) for a in attrs]``; one C-level pass when every
    element has all the names (the common case)."""
    try:
        return list(map(itemgetter(*names), attrs))
    except KeyError:
        pairs = tuple(zip(names, defaults))
        return [tuple(a.get(n, d) for n, d in pairs) for a in attrs]


def _row_of(index: dict, key, default=None):
    """``index.get(key, default)``; ``default`` for an unhashable key."""
    try:
        return index.get(key, default)
    except TypeError:
        return default


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


_INERTIA = ("inertia_xx", "inertia_yy", "inertia_zz", "inertia_xy", "inertia_yz", "inertia_xz")
_BODY_TAGS = ("Body_Rigid", "Body_Point")


class _Builder:
    """Resolves markers and bodies (the :class:`Geometry` element compilers read)."""

    def __init__(self, spec: DeckSpec):
        self.spec = spec
        self.pc = ProblemCollector()
        self.marker_els: list = []
        self.marker_glob: MarkerPoses | None = None
        self.marker_index: dict = {}
        self.marker_on_ground = np.zeros(0, bool)
        self.moving: list = []
        self.body_index: dict = {}
        self.ground_ids: set = set()
        self.needs_default_inertia: list = []
        self.nq = 0
        self.L = 1.0

    # ---------------------------------------------------------------- markers
    def markers(self):
        """Global input poses of all markers (``marker_glob``), vectorised; ``rm_id`` chains are
        composed level by level. A deck with a problem here (an expression position, a
        circular or unknown ``rm_id``) goes through :meth:`_markers_checked`, which reports the
        problems in the order of the marker-by-marker resolution."""
        els = self.spec.elements("Reference_Marker")
        self.marker_els = els
        n = len(els)
        attrs = [e.attrs for e in els]
        row = {a.get("id"): k for k, a in enumerate(attrs)}   # last element of an id wins
        try:
            P = np.array(_values(attrs, _POS, (0.0, 0.0, 0.0)), float).reshape(n, 3)
        except (TypeError, ValueError):
            return self._markers_checked(els)
        R = np.tile(np.eye(3), (n, 1, 1))
        dcm = [k for k, a in enumerate(attrs) if not a.keys().isdisjoint(_DCM)]
        if dcm:
            Ms = np.array(_values([attrs[k] for k in dcm], _DCM_ROWS, _DCM_ROWS_DEFAULT),
                          float).reshape(-1, 3, 3)
            R[dcm] = orthonormalize(Ms)
        has_r = np.zeros(n, bool)
        has_r[dcm] = True
        if len(dcm) < n:
            for k in np.flatnonzero(~has_r).tolist():
                Rk = _orientation(els[k])
                if Rk is not None:
                    R[k] = Rk
                    has_r[k] = True
        rms = [a.get("rm_id") for a in attrs]
        if any(rms):
            rmk = np.array([row.get(rm, -2) if rm else -1 for rm in rms], np.intp)
            if (rmk == -2).any():
                return self._markers_checked(els)
            src = np.array([row[e.id] for e in els], np.intp)    # the element each id reads
            P, R, has_r, rmk = P[src], R[src], has_r[src], rmk[src]
            done = rmk < 0
            while not done.all():
                lvl = np.flatnonzero(~done & (rmk >= 0))
                lvl = lvl[done[rmk[lvl]]]
                if not lvl.size:                                 # a cycle
                    return self._markers_checked(els)
                Rr = R[rmk[lvl]]
                P[lvl] = P[rmk[lvl]] + np.einsum("nij,nj->ni", Rr, P[lvl])
                R[lvl] = np.where(has_r[lvl, None, None], np.matmul(Rr, R[lvl]), Rr)
                has_r[lvl] = True
                done[lvl] = True
        self.marker_glob = MarkerPoses(row, P, R)

    def _markers_checked(self, els):
        """Marker-by-marker resolution (reports expression positions, circular or unknown
        ``rm_id`` in resolution order)."""
        byid = {e.id: e for e in els}
        glob: dict[int, tuple] = {}
        # direction cosines of all markers orthonormalised in one batch (same as _orientation)
        dcm = [e for e in els if any(k in e.attrs for k in _DCM)]
        pre = {}
        if dcm:
            Ms = np.array([[[a.get("a00", 1.0), a.get("a01", 0.0), a.get("a02", 0.0)],
                            [a.get("a10", 0.0), a.get("a11", 1.0), a.get("a12", 0.0)],
                            [a.get("a20", 0.0), a.get("a21", 0.0), a.get("a22", 1.0)]]
                           for a in (e.attrs for e in dcm)], float)
            pre = dict(zip(map(id, dcm), orthonormalize(Ms)))

        def resolve(mid, stack=()):
            if mid in glob:
                return glob[mid]
            el = byid[mid]
            p = np.array([_num(el, "pos_x", 0.0, self.pc), _num(el, "pos_y", 0.0, self.pc),
                          _num(el, "pos_z", 0.0, self.pc)], float)
            R = pre[id(el)] if id(el) in pre else _orientation(el)
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
        row = {mid: k for k, mid in enumerate(glob)}
        P = np.array([v[0] for v in glob.values()], float).reshape(len(glob), 3)
        R = np.array([v[1] for v in glob.values()], float).reshape(len(glob), 3, 3)
        self.marker_glob = MarkerPoses(row, P, R)

    # ---------------------------------------------------------------- bodies
    def bodies(self, mfac):
        """Moving bodies: one light pass over the elements (values and, in element order, the
        problems), then the inertia transforms of all bodies in one batch."""
        spec = self.spec
        rig = [e for e in spec.model if e.tag in _BODY_TAGS]
        moving = [e for e in rig if not (e.tag == "Body_Rigid" and e.attrs.get("isground"))]
        ground = [e for e in rig if e.tag == "Body_Rigid" and e.attrs.get("isground")]
        ground_ids = {e.id for e in ground}
        self.body_index = {e.id: i for i, e in enumerate(moving)}
        self.ground_ids = ground_ids
        self.ground_frames = {e.attrs.get(k) for e in ground for k in ("cg_id", "lprf_id")}
        nb = len(moving)
        rigid = [e.tag == "Body_Rigid" for e in moving]
        kind = np.array([0 if r else 1 for r in rigid], int)
        pc = self.pc
        mrow = self.marker_glob.row
        cgk = np.full(nb, -1, np.intp)        # marker row of the CG marker (-1: none)
        imk = np.full(nb, -1, np.intp)        # marker row of the inertia marker (-1: the CG)
        mass = np.zeros(nb)
        inert = np.zeros((nb, 6))
        has_in = np.zeros(nb, bool)
        off = np.zeros(nb, int)
        prefixes: list[str] = []
        o = 0
        for i, e in enumerate(moving):
            a = e.attrs
            off[i] = o
            cg = a.get("cg_id")
            k = _row_of(mrow, cg)
            if k is None:
                pc.error(e.loc, f"cg_id {cg} is not a Reference_Marker; expected a marker id",
                         "cg_id")
            else:
                cgk[i] = k
            m = a.get("mass", 0.0)
            if type(m) is not float:
                m = float(_num(e, "mass", 0.0, pc) or 0.0)
            mass[i] = m
            prefixes.append(e.loc.prefix()[:-1])       # its coordinates' names (CoordNames)
            o += 6 if rigid[i] else 3
            if rigid[i]:
                if a.keys().isdisjoint(_INERTIA):
                    pc.warn(e.loc, "no inertia given; using m*(0.1*L)^2 (only the stability "
                            "regularisation and MKEAM use it)")
                    self.needs_default_inertia.append(e.id)
                    continue
                vals = [a.get(k, 0.0) for k in _INERTIA]
                if not all(type(v) is float for v in vals):
                    vals = [float(_num(e, k, 0.0, pc) or 0.0) for k in _INERTIA]
                inert[i] = vals
                has_in[i] = True
                imk[i] = _row_of(mrow, a.get("im_id") or a.get("cg_id"), -1)
        Pm, Rm = self.marker_glob.P, self.marker_glob.R
        ok = cgk >= 0
        pos = np.zeros((nb, 3))
        rot = np.tile(np.eye(3), (nb, 1, 1))
        pos[ok] = Pm[cgk[ok]]
        R_cg = np.tile(np.eye(3), (nb, 1, 1))
        R_cg[ok] = Rm[cgk[ok]]
        rot[kind == 0] = R_cg[kind == 0]
        inertia = np.zeros((nb, 3, 3))
        sel = np.flatnonzero(has_in)
        if sel.size:
            xx, yy, zz, xy, yz, xz = inert[sel].T
            Jl = np.stack([xx, -xy, -xz, -xy, yy, -yz, -xz, -yz, zz], 1).reshape(-1, 3, 3)
            p_cg, Rc = pos[sel], R_cg[sel]
            im = imk[sel]
            own = im >= 0
            p_im = np.where(own[:, None], Pm[np.maximum(im, 0)], p_cg)
            R_im = np.where(own[:, None, None], Rm[np.maximum(im, 0)], Rc)
            Jg = np.matmul(np.matmul(R_im, Jl), np.swapaxes(R_im, 1, 2))
            d = p_cg - p_im
            dd = np.einsum("ni,ni->n", d, d)
            par = dd[:, None, None] * np.eye(3) - d[:, :, None] * d[:, None, :]
            Jcg = Jg - mass[sel, None, None] * par
            inertia[sel] = np.matmul(np.matmul(np.swapaxes(Rc, 1, 2), Jcg), Rc) * mfac
        self.moving = moving
        self.nq = o
        return dict(body_id=np.array([e.id for e in moving], int),
                    body_label=[str(e.attrs.get("label", "")) for e in moving],
                    body_kind=kind, body_mass=mass * mfac, body_inertia=inertia, body_off=off,
                    init_pos=pos, init_rot=rot, coord_info=CoordNames(prefixes, off, o))

    def marker_arrays(self, body_pos, body_rot):
        els = self.marker_els
        nb = len(self.moving)
        ids = [0] + [e.attrs.get("id") for e in els]
        self.marker_index = {0: GLOBAL}
        self.marker_index.update((mid, k + 1) for k, mid in enumerate(ids[1:]))
        glob = self.marker_glob
        src = np.array([glob.row[mid] for mid in ids[1:]], np.intp)
        P, R = glob.P[src], glob.R[src]
        bidx = self.body_index
        bids = [e.attrs.get("body_id") for e in els]
        mb = np.array([_row_of(bidx, b, nb) for b in bids], int).reshape(len(els))
        for k in np.flatnonzero(mb == nb).tolist():
            if bids[k] not in self.ground_ids:
                self.pc.error(els[k].loc, f"body_id {bids[k]} is not a body; expected the id "
                              "of a Body_Rigid or Body_Point", "body_id")
        self.marker_on_ground = mb == nb           # (marker_els,) not on a moving body
        s0 = P.copy()
        A0 = R.copy()
        mv = np.flatnonzero(mb < nb)
        if mv.size:
            b = mb[mv]
            RbT = np.swapaxes(body_rot[b], 1, 2)
            s0[mv] = np.einsum("nij,nj->ni", RbT, P[mv] - body_pos[b])
            A0[mv] = np.matmul(RbT, R[mv])
        self.marker_P = P
        self.L = _extent(P)
        return dict(marker_id=np.array(ids, int), marker_body=np.concatenate([[nb], mb]),
                    marker_s0=np.concatenate([np.zeros((1, 3)), s0]),
                    marker_A0=np.concatenate([np.eye(3)[None], A0]))

    def geometry(self, body_mass) -> Geometry:
        """What element compilers read (effective masses ``body_mass``)."""
        cg = np.array([self.marker_index.get(e.attrs.get("cg_id"), GLOBAL) for e in self.moving],
                      int)
        return Geometry(marker_index=self.marker_index, poses=self.marker_glob,
                        marker_elements=tuple(self.marker_els),
                        marker_on_ground=np.concatenate([[True], self.marker_on_ground]),
                        body_index=self.body_index, body_cg=cg, body_mass=body_mass, L=self.L)


def _extent(P) -> float:
    """Largest distance of the points ``P`` (n, 3) from their centroid (1.0 if none or 0)."""
    L = float(np.max(np.linalg.norm(P - P.mean(axis=0), axis=1))) if len(P) else 0.0
    return L if L > 0 and np.isfinite(L) else 1.0


def _named_markers(spec, ids) -> np.ndarray:
    """(len(ids),) bool: the marker is named by a model element other than a
    ``Reference_Marker`` (its ``rm_id`` frame) or an output-only ``Post_*``: in a marker
    attribute of the schema (``*marker_id``, ``cg_id``, ``lprf_id``, ...: a gear's contact
    point) or as a number in a text attribute (an expression's ``DX(200,101,101)``; a number
    that is not a marker there only keeps a marker in, as before)."""
    named = set()
    for tag in {e.tag for e in spec.model}:
        sch = element_schema(tag)
        if tag == "Reference_Marker" or tag.startswith("Post_"):
            continue
        keys = [a.name for a in sch.attrs.values() if a.ref == "marker"] if sch else []
        for el in spec.elements(tag):
            named.update(el.attrs.get(k) for k in keys)
            for v in el.attrs.values():
                v = getattr(v, "text", v)                 # an expression: its text
                if isinstance(v, str):
                    named.update(int(t) for t in re.findall(r"(?<![\w.])\d+(?![\w.])", v))
    return np.array([i in named for i in ids], bool)


UNUSED_REACH = 10.0      # model sizes: an unused marker farther out sets no scale


def _participating_extent(spec, b, markers, fams) -> float:
    """The model size ``L``: :func:`_extent` of the markers that play a part: on moving
    bodies, the ground's frames, read by an element family (``f.markers``; row 0 of the marker
    arrays is the global frame) or a user routine, or else named by a model element
    (:func:`_named_markers`, scanned only when markers are left over), and the unused ones
    within ``UNUSED_REACH`` of them. A marker nothing reads far outside the model (an unused
    ground marker 1e14 mm away, one only a Post_Request names) must not set the scale of
    tolerances, rotations and the stability classification. All markers when none plays a
    part."""
    ids = markers["marker_id"][1:]
    used = markers["marker_body"][1:] < len(b.moving)
    used |= np.isin(ids, np.array([i for i in b.ground_frames if i is not None], int))
    idx = [np.asarray(getattr(f, "markers", np.zeros((0, 0), int)), np.int64).ravel()
           for f in fams]
    for f in fams:
        r = getattr(f, "routine", None)          # a user routine also reads ground markers
        if r is not None:
            idx.append(np.array([r.mi.get(mid, 0) for mid, _ in r.slots], np.int64))
    idx = np.concatenate(idx + [np.zeros(0, np.int64)]) - 1
    used[idx[(idx >= 0) & (idx < len(used))]] = True
    if not used.all():
        used |= _named_markers(spec, ids.tolist())
    if not used.any():
        return b.L
    # a marker nothing uses still counts within UNUSED_REACH model sizes of those that do (the
    # ground origin of a dataset, a graphics anchor: the scale they always set), never beyond
    P = b.marker_P
    c = P[used].mean(axis=0)
    near = np.linalg.norm(P - c, axis=1) <= UNUSED_REACH * _extent(P[used])
    return _extent(P[used | near])


def compile_model(spec: DeckSpec, user_code: str = "refuse") -> Model:
    """Compile a validated :class:`DeckSpec` into a :class:`Model`.

    ``user_code`` says what to do with Python user routines the deck names
    (``poise.core.user_routines``): ``"run"`` imports and probes them (the caller's
    ``allow_user_code``), ``"refuse"`` (default) makes each a located deck error saying how to
    allow it, ``"skip"`` (``poise check``) validates the reference and leaves the element out of
    the model, running nothing. ``Model.user_routines`` lists them; ``Model.input_files`` maps
    each script read to its SHA-256 (freshness of batch results).

    Raises
    ------
    poise.core.errors.DeckError
        For problems only visible at this stage (unsupported joint types, expressions where
        numbers are needed, ...), all collected.
    """
    with spec.indexed():      # elements(tag) from one tag index, not one scan per call
        return _compile(spec, user_code)


def _compile(spec: DeckSpec, user_code: str = "refuse") -> Model:
    b = _Builder(spec)
    mfac, udesc = unit_info(spec)
    b.markers()
    bodies = b.bodies(mfac)
    markers = b.marker_arrays(bodies["init_pos"], bodies["init_rot"])

    ctx = CompileContext(spec, b.geometry(bodies["body_mass"]), b.pc, user_code)
    types = element_types()
    for et in types:                      # dependency order (poise.elements.registry)
        et.compile(spec, ctx)
    check_variables(spec, ctx)            # variables no element reads: problems located too
    try:
        result = ctx.result()             # raises the problems collected
    finally:
        ctx.close()                       # no cycle left holding the deck
    # L from the markers that play a part (unknown when a user routine was not run: which
    # markers it reads is learnt by running it; all markers then, as poise check needs no more)
    L = b.L
    if not (result.user_routines and user_code != "run"):
        L = _participating_extent(spec, b, markers, result.families)
    for f in result.families:             # user routines' finite-difference steps scale with L
        if getattr(f, "routine", None) is not None:
            f.routine.L = L               # before the model is built and sealed
    for bid in b.needs_default_inertia:
        i = b.body_index[bid]
        bodies["body_inertia"][i] = bodies["body_mass"][i] * (0.1 * L) ** 2 * np.eye(3)
    return build_model(bodies=bodies, markers=markers, result=result, nq_bodies=b.nq, L=L,
                       units=udesc, mass_factor=mfac, types=types, warnings=b.pc.warnings)
