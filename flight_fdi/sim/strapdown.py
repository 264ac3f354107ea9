"""Strapdown mechanization in the local-level ENU frame (forward and inverse), numba-compiled.

State at step k (times t_k = k dt): geodetic latitude L and longitude (rad), ellipsoidal
height h (m), velocity v = (v_E, v_N, v_U) over the Earth in ENU (m/s), attitude q = q_b^n
(``rotation``: body x forward / y left / z up into ENU). Input for the interval (t_k, t_k+1]:
the gyro rotation increment dtheta_k (rad, body, relative to inertial space) and the
accelerometer velocity increment dv_k (m/s, body, specific force integrated over the
interval) -- what a strapdown IMU outputs after its coning/sculling compensation.

``second_order`` (default) -- one step, with y_m = 1.5 y_k - 0.5 y_k-1 the mid-interval value
of L, h and v extrapolated from the last two states (y_m = y_0 on the first step)::

    omega_in = omega_ie(L_m) + omega_en(v_m, L_m, h_m)                   (earth.nav_rates)
    q_k+1 = exp(-omega_in dt) (x) q_k (x) exp(dtheta_k)        navigation-frame rotation, body
    v_k+1 = v_k + (C(q_k) + C(q_k+1)) dv_k / 2 + (g_m - (2 omega_ie + omega_en) x v_m) dt
    h_k+1 = h_k + (v_U,k + v_U,k+1) dt / 2
    L_k+1 = L_k + (v_N,k + v_N,k+1) dt / 2 / (R_M(L_m) + (h_k + h_k+1) / 2)
    lon_k+1 = lon_k + (v_E,k + v_E,k+1) dt / 2 / ((R_N(Lbar) + hbar) cos Lbar),  Lbar, hbar means

with g_m = (0, 0, -g(L_m, h_m)) (``earth.gravity``). Second order in dt: (C_k + C_k+1)/2 dv is
C_k (dv + dtheta x dv / 2), the rotation compensation.

``euler`` -- the explicit first-order scheme of the ``inu`` package (``inu.mech``), used to
compare with it: every derivative from the state at t_k::

    q_k+1 = q_k (x) exp(dtheta_k - C(q_k)^T omega_in(k) dt)
    v_k+1 = v_k + C(q_k) dv_k + (g_k - (2 omega_ie + omega_en)_k x v_k) dt
    (L, lon, h)_k+1 = (L, lon, h)_k + (v_N / (R_M + h), v_E / ((R_N + h) cos L), v_U)_k dt

**Inverse mechanization** (``inverse``): the increments that make the ``second_order`` step
reproduce a given sampled trajectory exactly: dtheta_k = log(q_k^-1 (x) exp(omega_in dt) (x)
q_k+1) and dv_k = ((C_k + C_k+1)/2)^-1 (v_k+1 - v_k - (g_m - ...) dt), with the mid values from
the true states. Forward(inverse(trajectory)) returns the trajectory to rounding error.

**Vertical channel.** Free inertial height is unstable (time constant sqrt(R / 2g) ~ 9.5 min).
With an aiding height h_a (barometric or reference), a third-order loop on e = h_k - h_a,k
(Widnall & Sinha) adds ``-k1 e dt`` to h and ``-(k2 e + k3 sum(e) dt) dt`` to v_U per step, with
gains placing the three poles at -1/tau: k1 = 3/tau, k2 = 3/tau^2 + 2 g/R, k3 = 1/tau^3
(``vertical_gains``). A perfect aiding height leaves a perfect trajectory untouched.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .earth import A, gravity, nav_rates, radii
from .errors import SimError
from .rotation import qexp, qlog, qmul, qrot

SCHEMES = ("second_order", "euler")


@dataclass
class NavSolution:
    """A navigation solution (or a true trajectory) sampled at t_k = k dt."""

    lat: np.ndarray   # (N,) rad
    lon: np.ndarray   # (N,) rad
    h: np.ndarray     # (N,) m, above the WGS-84 ellipsoid
    v: np.ndarray     # (N, 3) m/s, ENU
    q: np.ndarray     # (N, 4) q_b^n (w, x, y, z)

    def __len__(self) -> int:
        return int(self.lat.size)

    def initial(self) -> tuple[float, float, float, np.ndarray, np.ndarray]:
        return (float(self.lat[0]), float(self.lon[0]), float(self.h[0]), self.v[0].copy(),
                self.q[0].copy())


def vertical_gains(tau_s: float, lat: float = 0.7, h: float = 0.0) -> tuple[float, float, float]:
    """(k1, k2, k3) of the third-order height loop with a triple pole at -1/tau_s."""
    if not math.isfinite(tau_s) or tau_s <= 0:
        raise SimError(f"vertical loop time constant must be > 0 s, got {tau_s!r}")
    r_n, r_m = radii(float(lat))
    two_w2 = 2.0 * float(gravity(float(lat), float(h))) / (math.sqrt(r_n * r_m) + h)
    return 3.0 / tau_s, 3.0 / tau_s**2 + two_w2, 1.0 / tau_s**3


@njit(cache=True)
def _mid(y, k):
    return y[k] if k == 0 else 1.5 * y[k] - 0.5 * y[k - 1]


@njit(cache=True)
def _mid_state(lat, h, v, k, wie, wen):
    """Mid-interval (lat, h, v_E, v_N, v_U), extrapolated; fills omega_ie, omega_en there."""
    lat_m = _mid(lat, k)
    h_m = _mid(h, k)
    ve_m = _mid(v[:, 0], k)
    vn_m = _mid(v[:, 1], k)
    vu_m = _mid(v[:, 2], k)
    nav_rates(lat_m, h_m, ve_m, vn_m, wie, wen)
    return lat_m, h_m, ve_m, vn_m, vu_m


@njit(cache=True)
def _position_step(lat, lon, h, vk, v1, dt, lat_m):
    """Trapezoidal position update (the same rule builds the true trajectory)."""
    h1 = h + 0.5 * (vk[2] + v1[2]) * dt
    hbar = 0.5 * (h + h1)
    r_n, r_m = radii(lat_m)
    lat1 = lat + 0.5 * (vk[1] + v1[1]) * dt / (r_m + hbar)
    lbar = 0.5 * (lat + lat1)
    r_n, r_m = radii(lbar)
    lon1 = lon + 0.5 * (vk[0] + v1[0]) * dt / ((r_n + hbar) * math.cos(lbar))
    return lat1, lon1, h1


@njit(cache=True)
def integrate_position(lat0, lon0, h0, v, dt):
    """(lat, lon, h) of a velocity series v (N, 3) with the mechanization's position rule."""
    n = v.shape[0]
    lat = np.empty(n)
    lon = np.empty(n)
    h = np.empty(n)
    lat[0], lon[0], h[0] = lat0, lon0, h0
    for k in range(n - 1):
        lat_m = _mid(lat, k)
        lat[k + 1], lon[k + 1], h[k + 1] = _position_step(lat[k], lon[k], h[k], v[k], v[k + 1],
                                                          dt, lat_m)
    return lat, lon, h


