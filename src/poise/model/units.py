"""Unit systems (``Param_Unit`` / ``UNITS``): the factor that keeps F = m a consistent.

All numbers stay in the deck's units. Inertial quantities are multiplied by
``mass_factor = (mass_SI * length_SI / time_SI**2) / force_SI`` — the number of deck force units
in one (deck mass unit x deck length unit / deck time unit^2). For N-kg-mm-s this is 1e-3
(1 kg mm/s^2 = 1e-3 N), so a 2 kg body under g = -9810 mm/s^2 weighs 19.62 N.
``Param_Unit mass_mult_factor`` (when given) is used as this factor directly.
"""
from __future__ import annotations

MASS = {
    "KILOGRAM": 1.0, "GRAM": 1e-3, "MILLIGRAM": 1e-6, "MICROGRAM": 1e-9, "NANOGRAM": 1e-12,
    "MEGAGRAM": 1e3, "TONNE": 1e3, "POUND_MASS": 0.45359237, "SLUG": 14.5939029372,
    "OUNCE_MASS": 0.028349523125, "KPOUND_MASS": 453.59237, "US_TON": 907.18474,
    "US TON": 907.18474, "SLINCH": 175.126835246,
}
LENGTH = {
    "METER": 1.0, "MILLIMETER": 1e-3, "CENTIMETER": 1e-2, "KILOMETER": 1e3, "MICROMETER": 1e-6,
    "NANOMETER": 1e-9, "ANGSTROM": 1e-10, "INCH": 0.0254, "FOOT": 0.3048, "YARD": 0.9144,
    "MILE": 1609.344, "MILLIINCH": 2.54e-5, "MICROINCH": 2.54e-8, "MILS": 2.54e-5,
}
FORCE = {
    "NEWTON": 1.0, "KNEWTON": 1e3, "MEGANEWTON": 1e6, "CENTINEWTON": 1e-2, "MILLINEWTON": 1e-3,
    "MICRONEWTON": 1e-6, "NANONEWTON": 1e-9, "DYNE": 1e-5, "POUND_FORCE": 4.4482216152605,
    "KPOUND_FORCE": 4448.2216152605, "OUNCE_FORCE": 0.27801385095378, "KILOGRAM_FORCE": 9.80665,
    "POUNDAL": 0.138254954376,
}
TIME = {
    "SECOND": 1.0, "MILLISECOND": 1e-3, "MICROSECOND": 1e-6, "NANOSECOND": 1e-9, "MINUTE": 60.0,
    "HOUR": 3600.0, "DAY": 86400.0,
}
DEFAULT = {"force": "NEWTON", "mass": "KILOGRAM", "length": "METER", "time": "SECOND"}
TABLES = {"force": FORCE, "mass": MASS, "length": LENGTH, "time": TIME}


def mass_factor(force="NEWTON", mass="KILOGRAM", length="METER", time="SECOND") -> float:
    """Deck force units per (mass unit x length unit / time unit^2)."""
    f = FORCE[force.upper()]
    m = MASS[mass.upper()]
    L = LENGTH[length.upper()]
    t = TIME[time.upper()]
    return m * L / (t * t) / f
