"""The deck schema: one table that drives parsing, defaults, validation and documentation.

Every element poise knows is one ``el(...)`` entry (canonical tag, kind, whether it is
supported, its :class:`~poise.deck.schema_types.Attr` list). Conventions fixed here (see also
``/work/shared/reference/conventions.md``): products of inertia ``inertia_xy/yz/xz`` are the
integrals ``∫xy dm`` ... about the ``im_id`` marker axes, the tensor is
``[[xx, -xy, -xz], [-xy, yy, -yz], [-xz, -yz, zz]]`` and must be positive definite for a moving
body; attribute aliases (``Param_Static max_residual`` -> ``max_error``) and enum value aliases
(``Quasi-Static`` -> ``QUASISTATIC``) are stored canonical; defaults are filled in for model
elements only (commands carry exactly what is written); marker id ``0`` (the global frame) is
accepted where :attr:`Attr.zero_ok` is set.
"""
from __future__ import annotations

from poise.deck.schema_types import (NAMESPACES, SIX, USR, A, Attr, B, E, ElementSchema, ID, LABEL,
                                     M, R, xyz)


#: Largest marker coordinate magnitude: squared distances of larger ones overflow a float (1e154)
#: and a model spanning more is not a model; refused as a located deck error.
COORD_MAX = 1e100

#: Smallest convergence tolerance accepted (deck and CLI): below it the solvers' scaled squares
#: (1/tol**2) overflow, so a tighter tolerance can only end in a meaningless failure.
TOL_MIN = 1e-100


_ENTRIES: list[ElementSchema] = []


def el(tag, kind, supported, doc, attrs, open_attrs=False, aliases=()) -> None:
    flat: list[Attr] = []
    for a in attrs:
        flat.extend(a if isinstance(a, list) else [a])
    amap = {a.name: a for a in flat}
    alias_map = {al: a.name for a in flat for al in a.aliases}
    _ENTRIES.append(ElementSchema(tag, kind, supported, amap, doc, open_attrs,
                                  tuple(aliases), alias_map))


MASS_UNITS = ("GRAM MILLIGRAM KILOGRAM MEGAGRAM POUND_MASS SLUG OUNCE_MASS KPOUND_MASS TONNE "
              "MICROGRAM NANOGRAM US_TON SLINCH")
LENGTH_UNITS = ("INCH FOOT MILE MILLIMETER CENTIMETER METER KILOMETER NANOMETER ANGSTROM YARD "
                "MILLIINCH MICROINCH MILS MICROMETER")
FORCE_UNITS = ("OUNCE_FORCE POUND_FORCE KPOUND_FORCE DYNE NEWTON KILOGRAM_FORCE KNEWTON CENTINEWTON "
               "MILLINEWTON MICRONEWTON MEGANEWTON POUNDAL NANONEWTON")
TIME_UNITS = "MILLISECOND SECOND MINUTE HOUR MICROSECOND NANOSECOND DAY"
JOINT_TYPES = ("REVOLUTE SPHERICAL TRANSLATIONAL CYLINDRICAL FIXED UNIVERSAL HOOKE PLANAR "
               "CONSTANT_VELOCITY INLINE INPLANE ORIENTATION PARALLEL_AXES PERPENDICULAR ATPOINT "
               "SCREW RACK_PINION FREE")
JPRIM_TYPES = "ATPOINT INLINE INPLANE ORIENTATION PARALLEL_AXES PERPENDICULAR"
VEC_TYPES = "FORCEONLY TORQUEONLY FORCEANDTORQUE"
ANALYSIS_TYPES = "STATIC TRANSIENT LINEAR ASSEMBLY QUASISTATIC"
#: enum value aliases (upper case) -> canonical value, applied to every enum attribute
ENUM_ALIASES = {"QUASI-STATIC": "QUASISTATIC", "QUASI_STATIC": "QUASISTATIC", "US TON": "US_TON"}
DMS = "D V A"

# --------------------------------------------------------------------------- units, gravity
el("Param_Unit", "model", True, "Unit system: unit names or a single mass_mult_factor (N-kg-m-s when absent).", [
    E("force_unit", FORCE_UNITS, "force unit"), E("mass_unit", MASS_UNITS, "mass unit"),
    E("length_unit", LENGTH_UNITS, "length unit"), E("time_unit", TIME_UNITS, "time unit"),
    R("mass_mult_factor", "factor keeping F = m*a true in the deck's units (1.0 when absent)", lo=0, lo_open=True)])