@njit(cache=True)
def _forward_second_order(dth, dv, dt, lat, lon, h, v, q, aid_h, gains):
    """Fill lat/lon/h/v/q[1:] (their row 0 holds the initial state) from the increments."""
    wie = np.empty(3)
    wen = np.empty(3)
    v1 = np.empty(3)
    k1, k2, k3 = gains[0], gains[1], gains[2]
    integ = 0.0
    for k in range(dth.shape[0]):
        lat_m, h_m, ve_m, vn_m, vu_m = _mid_state(lat, h, v, k, wie, wen)
        qn = qexp(-(wie[0] + wen[0]) * dt, -(wie[1] + wen[1]) * dt, -(wie[2] + wen[2]) * dt)
        qb = qexp(dth[k, 0], dth[k, 1], dth[k, 2])
        a = qmul(qn[0], qn[1], qn[2], qn[3], q[k, 0], q[k, 1], q[k, 2], q[k, 3])
        b = qmul(a[0], a[1], a[2], a[3], qb[0], qb[1], qb[2], qb[3])
        nb = math.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2] + b[3] * b[3])
        for i in range(4):
            q[k + 1, i] = b[i] / nb
        d0 = qrot(q[k, 0], q[k, 1], q[k, 2], q[k, 3], dv[k, 0], dv[k, 1], dv[k, 2])
        d1 = qrot(q[k + 1, 0], q[k + 1, 1], q[k + 1, 2], q[k + 1, 3],
                  dv[k, 0], dv[k, 1], dv[k, 2])
        cx = 2.0 * wie[0] + wen[0]
        cy = 2.0 * wie[1] + wen[1]
        cz = 2.0 * wie[2] + wen[2]
        g = gravity(lat_m, h_m)
        v1[0] = v[k, 0] + 0.5 * (d0[0] + d1[0]) - (cy * vu_m - cz * vn_m) * dt
        v1[1] = v[k, 1] + 0.5 * (d0[1] + d1[1]) - (cz * ve_m - cx * vu_m) * dt
        v1[2] = v[k, 2] + 0.5 * (d0[2] + d1[2]) - (cx * vn_m - cy * ve_m + g) * dt
        hcorr = 0.0
        if k1 > 0.0:
            e = h[k] - aid_h[k]
            integ += e * dt
            v1[2] -= (k2 * e + k3 * integ) * dt
            hcorr = -k1 * e * dt
        v[k + 1, :] = v1
        lat[k + 1], lon[k + 1], h[k + 1] = _position_step(lat[k], lon[k], h[k], v[k], v1, dt,
                                                          lat_m)
        h[k + 1] += hcorr


