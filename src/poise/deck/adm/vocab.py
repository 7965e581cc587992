"""The Adams dataset vocabulary: every statement and command poise knows, and its keywords.

One table drives the reader (how each keyword's value is scanned: a flag, numbers, an expression
running to ``\\`` or the end of the statement, a string), the abbreviation rule (an exact name,
else a unique prefix among the statement's flags or valued keywords), what becomes of the
statement (``translate``, ``skip``: no effect on statics, one warning per kind, ``refuse``:
physics poise does not have, a located problem that ``--ignore KIND`` turns into a recorded
omission) and docs/adm.md's tables. A keyword kind ending in ``-`` is accepted and ignored (it
has no effect on equilibria: initial velocities, damping-only data, output options).
"""
from __future__ import annotations

import difflib
from dataclasses import dataclass, field

#: keyword kinds: flag (no value), int, ints, real, reals, expr (to ``\\`` or the statement's
#: end), str (to the next comma), and the same with "-" (accepted, no effect on statics)
KINDS = ("flag", "int", "ints", "real", "reals", "expr", "str")


@dataclass(frozen=True)
class Keyword:
    name: str
    kind: str
    ignored: bool = False


@dataclass(frozen=True)
class StatementDef:
    """One statement (or ACF command): its keywords and what poise does with it."""

    name: str
    status: str                         # translate | skip | refuse | command
    has_id: str = "yes"                 # yes | no | optional
    keywords: dict = field(default_factory=dict)   # NAME -> Keyword (valued)
    flags: dict = field(default_factory=dict)      # NAME -> Keyword (flag)
    aliases: dict = field(default_factory=dict)    # short spelling -> NAME
    why: str = ""                       # skip / refuse: the reason said in the message
    xml: str = ""                       # docs: the XML element(s) it becomes
    kind: str = ""                      # refuse: the --ignore KIND (default: the name)

    def resolve(self, word: str, valued: bool) -> tuple[str | None, str]:
        """Canonical keyword of ``word`` (case-insensitive; an exact name, an alias or a unique
        prefix) among the valued keywords (``valued``) or the flags; (None, message) else."""
        key = (id(self), word, valued)
        hit = _RESOLVED.get(key)
        if hit is None:
            hit = _RESOLVED[key] = self._resolve(word, valued)
        return hit

    def _resolve(self, word: str, valued: bool) -> tuple[str | None, str]:
        table = self.keywords if valued else self.flags
        w = word.upper()
        if w in table:
            return w, ""
        if w in self.aliases and self.aliases[w] in table:
            return self.aliases[w], ""
        hits = [n for n in table if n.startswith(w)]
        if len(hits) == 1:
            return hits[0], ""
        if not hits:    # Adams reads a longer spelling too (TRANSLATIONAL for TRANSLATION)
            longer = [n for n in table if w.startswith(n) and len(n) >= 4]
            if len(longer) == 1:
                return longer[0], ""
        kind = "keyword" if valued else "option"
        if hits:
            return None, (f"ambiguous {kind} {word!r}; it abbreviates " + ", ".join(sorted(hits)))
        other = self.flags if valued else self.keywords
        if w in other or len([n for n in other if n.startswith(w)]) == 1:
            name = w if w in other else next(n for n in other if n.startswith(w))
            return None, (f"{name} takes no value" if valued else f"{name} needs a value "
                          f"({name}=...)")
        near = difflib.get_close_matches(w, list(table), n=1, cutoff=0.6)
        expect = ("; expected one of " + ", ".join(sorted(table))) if len(table) <= 12 else ""
        return None, (f"unknown {kind} {word!r}" + (f"; did you mean {near[0]}?" if near
                                                     else expect))


_RESOLVED: dict[tuple, tuple] = {}      # (id(StatementDef), word, valued) -> resolve()


def _kw(spec: str) -> tuple[dict, dict]:
    """``"GROUND MASS:real IP:reals VX:real-"`` -> (valued keywords, flags)."""
    valued, flags = {}, {}
    for item in spec.split():
        name, _, kind = item.partition(":")
        kind = kind or "flag"
        ignored = kind.endswith("-")
        kind = kind.rstrip("-")
        assert kind in KINDS, item
        k = Keyword(name, kind, ignored)
        (flags if kind == "flag" else valued)[name] = k
    return valued, flags


_DEFS: dict[str, StatementDef] = {}


def st(name, status, spec="", has_id="yes", aliases=None, why="", xml="", table=None, kind=""):
    valued, flags = _kw(spec + (" LABEL:str" if status in ("translate", "command") else ""))
    (table if table is not None else _DEFS)[name] = StatementDef(
        name, status, has_id, valued, flags, dict(aliases or {}), why, xml, kind or name)