el("UNITS", "model", True, "Older unit element (same meaning as Param_Unit).", [
    E("force", FORCE_UNITS, "force unit"), E("mass", MASS_UNITS, "mass unit"),
    E("length", LENGTH_UNITS, "length unit"), E("time", TIME_UNITS, "time unit")])
el("Force_Gravity", "both", True, "Uniform gravitational acceleration (L/T^2), may depend on TIME.",
   xyz("grav_", "", "gravitational acceleration", kind="real_or_expr", default=0.0))

# --------------------------------------------------------------------------- frames and bodies
el("Reference_Marker", "both", True,
   "Orthonormal frame fixed to a body; position/orientation global unless rm_id is given.", [
       ID(), LABEL(), A("body_id", "int", "owning body", required=True, ref="body", lo=1),
       E("body_type", "RIGIDBODY FLEXBODY POINTBODY", "kind of owning body (derived when absent)"),
       M("rm_id", "marker the position/orientation are relative to (0/absent: global)", zero_ok=True),
       A("node_id", "int", "flexible-body node (flexible bodies only)"),
       xyz("pos_", "", "origin coordinate", default=0.0, lo=-COORD_MAX, hi=COORD_MAX),
       [R(f"a{r}{c}", f"direction cosine, row {r} column {c} (columns = unit x, y, z axes)")
        for c in range(3) for r in range(3)],
       R("psi", "body-fixed 3-1-3 Euler angle 1 (rad)"), R("theta", "3-1-3 Euler angle 2 (rad)"),
       R("phi", "3-1-3 Euler angle 3 (rad)"), R("yaw", "yaw angle (rad)"),
       R("pitch", "pitch angle (rad)"), R("roll", "roll angle (rad)"),
       [R(f"e{k}", f"Euler parameter e{k} (e0 scalar part)") for k in range(4)],
       A("usrsub_dll_name", "str", "MARKER_READ library (not supported)"),
       A("usrsub_fnc_name", "str", "MARKER_READ function (not supported)"),
       A("usrsub_param_string", "str", "MARKER_READ parameters (not supported)")])
_VIC = [*xyz("v_ic_", "", "initial CG velocity (ignored in statics)", default=0.0),
        *xyz("v_ic_", "_flag", "velocity IC specified flag (ignored)", kind="bool", default=False)]
el("Body_Rigid", "both", True,
   "Rigid body; inertia about im_id axes, products = +integral(xy dm), tensor carries -Ixy.", [
       ID(), LABEL(), B("isground", "TRUE for the (single) ground body"),
       M("cg_id", "centre-of-mass marker (required for moving bodies)", lo=1),
       M("im_id", "inertia marker (defaults to cg_id)", lo=1), M("lprf_id", "local part reference frame", lo=1),
       R("mass", "mass (>= 0; a moving body without mass only warns)", lo=0),
       R("inertia_xx", "moment of inertia about im x", lo=0), R("inertia_yy", "moment of inertia about im y", lo=0),
       R("inertia_zz", "moment of inertia about im z", lo=0), R("inertia_xy", "product of inertia integral(xy dm)"),
       R("inertia_yz", "product of inertia integral(yz dm)"), R("inertia_xz", "product of inertia integral(xz dm)"),
       _VIC, xyz("w_ic_", "", "initial angular velocity (ignored in statics)", default=0.0),
       xyz("w_ic_", "_flag", "angular velocity IC specified flag (ignored)", kind="bool", default=False),
       M("vm_id", "marker giving velocity IC directions (ignored)"),
       M("wm_id", "marker giving angular velocity IC directions (ignored)"),
       B("is_wet_body", "AcuSolve co-simulation flag (ignored)"),
       A("cp_inp_id", "int", "AcuSolve co-simulation input (ignored)")])
el("Body_Point", "both", True, "Point mass: three translations, orientation stays global.", [
    ID(), LABEL(), M("cg_id", "centre-of-mass marker", required=True, lo=1),
    M("lprf_id", "local part reference frame", lo=1), R("mass", "mass (>= 0)", lo=0), _VIC])
el("Body_Flexible", "model", False, "Modal flexible body (flex-H3D).", [ID(), LABEL()], open_attrs=True)

# --------------------------------------------------------------------------- constraints
_IJ = [M("i_marker_id", "I marker (first body)", required=True, lo=1),
       M("j_marker_id", "J marker (second body)", required=True, lo=1)]