@njit(cache=True)
def _forward_euler(dth, dv, dt, lat, lon, h, v, q):
    """The ``inu.mech`` scheme (no aiding), ENU/FLU form."""
    wie = np.empty(3)
    wen = np.empty(3)
    for k in range(dth.shape[0]):
        nav_rates(lat[k], h[k], v[k, 0], v[k, 1], wie, wen)
        w0, w1, w2, w3 = q[k, 0], q[k, 1], q[k, 2], q[k, 3]
        # C^T omega_in = rotation of omega_in by the conjugate quaternion
        r = qrot(w0, -w1, -w2, -w3, wie[0] + wen[0], wie[1] + wen[1], wie[2] + wen[2])
        qb = qexp(dth[k, 0] - r[0] * dt, dth[k, 1] - r[1] * dt, dth[k, 2] - r[2] * dt)
        b = qmul(w0, w1, w2, w3, qb[0], qb[1], qb[2], qb[3])
        nb = math.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2] + b[3] * b[3])
        for i in range(4):
            q[k + 1, i] = b[i] / nb
        f = qrot(w0, w1, w2, w3, dv[k, 0] / dt, dv[k, 1] / dt, dv[k, 2] / dt)
        cx = 2.0 * wie[0] + wen[0]
        cy = 2.0 * wie[1] + wen[1]
        cz = 2.0 * wie[2] + wen[2]
        ve, vn, vu = v[k, 0], v[k, 1], v[k, 2]
        g = gravity(lat[k], h[k])
        v[k + 1, 0] = ve + (f[0] - (cy * vu - cz * vn)) * dt
        v[k + 1, 1] = vn + (f[1] - (cz * ve - cx * vu)) * dt
        v[k + 1, 2] = vu + (f[2] - (cx * vn - cy * ve) - g) * dt
        r_n, r_m = radii(lat[k])
        lat[k + 1] = lat[k] + vn / (r_m + h[k]) * dt
        lon[k + 1] = lon[k] + ve / ((r_n + h[k]) * math.cos(lat[k])) * dt
        h[k + 1] = h[k] + vu * dt


def mechanize(dtheta: np.ndarray, dvel: np.ndarray, dt: float,
              initial: tuple[float, float, float, np.ndarray, np.ndarray],
              scheme: str = "second_order", aid_h: np.ndarray | None = None,
              tau_vertical_s: float | None = None) -> NavSolution:
    """Run the forward mechanization over N-1 increments; returns N states.

    ``initial`` = (lat, lon, h, v (3,), q (4,)). ``aid_h`` (N,) with ``tau_vertical_s`` closes
    the vertical loop (second_order only); without them the vertical channel is free.
    """
    if scheme not in SCHEMES:
        raise SimError(f"mechanization scheme must be one of {', '.join(SCHEMES)}, got {scheme!r}")
    dth = np.ascontiguousarray(dtheta, dtype=float)
    dvl = np.ascontiguousarray(dvel, dtype=float)
    if dth.ndim != 2 or dth.shape[1] != 3 or dvl.shape != dth.shape:
        raise SimError("mechanize: increments must be two (N-1, 3) arrays of the same shape")
    n = dth.shape[0] + 1
    lat0, lon0, h0, v0, q0 = initial
    lat, lon, h = np.empty(n), np.empty(n), np.empty(n)
    v, q = np.empty((n, 3)), np.empty((n, 4))
    lat[0], lon[0], h[0] = lat0, lon0, h0
    v[0] = v0
    q[0] = np.asarray(q0, dtype=float) / np.linalg.norm(q0)
    if scheme == "euler":
        if aid_h is not None:
            raise SimError("mechanize: the euler scheme has no vertical aiding")
        _forward_euler(dth, dvl, float(dt), lat, lon, h, v, q)
    else:
        if (aid_h is None) != (tau_vertical_s is None):
            raise SimError("mechanize: give both aid_h and tau_vertical_s, or neither")
        gains = np.zeros(3) if aid_h is None else np.array(vertical_gains(tau_vertical_s, lat0,
                                                                          h0))
        aid = np.zeros(n) if aid_h is None else np.ascontiguousarray(aid_h, dtype=float)
        if aid.shape != (n,):
            raise SimError(f"mechanize: aid_h must have {n} samples, got {aid.shape}")
        _forward_second_order(dth, dvl, float(dt), lat, lon, h, v, q, aid, gains)
    return NavSolution(lat, lon, h, v, q)