_USER = " ROUTINE:str"
_VEL = " VX:real- VY:real- VZ:real- WX:real- WY:real- WZ:real- VM:int- WM:int- EXACT:str-"

# ------------------------------------------------------------------------ translated statements
st("UNITS", "translate", "FORCE:str MASS:str LENGTH:str TIME:str SYSTEM:str UCF:real", "no",
   xml="Param_Unit")
st("PART", "translate", "GROUND MASS:real CM:int IM:int IP:reals QG:reals REULER:reals XG:reals "
   "ZG:reals MATERIAL:str- DENSITY:real- PLANAR-" + _VEL, xml="Body_Rigid")
st("POINT_MASS", "translate", "MASS:real CM:int QG:reals REULER:reals XG:reals ZG:reals" + _VEL,
   xml="Body_Point")
st("MARKER", "translate", "PART:int POINT_MASS:int FLEX_BODY:int FE_PART:int NODE_ID:int "
   "NODE_LABEL:str QP:reals "
   "REULER:reals XP:reals ZP:reals USEXP FLOATING", xml="Reference_Marker")
_JOINTS = "REVOLUTE SPHERICAL TRANSLATIONAL CYLINDRICAL FIXED UNIVERSAL HOOKE PLANAR CONVEL "
st("JOINT", "translate", "I:int J:int " + _JOINTS + "RACKPIN SCREW PD:real PITCH:real "
   "IC:reals- ICTRAN:reals- ICROT:reals- DELTA_V:real- MAXIMUM_DEFORMATION:real-",
   xml="Constraint_Joint")
st("JPRIM", "translate", "I:int J:int ATPOINT INLINE INPLANE ORIENTATION PARALLEL_AXES "
   "PERPENDICULAR", xml="Constraint_Jprim")
st("MOTION", "translate", "JOINT:int I:int J:int TRANSLATION ROTATION X Y Z B1 B2 B3 "
   "DISPLACEMENT VELOCITY ACCELERATION FUNCTION:expr ICDISP:real ICVEL:real" + _USER,
   xml="Motion_Joint, Motion_Marker")
st("SFORCE", "translate", "I:int J:int TRANSLATION ROTATION ACTIONONLY FUNCTION:expr" + _USER,
   xml="Force_Scalar_TwoBody")
st("SPRINGDAMPER", "translate", "I:int J:int TRANSLATION ROTATION K:real C:real LENGTH:real "
   "FORCE:real KT:real CT:real ANGLE:real TORQUE:real", xml="Force_SpringDamper")
st("BUSHING", "translate", "I:int J:int K:reals KT:reals C:reals CT:reals FORCE:reals "
   "TORQUE:reals", xml="Force_Bushing")
st("BEAM", "translate", "I:int J:int LENGTH:real IXX:real IYY:real IZZ:real AREA:real ASY:real "
   "ASZ:real EMODULUS:real GMODULUS:real CRATIO:real CMATRIX:reals- SECTION:str-",
   xml="Force_Beam")
st("FIELD", "translate", "I:int J:int KMATRIX:reals CMATRIX:reals CRATIO:real LENGTH:reals "
   "FORCE:reals FUNCTION:expr" + _USER, xml="Force_Field")
_VF = "I:int JFLOAT:int RM:int FUNCTION:expr" + _USER
st("VFORCE", "translate", _VF + " FX:expr FY:expr FZ:expr",
   xml="Force_Vector_TwoBody / Force_Vector_OneBody (JFLOAT on ground)")
st("VTORQUE", "translate", _VF + " TX:expr TY:expr TZ:expr",
   xml="Force_Vector_TwoBody / Force_Vector_OneBody (JFLOAT on ground)")
st("GFORCE", "translate", _VF + " FX:expr FY:expr FZ:expr TX:expr TY:expr TZ:expr",
   xml="Force_Vector_TwoBody / Force_Vector_OneBody (JFLOAT on ground)")
st("ACCGRAV", "translate", "IGRAV:real JGRAV:real KGRAV:real", "no", xml="Force_Gravity")
st("VARIABLE", "translate", "FUNCTION:expr IC:real" + _USER, xml="Reference_Variable")
st("DIFF", "translate", "FUNCTION:expr IC:reals IMPLICIT STATIC_HOLD" + _USER,
   xml="Control_Diff")
st("SPLINE", "translate", "X:reals Y:reals Z:reals LINEAR_EXTRAPOLATE FILE:str BLOCK:str",
   xml="Reference_Spline")