el("Constraint_Joint", "both", True,
   "Ideal joint between the bodies of its I and J markers (primitive names accepted as types).", [
       ID(), LABEL(), E("type", JOINT_TYPES, "joint type", required=True), *_IJ,
       R("pitch", "SCREW: translation of I along z_J per full turn of I about z_J "
         "(d.z_J = pitch*AZ(I,J)/(2 pi); > 0 right-handed; pair it with a CYLINDRICAL joint)"),
       R("pitch_diameter", "RACK_PINION: pinion pitch diameter PD (I on the pinion, J on the rack): "
         "the rack travels PD/2 along z_J per radian the pinion turns about z_I, measured from "
         "the input configuration; < 0 reverses the direction; non-zero"),
       B("is_virtual", "virtual joint flag (treated as a normal joint)")])
el("Constraint_Jprim", "both", True, "Joint primitive.", [
    ID(), LABEL(), E("type", JPRIM_TYPES, "primitive type", required=True), *_IJ,
    B("is_virtual", "virtual joint flag")])
el("Constraint_Coupler", "model", True, "Coupler between 2 or 3 joints (poise.elements.couplers).", [
    ID(), LABEL(), A("joint1_id", "int", "first joint", ref="joint"), E("freedom_1", "T R", "freedom of joint 1"),
    A("joint2_id", "int", "second joint", ref="joint"), E("freedom_2", "T R", "freedom of joint 2"),
    A("joint3_id", "int", "third joint", ref="joint"), E("freedom_3", "T R", "freedom of joint 3"),
    A("coefficients", "real_list", "scale factors c1, c2[, c3]"), B("is_virtual", "virtual flag"), *USR()])
el("Constraint_Gear", "model", True, "Gear between two joints (poise.elements.gears).", [
    ID(), LABEL(), A("joint1_id", "int", "first joint", ref="joint"), A("joint2_id", "int", "second joint", ref="joint"),
    M("cv_marker_id", "contact-point marker (origin) and common-velocity direction (z), on the carrier", required=True, lo=1),
    B("is_virtual", "virtual flag"), *USR()])
el("Constraint_General", "both", True,
   "Expression held at zero (Adams GCON; poise.elements.general); exact first and second "
   "derivatives; i_marker_id: reaction marker (group gcons).", [
       ID(), LABEL(), E("type", "EXPRESSION USERSUB", "how it is given (USERSUB: GCOSUB, not "
                        "supported)", default="EXPRESSION"),
       A("expr", "expr", "the constraint: expr = 0"),
       M("i_marker_id", "reaction marker: the row's load on its body is reported (group gcons)",
         lo=1), B("is_virtual", "virtual flag (treated as a normal constraint)"), *USR()])
el("Constraint_UserConstr", "both", True, "User-defined constraint (UCOSUB).", [ID(), LABEL(), *USR()],
   open_attrs=True, aliases=("Constraint_Usrconstr",))
# higher pairs (poise.elements.compile_curves; docs/elements.md "Curves and surfaces")
_CV = A("curve_id", "int", "Reference_ParamCurve id", ref="curve", lo=1)
_SF = A("surface_id", "int", "Reference_ParamSurface id", ref="surface", lo=1)
el("Constraint_PTCV", "model", True, "Point (I origin) on a curve fixed in J (3 rows, u unknown).", [
    ID(), LABEL(), *_IJ, _CV,
    *xyz("disp_", "0", "initial contact-point guess, global coordinates"), R("vel_0", "initial sliding speed (ignored)")])
el("Constraint_CVCV", "model", True, "Curve in I touches curve in J with a common tangent (5 rows).", [
    ID(), LABEL(), *_IJ, A("i_curve_id", "int", "curve fixed in I", ref="curve", lo=1),
    A("j_curve_id", "int", "curve fixed in J", ref="curve", lo=1),
    *xyz("i_disp_", "0", "initial contact guess on curve I, I-marker coordinates"),
    *xyz("j_disp_", "0", "initial contact guess on curve J, J-marker coordinates"),
    R("i_vel0", "ignored"), R("j_vel0", "ignored"), B("is_no_slip", "no-slip (not supported: ignored with a warning)")])
el("Constraint_PTSF", "model", True, "Point (I origin) on a surface fixed in J (3 rows, u, v unknown).", [
    ID(), LABEL(), *_IJ, _SF, *xyz("disp_", "0", "initial contact-point guess, J-marker coordinates")])
