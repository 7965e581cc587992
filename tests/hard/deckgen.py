"""Small XML deck writer for the hard-case suite (one element per line, so deck lines are known).

Lengths are given in millimetres and converted with ``units``: ``"mm"`` (N-kg-mm-s) or ``"m"``
(N-kg-m-s); forces stay in newtons, so translational stiffness scales by 1/s, rotational by s,
inertia by s**2 and gravity by s.
"""
from __future__ import annotations

import numpy as np

I3 = np.eye(3)


def rot_z(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_x(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _dcm(R):
    R = np.asarray(R, float)
    return " ".join(f'a{i}{j}="{float(R[i, j])!r}"' for i in range(3) for j in range(3))


class Deck:
    def __init__(self, units="mm", grav=(0.0, -9810.0, 0.0), static=None, method="FIM_S"):
        self.s = 1.0 if units == "mm" else 1e-3
        unit = "MILLIMETER" if units == "mm" else "METER"
        st = dict(max_num_iter=100, max_imbalance=1e-8, max_error=1e-8)
        st.update(static or {})
        sattr = " ".join(f'{k}="{v}"' for k, v in st.items())
        self.lines = ["<MotionSolve>", "<Model>",
                      f'<Param_Unit force_unit="NEWTON" mass_unit="KILOGRAM" length_unit="{unit}" '
                      'time_unit="SECOND"/>']
        if grav is not None:
            g = [float(x) * self.s for x in grav]
            self.lines.append(f'<Force_Gravity grav_x="{g[0]!r}" grav_y="{g[1]!r}" grav_z="{g[2]!r}"/>')
        self.lines.append(f'<Param_Static method="{method}" {sattr}/>')
        self.commands = ['<Simulate analysis_type="Static"/>', "<Stop/>"]

    # -- helpers ----------------------------------------------------------------------------
    def L(self, x):
        return float(x) * self.s

    def add(self, line: str) -> int:
        self.lines.append(line)
        return len(self.lines)            # 1-based line number in the written deck

    def ground(self, id=1, cg=100):
        self.marker(cg, id)
        return self.add(f'<Body_Rigid id="{id}" isground="TRUE" cg_id="{cg}"/>')

    def marker(self, id, body, pos=(0, 0, 0), R=I3):
        p = [self.L(x) for x in pos]
        return self.add(f'<Reference_Marker id="{id}" body_id="{body}" pos_x="{p[0]!r}" '
                        f'pos_y="{p[1]!r}" pos_z="{p[2]!r}" {_dcm(R)}/>')

    def body(self, id, cg, pos, R=I3, mass=1.0, inertia=(1.0, 1.0, 1.0)):
        """Rigid body; ``inertia`` in kg mm^2 (converted)."""
        self.marker(cg, id, pos, R)
        s2 = self.s ** 2
        ii = [float(x) * s2 for x in inertia]
        return self.add(f'<Body_Rigid id="{id}" cg_id="{cg}" mass="{mass!r}" inertia_xx="{ii[0]!r}" '
                        f'inertia_yy="{ii[1]!r}" inertia_zz="{ii[2]!r}" inertia_xy="0" '
                        'inertia_yz="0" inertia_xz="0"/>')

    def point(self, id, cg, pos, mass=1.0):
        self.marker(cg, id, pos)
        return self.add(f'<Body_Point id="{id}" cg_id="{cg}" mass="{mass!r}"/>')

    def joint(self, id, type, i, j):
        return self.add(f'<Constraint_Joint id="{id}" type="{type}" i_marker_id="{i}" j_marker_id="{j}"/>')

    def jprim(self, id, type, i, j):
        return self.add(f'<Constraint_Jprim id="{id}" type="{type}" i_marker_id="{i}" j_marker_id="{j}"/>')

    def spring(self, id, i, j, k, length, rotational=False, preload=0.0):
        """Translational: k in N/mm, length in mm. Rotational: k in N mm/rad, length in rad."""
        if rotational:
            kk, ll, pl = float(k) * self.s, float(length), float(preload) * self.s
            typ = "ROTATIONAL"
        else:
            kk, ll, pl = float(k) / self.s, self.L(length), float(preload)
            typ = "TRANSLATIONAL"
        return self.add(f'<Force_SpringDamper id="{id}" type="{typ}" i_marker_id="{i}" '
                        f'j_marker_id="{j}" stiffness="{kk!r}" damping="0" length="{ll!r}" '
                        f'preload="{pl!r}"/>')

    def bushing(self, id, i, j, k, kt):
        k = [float(x) / self.s for x in k]
        kt = [float(x) * self.s for x in kt]
        return self.add(f'<Force_Bushing id="{id}" i_marker_id="{i}" j_marker_id="{j}" '
                        f'kx="{k[0]!r}" ky="{k[1]!r}" kz="{k[2]!r}" ktx="{kt[0]!r}" '
                        f'kty="{kt[1]!r}" ktz="{kt[2]!r}"/>')

    def force(self, id, marker, f, ref=0):
        return self.add(f'<Force_Vector_OneBody id="{id}" type="FORCEONLY" marker_id="{marker}" '
                        f'ref_marker_id="{ref}" fx_expression="{f[0]!r}" fy_expression="{f[1]!r}" '
                        f'fz_expression="{f[2]!r}"/>')

    def text(self) -> str:
        return "\n".join(self.lines + ["</Model>", "<Command>"] + self.commands
                         + ["</Command>", "</MotionSolve>", ""])

    def write(self, path) -> str:
        path.write_text(self.text())
        return str(path)


def stiff_soft_deck(m=1e-3, k1=1e9, k2=1.0, kb=1e9):
    """Masses ``m`` [kg] on springs ``k1`` and ``k2`` [N/m] in series below ground, and a rigid
    body on a ``kb`` N/m bushing, in N-kg-m-s; the springs start at their free lengths."""
    # max_error 1e-9: with max_imbalance 1e-8 N a 1 N/m spring pins its body only to ~1e-8 m
    # (Newton's remaining step ~6e-10 x L); 1e-12 could not be proved and is now reported so
    d = Deck(units="m", static=dict(max_imbalance=1e-8, max_error=1e-9))
    d.ground()
    d.marker(101, 1, (0, 0, 0))
    d.marker(102, 1, (300, 0, 0))
    d.point(2, 20, (0, -10, 0), mass=m)
    d.point(3, 30, (0, -510, 0), mass=m)
    d.spring(1, 20, 101, k1 * 1e-3, 10.0)          # Deck takes N/mm
    d.spring(2, 30, 20, k2 * 1e-3, 500.0)
    d.body(4, 40, (300, 0, 0), mass=m, inertia=(1e-2, 1e-2, 1e-2))
    d.bushing(1, 40, 102, (kb * 1e-3,) * 3, (1e12,) * 3)
    return d