st("ARRAY", "translate", "IC U X Y NUMBERS:reals SIZE:int VARIABLES:ints", xml="Reference_Array")
st("CURVE", "translate", "MATRIX:int CLOSED OPEN CURVE_POINTS MINPAR:real MAXPAR:real ORDER:int "
   "FUNCTION:expr" + _USER, xml="Reference_ParamCurve")
st("MATRIX", "translate", "FULL:str SPARSE ROWS:int COLUMNS:int I:ints J:ints VALUES:reals "
   "FILE:str NAME:str", xml="Reference_Matrix")
st("PTCV", "translate", "I:int JFLOAT:int CURVE:int RM:int DISP:reals VEL:real-",
   xml="Constraint_PTCV")
st("CVCV", "translate", "IFLOAT:int JFLOAT:int ICURVE:int JCURVE:int IRM:int JRM:int "
   "IDISP:reals JDISP:reals IVEL:real- JVEL:real-", xml="Constraint_CVCV")
st("COUPLER", "translate", "JOINTS:ints TYPE:str SCALES:reals FUNCTION:expr" + _USER,
   xml="Constraint_Coupler")
st("GEAR", "translate", "JOINTS:ints CV:int", xml="Constraint_Gear")
st("GCON", "translate", "FUNCTION:expr I:int" + _USER, xml="Constraint_General")
_EQ = ("ALIMIT:real- ERROR:real IMBALANCE:real MAXIT:int PATTERN:str- STABILITY:real "
       "TLIMIT:real- STATIC DYNAMIC GLOBAL_DAMPING:real- SETTLING_TIME:real- "
       "KINETIC_ENERGY_ERROR:real ACCELERATION_ERROR:real- METHOD:str- ATOL:real- RTOL:real- "
       "MAXITL:int- ETAMAX:real- ETA:real- FIM_S FIM_D MKEAM COMPDELTA:real MAX_KE_TOL:real "
       "MAX_DQ_TOL:real")
st("EQUILIBRIUM", "translate", _EQ, "no", xml="Param_Static")
_INT = ("GSTIFF WSTIFF HHT NEWMARK CONSTANT_BDF HASTIFF DSTIFF CSTIFF VSTIFF MSTIFF ABAM "
        "SI2:flag- SI1:flag- I3:flag- ERROR:real HMAX:real HMIN:real HINIT:real KMAX:int MAXIT:int PATTERN:str- "
        "CORRECTOR:str- INTERPOLATE:str- ALPHA:real- BETA:real- GAMMA:real- MINIT:int "
        "CONSTR_TOL:real VEL_CTRL:int JACINIT:str")
st("INTEGRATOR", "translate", _INT, "no", xml="Param_Transient")
st("REQUEST", "translate", "DISPLACEMENT VELOCITY ACCELERATION FORCE I:int J:int RM:int "
   "F1:expr F2:expr F3:expr F4:expr F5:expr F6:expr F7:expr F8:expr COMMENT:str TITLE:str- "
   "FUNCTION:expr VARIABLES:ints- RESULTS_NAME:str- CNAMES:str- CUNITS:str- CLABELS:str-"
   + _USER, aliases={"C": "COMMENT"}, xml="Post_Request")

# ------------------------------------------------------------------------ skipped (no statics)
for _n, _why in (("GRAPHICS", "graphics"), ("OUTPUT", "output options"),
                 ("RESULTS", "results-file options"), ("KINEMATICS", "kinematic-analysis options"),
                 ("MATERIAL", "material data for graphics and mass computation"),
                 ("PREFERENCES", "solver preferences"), ("LSOLVER", "linear-solver options"),
                 ("DEBUG", "debug output options"), ("PINPUT", "controls plant input"),
                 ("POUTPUT", "controls plant output"), ("SECTION", "beam section data"),
                 ("STRING", "a character string"), ("ENVIRONMENT", "environment settings"),
                 ("MREQUEST", "multiple output requests"), ("FEMDATA", "FE output data"),
                 ("IC", "initial-conditions analysis options"), ("LIST", "listing options"),
                 ("NOLIST", "listing options"), ("DYNAMICS", "dynamic-analysis options"),
                 ("CBKSUB", "callback subroutine options"), ("UNDEFINED", "undefined data")):
    st(_n, "skip", has_id="optional", why=_why)