el("Constraint_CVSF", "model", True, "Curve in I on a surface in J, tangent in the tangent plane (5 rows).", [
    ID(), LABEL(), *_IJ, _CV, _SF,
    *xyz("i_disp_", "0", "initial contact guess on the curve, I-marker coordinates"),
    *xyz("j_disp_", "0", "initial contact guess on the surface, J-marker coordinates")])
el("Constraint_SFSF", "model", True, "Surface in I touches surface in J, common normal (5 rows).", [
    ID(), LABEL(), *_IJ, A("i_surface_id", "int", "surface fixed in I", ref="surface", lo=1),
    A("j_surface_id", "int", "surface fixed in J", ref="surface", lo=1),
    *xyz("i_disp_", "0", "initial contact guess on surface I, I-marker coordinates"),
    *xyz("j_disp_", "0", "initial contact guess on surface J, J-marker coordinates")])
el("Constraint_PTdSF", "model", False, "Higher-pair constraint PTdSF.", [ID(), LABEL()], open_attrs=True)

# --------------------------------------------------------------------------- motions
_MOT = [E("val_type", DMS, "expression is a displacement, velocity or acceleration", default="D"),
        R("ic_disp", "initial displacement (V and A)"), R("ic_vel", "initial velocity (A)"),
        E("type", "EXPRESSION USERSUB", "how the motion is given", default="EXPRESSION"),
        A("expr", "expr", "motion expression, usually of TIME"), *USR()]
el("Motion_Joint", "both", True, "Motion on a joint's free coordinate.", [
    ID(), LABEL(), A("joint_id", "int", "driven joint", required=True, ref="joint", lo=1),
    E("joint_type", "R T", "driven freedom (model element)"), E("motion_type", "R T", "driven freedom (command)"),
    *_MOT])
el("Motion_Marker", "both", True, "Motion between two markers along one direction.", [
    ID(), LABEL(), *_IJ, E("direction", "X Y Z B1 B2 B3", "driven direction (J axes)", required=True), *_MOT])

# --------------------------------------------------------------------------- forces
el("Force_SpringDamper", "both", True, "Linear translational or rotational spring-damper.", [
    ID(), LABEL(), E("type", "TRANSLATIONAL ROTATIONAL", "translational force or torque about J z", required=True),
    *_IJ, R("stiffness", "stiffness (force/length or torque/rad)", required=True, lo=0),
    R("damping", "damping (vanishes in statics)", default=0.0, lo=0),
    R("length", "free length, or reference angle (rad) for ROTATIONAL (alias 'angle')",
      required=True, aliases=("angle",)),
    R("preload", "force/torque at the free length", default=0.0)])
el("Force_Bushing", "both", True, "Linear 6-component bushing, components in J axes.", [
    ID(), LABEL(), *_IJ,
    [R(f"k{c}", f"stiffness ({c})", default=0.0, lo=0) for c in ("x", "y", "z", "tx", "ty", "tz")],
    [R(f"c{c}", f"damping ({c})", default=0.0, lo=0) for c in ("x", "y", "z", "tx", "ty", "tz")],
    SIX("preload_{}", "preload", default=0.0)])
_VEXP = [Attr(f"{c}_expression", "real_or_expr", f"{c} component", default=0.0)
         for c in ("fx", "fy", "fz", "tx", "ty", "tz")]
el("Force_Vector_OneBody", "both", True, "Action-only vector force/torque, components in ref_marker axes.", [
    ID(), LABEL(), M("marker_id", "point of application", required=True, lo=1),
    M("ref_marker_id", "component axes (0/absent: global)", zero_ok=True),
    E("type", VEC_TYPES, "force, torque or both", required=True), *_VEXP, *USR()])
el("Force_Vector_TwoBody", "both", True, "Vector force/torque with reaction on a floating marker.", [
    ID(), LABEL(), M("i_marker_id", "point of application", required=True, lo=1),
    M("j_floating_marker_id", "floating marker on the reaction body", required=True, lo=1),
    M("ref_marker_id", "component axes (0/absent: global)", zero_ok=True),
    E("type", VEC_TYPES, "force, torque or both", required=True), *_VEXP, *USR()])
el("Force_Scalar_TwoBody", "both", True, "Scalar force along J->I or torque about J z.", [
    ID(), LABEL(), *_IJ, E("type", "FORCE TORQUE", "force or torque", required=True),
    B("is_action_only", "TRUE: no reaction (one-body scalar force)"),
    R("val", "constant magnitude"), A("val_expression", "real_or_expr", "magnitude expression"), *USR()])
