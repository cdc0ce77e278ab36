"""Reference magnitudes at rest: Earth rate and WGS-84 normal gravity (docs/reference.md#rest)."""

from __future__ import annotations

import math

#: Earth rotation rate, rad/s (WGS-84).
OMEGA_IE_RAD_S = 7.2921150e-5
#: Earth rotation rate in deg/h: 15.04107 (the seed rounds to 15.0411).
OMEGA_IE_DEG_H = math.degrees(OMEGA_IE_RAD_S) * 3600.0
#: Standard gravity, m/s^2; the accelerometer model works in g of this size.
G0_M_S2 = 9.80665

# WGS-84 constants for Somigliana's normal gravity formula.
_A = 6378137.0  # semi-major axis, m
_F = 1.0 / 298.257223563  # flattening
_GE = 9.7803253359  # normal gravity at the equator, m/s^2
_K = 0.00193185265241  # Somigliana constant
_E2 = 6.69437999014e-3  # first eccentricity squared
_M = 0.00344978650684  # omega^2 a^2 b / GM


def normal_gravity_m_s2(latitude_deg: float, height_m: float = 0.0) -> float:
    """WGS-84 normal gravity (Somigliana, with the second-order free-air height correction), m/s^2."""
    if not -90.0 <= latitude_deg <= 90.0:
        raise ValueError(f"latitude {latitude_deg} deg is outside [-90, 90]")
    s2 = math.sin(math.radians(latitude_deg)) ** 2
    g_surface = _GE * (1.0 + _K * s2) / math.sqrt(1.0 - _E2 * s2)
    h = height_m
    return g_surface * (1.0 - 2.0 / _A * (1.0 + _F + _M - 2.0 * _F * s2) * h + 3.0 / _A**2 * h * h)


def normal_gravity_g(latitude_deg: float, height_m: float = 0.0) -> float:
    """Local normal gravity in units of g0 = 9.80665 m/s^2 (0.99732 at the equator)."""
    return normal_gravity_m_s2(latitude_deg, height_m) / G0_M_S2


def dot_reference(latitude_deg: float, height_m: float = 0.0) -> float:
    """w . f at rest in (deg/h)*g: Omega_ie * g_local/g0 * sin(latitude), the same at every position."""
    return (
        OMEGA_IE_DEG_H
        * normal_gravity_g(latitude_deg, height_m)
        * math.sin(math.radians(latitude_deg))
    )