# ------------------------------------------------------------------------ refused (physics)
for _n, _why in (("CONTACT", "contact between CAD solids"), ("FRICTION", "joint friction"),
                 ("GSE", "general state equations"), ("LSE", "linear state equations"),
                 ("TFSISO", "transfer-function states"), ("FE_PART", "finite-element parts"),
                 ("FE_LOAD", "finite-element loads"), ("FLEX_BODY", "flexible bodies"),
                 ("NFORCE", "multi-point forces"), ("SENSOR", "sensors (event-driven changes)"),
                 ("SURFACE", "parametric surfaces (user-written or from files)"),
                 ("PTSF", "point-to-surface contact (needs SURFACE)"),
                 ("CVSF", "curve-to-surface contact (needs SURFACE)"),
                 ("SFSF", "surface-to-surface contact (needs SURFACE)"),
                 ("CLEARANCE", "clearance contact"), ("MFORCE", "modal forces"),
                 ("UCON", "user-written constraints"), ("TIRE", "tyre models"),
                 ("PSTATE", "user-defined plant states"), ("DSTATE", "discrete states"),
                 ("DEQUATION", "discrete equations")):
    st(_n, "refuse", has_id="optional", why=_why)
st("FE_NODE", "refuse", has_id="optional", why="finite-element part nodes", kind="FE_PART")

STATEMENTS = _DEFS
END = "END"

# ------------------------------------------------------------------------ ACF commands
ACF: dict[str, StatementDef] = {}
st("FILE", "command", "MODEL:str OUTPUT_PREFIX:str- COMMAND:str", "no", table=ACF)
st("SIMULATE", "command", "STATIC DYNAMIC KINEMATIC TRANSIENT INITIAL_CONDITIONS END:real "
   "DURATION:real STEPS:int DTOUT:real", "no", table=ACF)
_ACT = ("BEAM BUSHING FIELD GFORCE JOINT JPRIM MOTION SFORCE SPRINGDAMPER VFORCE VTORQUE COUPLER "
        "GEAR GCON DIFF VARIABLE PTCV CVCV CONTACT FRICTION SENSOR GSE LSE TFSISO NFORCE "
        "ID:ints RANGE:ints")
st("ACTIVATE", "command", _ACT, "no", table=ACF)
st("DEACTIVATE", "command", _ACT, "no", table=ACF)
st("STOP", "command", "", "no", table=ACF)
for _n, _why in (("OUTPUT", "output options"), ("RESULTS", "results-file options"),
                 ("PREFERENCES", "solver preferences"), ("DEBUG", "debug output options"),
                 ("SHOW", "printing the model"), ("INFO", "printing the model"),
                 ("PLOT", "plotting"), ("MENU", "interactive menus"), ("HELP", "help"),
                 ("KINEMATICS", "kinematic-analysis options"), ("LSOLVER", "linear-solver options"),
                 ("IC", "initial-conditions analysis options"), ("TIME", "printing the time"),
                 ("GRAPHICS", "graphics"), ("REQUEST", "output requests"),
                 ("MREQUEST", "output requests"), ("ENVIRONMENT", "environment settings")):
    st(_n, "skip", has_id="optional", why=_why, table=ACF)
for _n, _why in (("LINEAR", "linear (eigen/state-matrix) analyses"),
                 ("SAVE", "saving and reloading states"), ("RELOAD", "saving and reloading states"),
                 ("CONTROL", "user control subroutines (CONSUB)"),
                 ("SENSOR", "sensors (event-driven changes)")):
    st(_n, "refuse", has_id="optional", why=_why, table=ACF)
#: model statements an ACF may redefine between simulations (their ACF vocabulary is the
#: statement's own); the translation decides which keywords may change
REDEFINABLE = ("ACCGRAV", "BEAM", "BUSHING", "DIFF", "EQUILIBRIUM", "FIELD", "GFORCE",
               "INTEGRATOR", "MOTION", "PART", "SFORCE", "SPRINGDAMPER", "VARIABLE", "VFORCE",
               "VTORQUE", "MARKER", "JOINT", "GCON", "REQUEST", "UNITS", "POINT_MASS", "SPLINE",
               "ARRAY", "MATRIX", "CURVE")


#: kinds ``--ignore`` accepts: the refused statements, USER (user subroutines) and CURVE
#: (control-point curves)
IGNORABLE = sorted({d.kind for t in (_DEFS, ACF) for d in t.values() if d.status == "refuse"}
                   | {"USER", "CURVE"})


def lookup(name: str, table: dict) -> tuple[StatementDef | None, str]:
    """The statement a written name stands for (exact, else a unique prefix), or a message."""
    n = name.upper()
    if n in table:
        return table[n], ""
    hits = [k for k in table if k.startswith(n)]
    if len(hits) == 1:
        return table[hits[0]], ""
    if hits:
        return None, f"ambiguous statement {name!r}; it abbreviates " + ", ".join(sorted(hits))
    near = difflib.get_close_matches(n, list(table), n=1, cutoff=0.6)
    return None, f"unknown statement {name!r}" + (f"; did you mean {near[0]}?" if near else "")