# Force_Field / Force_Beam: poise.elements.field_beam (docs/elements.md "Fields and beams")
el("Force_Field", "model", True, "Linear 6x6 field: [F;T]_J = -K (X - length) + preload, X = [DX..AZ](I,J) in J.", [
    ID(), LABEL(), *_IJ, [R(f"k{i}{j}", f"stiffness K{i}{j} (row {i}, column {j})", default=0.0)
                          for i in range(1, 7) for j in range(1, 7)],
    [R(f"c{i}{j}", f"damping C{i}{j} (vanishes in statics)", default=0.0) for i in range(1, 7) for j in range(1, 7)],
    R("cratio", "damping ratio (vanishes in statics)", default=0.0),
    SIX("length_{}", "reference displacement/angle", default=0.0), SIX("preload_{}", "preload at the reference", default=0.0),
    *USR()])
el("Force_Beam", "both", True, "Straight uniform massless Timoshenko beam J->I along J's x axis (linear 6x6 law in J axes).", [
    ID(), LABEL(), *_IJ, R("length", "free length (J origin to I origin)", lo=0, lo_open=True),
    R("e", "Young's modulus", lo=0, lo_open=True), R("g", "shear modulus", lo=0, lo_open=True),
    R("area", "cross-section area", lo=0, lo_open=True), R("ixx", "torsional constant", lo=0),
    R("iyy", "area moment about J y", lo=0), R("izz", "area moment about J z", lo=0),
    R("asy", "shear-area correction factor for y shear", default=0.0, lo=0),
    R("asz", "shear-area correction factor for z shear", default=0.0, lo=0),
    R("cratio", "damping ratio (vanishes in statics)", default=0.0),
    SIX("preload_{}", "preload (J axes)", default=0.0)])
_UNS_FORCES = {"Force_Contact": "contact between Post_Graphic geometries", "Force_MultiPoint": "multi-point force",
               "Force_Tire": "tyre model", "Force_StateEqn": "state-equation force", "Force_JointFriction": "joint friction"}
for _t, _d in _UNS_FORCES.items():
    el(_t, "both" if _t == "Force_Contact" else "model", _t == "Force_Contact",
       _d.capitalize() + ".",
       [ID(), LABEL()], open_attrs=True)

# --------------------------------------------------------------------------- reference data, control
el("Reference_Array", "both", True, "Array of values given as element text.", [
    ID(), LABEL(), E("type", "IC RESTART PRINT X Y U", "array type"),
    A("num_element", "int", "number of values", lo=0), *USR()])
el("Reference_Matrix", "model", True,
   "nrow x ncol matrix as element text: full (column order; row order with isroworder) or sparse "
   "(issparse: nval row col value triples, 1-based); poise.deck.matrix. Read by "
   "Reference_ParamCurve matrix_id.", [
       ID(), LABEL(), A("nrow", "int", "number of rows", required=True, lo=1),
       A("ncol", "int", "number of columns", required=True, lo=1),
       B("isroworder", "full form: values row by row (default: column by column)"),
       B("issparse", "sparse form: the text holds nval row col value triples"),
       A("nval", "int", "sparse form: number of triples", lo=0), *USR()])
el("Reference_Variable", "both", True, "Algebraic variable usable through VARVAL(id).", [
    ID(), LABEL(), E("type", "EXPRESSION USERSUB", "how it is given", default="EXPRESSION"),
    A("expr", "expr", "defining expression"), *USR(), B("is_implicit", "implicit (adds an equation)"),
    E("autobalance", "DEFAULT CONDITIONAL DISABLED PENALTY", "static autobalance mode"),
    R("penalty", "penalty"), R("penalty1", "penalty1"), A("dot_form", "str", "derivative form"),
    R("ic", "initial value"), B("static_hold", "hold value fixed in statics")])
el("Reference_Spline", "model", True, "Curve y(x) (or surface y(x,z)) given as element text.", [
    ID(), LABEL(), A("num_xy_pair", "int", "number of (x, y) pairs", lo=0),
    A("num_x", "int", "number of x values (surface form)", lo=0),
    A("num_z", "int", "number of z values (surface form)", lo=0),
    B("linear_extrap", "extrapolate linearly outside the data"), A("file_name", "str", "data file"), *USR()])