@njit(cache=True)
def _inverse(lat, h, v, q, dt, dth, dv):
    wie = np.empty(3)
    wen = np.empty(3)
    m = np.empty((3, 3))
    for k in range(dth.shape[0]):
        lat_m, h_m, ve_m, vn_m, vu_m = _mid_state(lat, h, v, k, wie, wen)
        qn = qexp((wie[0] + wen[0]) * dt, (wie[1] + wen[1]) * dt, (wie[2] + wen[2]) * dt)
        a = qmul(q[k, 0], -q[k, 1], -q[k, 2], -q[k, 3], qn[0], qn[1], qn[2], qn[3])
        b = qmul(a[0], a[1], a[2], a[3], q[k + 1, 0], q[k + 1, 1], q[k + 1, 2], q[k + 1, 3])
        dth[k, 0], dth[k, 1], dth[k, 2] = qlog(b[0], b[1], b[2], b[3])
        cx = 2.0 * wie[0] + wen[0]
        cy = 2.0 * wie[1] + wen[1]
        cz = 2.0 * wie[2] + wen[2]
        g = gravity(lat_m, h_m)
        r0 = v[k + 1, 0] - v[k, 0] + (cy * vu_m - cz * vn_m) * dt
        r1 = v[k + 1, 1] - v[k, 1] + (cz * ve_m - cx * vu_m) * dt
        r2 = v[k + 1, 2] - v[k, 2] + (cx * vn_m - cy * ve_m + g) * dt
        # solve (C_k + C_k+1)/2 dv = r (Cramer's rule)
        for j in range(3):
            e0 = 1.0 if j == 0 else 0.0
            e1 = 1.0 if j == 1 else 0.0
            e2 = 1.0 if j == 2 else 0.0
            c0 = qrot(q[k, 0], q[k, 1], q[k, 2], q[k, 3], e0, e1, e2)
            c1 = qrot(q[k + 1, 0], q[k + 1, 1], q[k + 1, 2], q[k + 1, 3], e0, e1, e2)
            for i in range(3):
                m[i, j] = 0.5 * (c0[i] + c1[i])
        det = (m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
               - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
               + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]))
        x0 = (r0 * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
              - m[0, 1] * (r1 * m[2, 2] - m[1, 2] * r2)
              + m[0, 2] * (r1 * m[2, 1] - m[1, 1] * r2)) / det
        x1 = (m[0, 0] * (r1 * m[2, 2] - m[1, 2] * r2)
              - r0 * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
              + m[0, 2] * (m[1, 0] * r2 - r1 * m[2, 0])) / det
        x2 = (m[0, 0] * (m[1, 1] * r2 - r1 * m[2, 1])
              - m[0, 1] * (m[1, 0] * r2 - r1 * m[2, 0])
              + r0 * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0])) / det
        dv[k, 0], dv[k, 1], dv[k, 2] = x0, x1, x2


def inverse(traj: NavSolution, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(dtheta, dv), each (N-1, 3): the ideal IMU increments that reproduce ``traj``."""
    n = len(traj)
    if n < 2:
        raise SimError("inverse mechanization needs at least two states")
    dth, dv = np.empty((n - 1, 3)), np.empty((n - 1, 3))
    _inverse(np.ascontiguousarray(traj.lat), np.ascontiguousarray(traj.h),
             np.ascontiguousarray(traj.v), np.ascontiguousarray(traj.q), float(dt), dth, dv)
    return dth, dv


def warm_up() -> None:
    """Compile (or load from the numba cache) every kernel on a tiny input."""
    n = 4
    v = np.tile([100.0, 50.0, 1.0], (n, 1))
    lat, lon, h = integrate_position(0.7, 0.1, 1000.0, v, 0.01)
    q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    traj = NavSolution(lat, lon, h, v, q)
    dth, dv = inverse(traj, 0.01)
    mechanize(dth, dv, 0.01, traj.initial())
    mechanize(dth, dv, 0.01, traj.initial(), aid_h=h, tau_vertical_s=100.0)
    mechanize(dth, dv, 0.01, traj.initial(), scheme="euler")


__all__ = ["A", "NavSolution", "SCHEMES", "integrate_position", "inverse", "mechanize",
           "vertical_gains", "warm_up"]
