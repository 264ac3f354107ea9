"""WGS-84 Earth model (the 3-D simulator and the ins3d error model): radii of curvature, normal
gravity, Earth rate and transport rate in the local-level ENU navigation frame (REP 103: x East,
y North, z Up).

Constants as IS-GPS-200 / NIMA TR8350.2 (the same values the ``inu`` package uses, so the
comparison test runs both mechanizations on one Earth)::

    a = 6 378 137 m, e^2 = 6.694379990141317e-3, Omega = 7.2921151467e-5 rad/s

Normal gravity (Somigliana on the ellipsoid, second-order free-air correction in height; Groves
eq. 2.134; NIMA TR8350.2 eq. 4-1 and 4-3)::

    g0(L)   = g_e (1 + k sin^2 L) / sqrt(1 - e^2 sin^2 L)
    g(L, h) = g0(L) (1 - 2 h/a (1 + f + m - 2 f sin^2 L) + 3 h^2/a^2)

directed along -Up (its tiny north component at altitude is neglected, as in ``inu``). It is
*gravity* (gravitation plus the centrifugal acceleration of the Earth's rotation), so the
velocity equation has no separate centripetal term.

Rates in the ENU frame, with R_N the transverse (prime vertical) and R_M the meridian radius::

    omega_ie^n = Omega (0, cos L, sin L)
    omega_en^n = (-v_N / (R_M + h),  v_E / (R_N + h),  v_E tan L / (R_N + h))

The functions are numba ``njit`` (cache=True) on scalars, used inside the mechanization loop;
``gravity`` and ``radii`` also accept numpy arrays (they are written with numpy ufuncs).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

A = 6378137.0                    # semi-major axis, m
E2 = 6.694379990141317e-3        # first eccentricity squared
OMEGA_IE = 7.2921151467e-5       # Earth rotation rate, rad/s
GE = 9.7803253359                # normal gravity at the equator, m/s^2
GK = 1.93185265241e-3            # Somigliana constant k
GF = 3.35281066475e-3            # flattening f
GM_RATIO = 3.44978650684e-3      # m = Omega^2 a^2 b / GM


@njit(cache=True)
def radii(lat):
    """(R_N transverse, R_M meridian) radii of curvature, m."""
    s2 = np.sin(lat) ** 2
    k = np.sqrt(1.0 - E2 * s2)
    r_n = A / k
    r_m = r_n * (1.0 - E2) / (k * k)
    return r_n, r_m


@njit(cache=True)
def gravity(lat, h):
    """Magnitude of normal gravity at geodetic latitude ``lat`` (rad) and height ``h`` (m)."""
    s2 = np.sin(lat) ** 2
    g0 = GE * (1.0 + GK * s2) / np.sqrt(1.0 - E2 * s2)
    return g0 * (1.0 + (3.0 / (A * A)) * h * h
                 - (2.0 / A) * (1.0 + GF + GM_RATIO - 2.0 * GF * s2) * h)


@njit(cache=True)
def nav_rates(lat, h, ve, vn, out_ie, out_en):
    """Fill ``out_ie`` = omega_ie^n and ``out_en`` = omega_en^n (ENU, rad/s) in place."""
    r_n, r_m = radii(lat)
    cl = math.cos(lat)
    sl = math.sin(lat)
    out_ie[0] = 0.0
    out_ie[1] = OMEGA_IE * cl
    out_ie[2] = OMEGA_IE * sl
    out_en[0] = -vn / (r_m + h)
    out_en[1] = ve / (r_n + h)
    out_en[2] = ve * (sl / cl) / (r_n + h)


def schuler_period(lat: float, h: float, channel: str = "east") -> float:
    """2 pi sqrt((R + h) / g): the Schuler period (s) of the east (R_N) or north (R_M) channel."""
    r_n, r_m = radii(float(lat))
    r = r_n if channel == "east" else r_m
    return 2.0 * math.pi * math.sqrt((r + h) / float(gravity(float(lat), float(h))))