_PC = [B("is_u_closed", "closed in u (periodic spline; analytic: u wraps into [u_start, u_end))"),
       A("u_start", "real", "first u (analytic; spline data: default 0)"),
       A("u_end", "real", "last u (analytic; spline data: default 1)"),
       B("is_curve_points", "the points (text or matrix) are points the spline passes through; "
         "FALSE (B-spline control points) is refused"),
       A("num_pts", "int", "number of x y z points in the element text (spline form)", lo=2),
       A("matrix_id", "int", "Reference_Matrix with the points, one row per point, columns x y z "
         "(curves; Adams CURVE/MATRIX=)", ref="matrix", lo=1), *USR()]
el("Reference_ParamCurve", "model", True,
   "Curve c(u) in a marker frame: spline through x y z points (text) or x/y/z_expression of U.", [
       ID(), LABEL(), *_PC, *[A(f"{c}_expression", "expr", f"{c}(U), analytic form (poise)") for c in "xyz"]],
   open_attrs=True)
el("Reference_ParamSurface", "model", True,
   "Surface s(u, v) in a marker frame: x/y/z_expression of U and V, or a grid of points (text).", [
       ID(), LABEL(), *_PC, B("is_v_closed", "closed in v"), A("v_start", "real", "first v"),
       A("v_end", "real", "last v"), A("num_u", "int", "grid points along u (spline form)", lo=2),
       A("num_v", "int", "grid points along v (spline form)", lo=2),
       *[A(f"{c}_expression", "expr", f"{c}(U, V), analytic form (poise)") for c in "xyz"]],
   open_attrs=True)
for _t in ("Reference_DeformCurve", "Reference_DeformSurface"):
    el(_t, "model", False, _t.split("_")[1] + ".", [ID(), LABEL()], open_attrs=True)
el("Control_Diff", "both", True, "First-order differential equation state DIF(id).", [
    ID(), LABEL(), B("is_implicit", "FALSE: y' = expr; TRUE: 0 = expr"), R("ic", "initial value"),
    R("ic_dot", "initial derivative"), B("is_static_hold", "hold the state fixed in statics"),
    E("type", "EXPRESSION USERSUB", "how it is given", default="EXPRESSION"),
    A("expr", "expr", "defining expression"), *USR()])
for _t in ("Control_StateEqn", "Control_SISO"):
    el(_t, "model", False, "Control element.", [ID(), LABEL()], open_attrs=True)

# --------------------------------------------------------------------------- no effect on statics
#: elements modelling tools write that do not affect statics: accepted, one warning per kind
#: (poise.deck.validate); tag -> (kind, what it is)
NO_EFFECT = {
    "Control_PlantInput": ("model", "controls plant inputs (linearisation and co-simulation; "
                           "PINVAL reads them)"),
    "Control_PlantOutput": ("model", "controls plant outputs (linearisation and co-simulation; "
                            "POUVAL reads them)"),
    "Post_UserAPI": ("model", "a user results-output routine (POST_SUB)"),
    "Reference_String": ("model", "string data for user subroutines"),
    "Param_Linear": ("both", "linear-analysis settings (poise runs no linear analysis)"),
}
_PLANT = [ID(), LABEL(), A("variable_id_list", "int_list", "Reference_Variable ids (plant I/O)")]
for _t, (_k, _d) in NO_EFFECT.items():
    el(_t, _k, True, _d[0].upper() + _d[1:] + "; no effect on statics: accepted with a warning.",
       _PLANT if _t.startswith("Control_Plant") else [ID(), LABEL()] if _t == "Reference_String"
       else [], open_attrs=True)

# --------------------------------------------------------------------------- output
el("Post_Graphic", "model", True, "Graphic/geometry; all attributes kept as data (used by contact).",
   [ID(), LABEL(), A("type", "str", "geometry type"), A("body_id", "int", "owning body", ref="body")],
   open_attrs=True)
el("Post_Request", "model", True, "Output request (its label: `label`, else `comment`).", [
    ID(), LABEL(), A("comment", "str", "comment (the request's label when it has no label)"),
    A("type", "str", "request type: MARKER_DISPLACEMENT MARKER_VELOCITY MARKER_ACCELERATION "
      "MARKER_FORCE ELEMENTAL_FORCE EXPRESSION (computed); USERSUB and any other type are "
      "accepted with a warning and not computed"),
    M("i_marker_id", "I marker", lo=1), M("j_marker_id", "J marker", zero_ok=True),
    M("ref_marker_id", "result axes", zero_ok=True), A("elem_type", "str", "element type (ELEMENTAL_FORCE)"),
    A("elem_id", "int", "element id (ELEMENTAL_FORCE)"), A("jflag", "int", "0: on I, 1: on J", lo=0, hi=1),
    [A(f"expr{k}", "expr", f"channel {k} expression (NULL: empty)") for k in range(1, 9)], *USR()])

# --------------------------------------------------------------------------- parameters and commands
el("Param_Static", "both", True, "Static / quasi-static solver settings.", [
    E("method", "MKEAM FIM_S FIM_D", "equilibrium method", default="FIM_D"),
    R("max_ke_tol", "MKEAM: residual kinetic energy at equilibrium", default=1e-5, lo=TOL_MIN),
    R("max_dq_tol", "MKEAM: largest relative state change", default=1e-3, lo=TOL_MIN),
    A("max_num_iter", "int", "iteration cap (failure when reached)", default=100, lo=1),
    R("max_imbalance", "FIM: largest force imbalance", default=1e-4, lo=TOL_MIN),
    R("max_error", "FIM: bound on residual change (alias max_residual)", default=1e-4, lo=TOL_MIN,
      aliases=("max_residual",)),
    R("stability", "FIM: sqrt(stability) x mass matrix added to the Jacobian", default=1e-10, lo=0),
    R("compliance_delta", "FIM: perturbation for the compliance matrix", default=1e-3, lo=0, lo_open=True),
    A("compliance_markers", "str", "poise: markers of the compliance matrix (ids, all, auto, none; default none)"),
    E("compliance_method", "EXACT FD", "poise: compliance from the analytic tangent or by re-solving")])
el("Param_Transient", "both", True, "DAE integrator settings (FIM_D quasi-static stepping).", [
    E("integrator_type", "DSTIFF CSTIFF VSTIFF MSTIFF ABAM GSTIFF HSTIFF", "integrator", default="DSTIFF"),
    R("integr_tol", "local error tolerance", default=1e-3, lo=0, lo_open=True),
    R("h_max", "largest step", lo=0, lo_open=True), R("h_min", "smallest step", default=1e-6, lo=0, lo_open=True),
    R("h0_max", "largest initial step (no default: FIM_D sizes its first step from the path)", lo=0, lo_open=True),
    R("vel_tol_factor", "velocity tolerance factor", lo=0), A("max_order", "int", "largest BDF order", lo=1, hi=6),
    R("dae_alg_tol_factor", "algebraic tolerance factor", lo=0), A("dae_index", "int", "DAE formulation index", lo=0),
    R("dae_constr_tol", "constraint tolerance of the DAE corrector", lo=0, lo_open=True),
    A("dae_corrector_maxit", "int", "largest corrector iteration count", lo=1),
    A("dae_corrector_minit", "int", "smallest corrector iteration count", lo=0),
    B("dae_vel_ctrl", "velocity-constraint error control", default=None),
    A("dae_jacob_eval", "int", "Jacobian evaluation pattern"), A("dae_eval_expiry", "int", "Jacobian expiry"),
    A("dae_jacob_init", "str", "initial Jacobian mode (JACINIT)"),
    B("dae_interpolation", "interpolate outputs", default=None),
    R("rel_abs_tol_ratio", "ODE relative/absolute tolerance ratio", lo=0)])
el("Param_Simulation", "both", True, "General simulation settings.", [
    R("constr_tol", "constraint tolerance (assembly, kinematics)", lo=0, lo_open=True),
    R("implicit_diff_tol", "implicit Control_Diff tolerance", default=1e-5, lo=0, lo_open=True),
    R("nr_converge_ratio", "ODE repartitioning ratio", lo=0), A("linsolver", "str", "linear solver name"),
    B("acusolve_cosim", "AcuSolve co-simulation (ignored)"), *USR()])
el("Simulate", "command", True, "Run one analysis (Static with end_time/duration > start = quasi-static).", [
    E("analysis_type", ANALYSIS_TYPES, "analysis", required=True),
    R("start_time", "start / first output time (default 0)"), R("end_time", "end time (>= start_time)"),
    R("duration", "alternative to end_time", lo=0),
    A("num_steps", "int", "number of output steps (alias num_step)", lo=1, aliases=("num_step",)),
    R("print_interval", "output interval (default 0.01)", lo=0, lo_open=True),
    A("print_increment", "int", "output every n-th step", lo=1),
    A("print_array_id", "int", "PRINT Reference_Array of output times", ref="array", lo=1),
    A("restart_array_id", "int", "RESTART Reference_Array", ref="array", lo=1),
    R("start_freq", "frequency response only"), R("end_freq", "frequency response only"),
    A("freq_input_id_list", "int_list", "frequency response only"), A("incr_type", "str", "frequency response only")])
el("Stop", "command", True, "End of the run.", [])
el("ResOutput", "both", True, "Output file options (accepted, no effect).", [
    B("mrf_file", "write .mrf", default=None), B("abf_file", "write .abf", default=None),
    B("plt_file", "write .plt", default=None), E("abf_unique_time", "FIRST LAST ALL", "duplicate-time policy"),
    E("plt_unique_time", "FIRST LAST ALL", "duplicate-time policy"),
    E("angle_type", "EULER_ANGLES YPR", "angle output"), B("flex_vel_acc_output", "", default=None),
    B("contact_gra_output", "", default=None), B("cof_file", "", default=None),
    B("capture_max_pd", "", default=None), B("req_comment_only", "", default=None),
    R("dzero", "zero threshold"), R("vzero", "zero threshold"), R("azero", "zero threshold"),
    R("fzero", "zero threshold")])
el("DebugOutput", "both", True, "Debug output options (accepted, no effect).", [
    B("switch_on", "trace convergence", default=None), B("debug_anim", "animate iterations", default=None),
    B("screen_output", "echo to screen", default=None)])
el("H3DOutput", "both", True, "H3D output options (accepted, no effect).", [B("switch_on", "", default=None)],
   open_attrs=True)
for _t in ("Activate", "Deactivate", "Save", "Load_Model", "Load_Command"):
    el(_t, "command", False, f"{_t} command.", [], open_attrs=True)

# --------------------------------------------------------------------------- lookup
SCHEMAS: dict[str, ElementSchema] = {s.tag: s for s in _ENTRIES}
_BY_LOWER: dict[str, ElementSchema] = {}
for _s in _ENTRIES:
    for _n in (_s.tag, *_s.aliases):
        _BY_LOWER[_n.lower()] = _s
SECTION_TAGS = ("model", "command")


def element_schema(tag: str) -> ElementSchema | None:
    """Schema of an element by (case-insensitive) tag or alias; None when unknown."""
    return _BY_LOWER.get(tag.lower())


def namespace_of(tag: str) -> str | None:
    """Reference namespace whose ids an element type defines (``"marker"`` for markers)."""
    for ns, tags in NAMESPACES.items():
        if tag in tags:
            return ns
    return None


def render_markdown() -> str:
    """Render the whole table as markdown (for ``docs/deck-reference.md``)."""
    out = ["# Deck element reference", "", "Generated from `poise.deck.schema`. "
           "Names are case-insensitive; enum values are case-insensitive and stored upper case.", "",
           "Products of inertia are entered as the integrals ∫xy dm; the inertia tensor is "
           "[[xx, −xy, −xz], [−xy, yy, −yz], [−xz, −yz, zz]] and must be positive definite.", ""]
    for s in _ENTRIES:
        status = "supported" if s.supported else "**not supported yet**"
        out += [f"## `{s.tag}`", "", f"{s.doc}  ", f"Kind: {s.kind}; {status}."
                + (f" Also spelled `{'`, `'.join(s.aliases)}`." if s.aliases else "")
                + (" Unknown attributes are kept as data." if s.open_attrs else ""), ""]
        if not s.attrs:
            continue
        out += ["| attribute | kind | required | default | constraints | meaning |", "|---|---|---|---|---|---|"]
        for a in s.attrs.values():
            cons = []
            if a.choices:
                cons.append(" \\| ".join(a.choices))
            if a.bounds_text():
                cons.append(a.bounds_text())
            if a.ref:
                cons.append(f"id of {' / '.join(NAMESPACES[a.ref])}" + (" (0 = global)" if a.zero_ok else ""))
            if a.aliases:
                cons.append("alias " + ", ".join(f"`{x}`" for x in a.aliases))
            dflt = "" if a.default is None else (str(a.default).upper() if isinstance(a.default, bool)
                                                 else f"{a.default}")
            out.append(f"| `{a.name}` | {a.kind} | {'yes' if a.required else ''} | {dflt} | "
                       f"{'; '.join(cons)} | {a.doc} |")
        out.append("")
    return "\n".join(out)
