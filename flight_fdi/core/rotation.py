"""Quaternions (the 3-D simulator and the ins3d error model).

Convention: Hamilton quaternions q = (w, x, y, z), scalar first, unit norm. A quaternion q_b^n
*rotates body vectors into the navigation frame*: v^n = C(q) v^b, and composition is
q_a^c = q_b^c (x) q_a^b. Frames: navigation ENU (x East, y North, z Up), body x forward,
y left, z up (REP 103). ROS messages store (x, y, z, w); the bag writer reorders.

Euler angles follow REP 103 / ``tf2`` (q = q_z(yaw) (x) q_y(pitch) (x) q_x(roll)): yaw 0 faces
East and grows counter-clockwise (towards North), so yaw = pi/2 - heading; with z up and y
left, a positive *pitch* is nose **down** and a positive roll is right wing down.

The scalar kernels take and return tuples of floats (no allocation inside the numba loops);
``*_array`` helpers are their vectorised numpy forms for whole series.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def qmul(a0, a1, a2, a3, b0, b1, b2, b3):
    """Hamilton product a (x) b."""
    return (a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
            a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
            a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
            a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0)


@njit(cache=True)
def qexp(x, y, z):
    """The unit quaternion of the rotation vector (x, y, z) (rad)."""
    a = math.sqrt(x * x + y * y + z * z)
    if a < 1e-6:  # series: sin(a/2)/a = 1/2 - a^2/48 + a^4/3840
        a2 = a * a
        s = 0.5 - a2 / 48.0 + a2 * a2 / 3840.0
        c = 1.0 - a2 / 8.0 + a2 * a2 / 384.0
    else:
        s = math.sin(0.5 * a) / a
        c = math.cos(0.5 * a)
    return c, s * x, s * y, s * z


@njit(cache=True)
def qlog(w, x, y, z):
    """The rotation vector (rad) of a unit quaternion (shortest rotation)."""
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    n = math.sqrt(x * x + y * y + z * z)
    if n < 1e-6:  # a / sin(a/2) * ... = 2 / w * (1 + n^2 / (6 w^2) ...) via atan2 series
        k = 2.0 / w * (1.0 - n * n / (3.0 * w * w))
    else:
        k = 2.0 * math.atan2(n, w) / n
    return k * x, k * y, k * z


@njit(cache=True)
def qrot(w, x, y, z, vx, vy, vz):
    """C(q) v: the body vector v expressed in the navigation frame."""
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return (vx + w * tx + y * tz - z * ty,
            vy + w * ty + z * tx - x * tz,
            vz + w * tz + x * ty - y * tx)


@njit(cache=True)
def qdcm(w, x, y, z, out):
    """Fill the 3x3 ``out`` with C(q) (body to navigation)."""
    out[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    out[0, 1] = 2.0 * (x * y - w * z)
    out[0, 2] = 2.0 * (x * z + w * y)
    out[1, 0] = 2.0 * (x * y + w * z)
    out[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    out[1, 2] = 2.0 * (y * z - w * x)
    out[2, 0] = 2.0 * (x * z - w * y)
    out[2, 1] = 2.0 * (y * z + w * x)
    out[2, 2] = 1.0 - 2.0 * (x * x + y * y)


def quat_from_euler_array(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """(N, 4) q = q_z(yaw) (x) q_y(pitch) (x) q_x(roll) (REP 103 angles, rad)."""
    cy, sy = np.cos(0.5 * yaw), np.sin(0.5 * yaw)
    cp, sp = np.cos(0.5 * pitch), np.sin(0.5 * pitch)
    cr, sr = np.cos(0.5 * roll), np.sin(0.5 * roll)
    return np.stack([cy * cp * cr + sy * sp * sr,
                     cy * cp * sr - sy * sp * cr,
                     cy * sp * cr + sy * cp * sr,
                     sy * cp * cr - cy * sp * sr], axis=-1)


def euler_from_quat_array(q: np.ndarray) -> np.ndarray:
    """(N, 3) yaw, pitch, roll (REP 103, rad) of (N, 4) quaternions."""
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    return np.stack([yaw, pitch, roll], axis=-1)


def dcm_array(q: np.ndarray) -> np.ndarray:
    """(N, 3, 3) C(q) of (N, 4) quaternions."""
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def qexp_array(v: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions of (N, 3) rotation vectors."""
    v = np.asarray(v, dtype=float)
    a = np.linalg.norm(v, axis=-1)
    half = 0.5 * a
    safe = np.where(a < 1e-6, 1.0, a)
    s = np.where(a < 1e-6, 0.5 - a * a / 48.0, np.sin(half) / safe)
    return np.concatenate([np.cos(half)[..., None], s[..., None] * v], axis=-1)


def qmul_array(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products of (N, 4) (or broadcastable) quaternion arrays."""
    a0, a1, a2, a3 = np.moveaxis(np.asarray(a, dtype=float), -1, 0)
    b0, b1, b2, b3 = np.moveaxis(np.asarray(b, dtype=float), -1, 0)
    return np.stack([a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
                     a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
                     a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
                     a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0], axis=-1)


def attitude_error_array(q_est: np.ndarray, q_true: np.ndarray) -> np.ndarray:
    """(N, 3) phi (rad, ENU) with C_est = exp(-[phi x]) C_true, i.e. q_est = exp(-phi) (x) q_true.

    For small angles C_est = (I - [phi x]) C_true: the SPEC section 8 definition.
    """
    conj = np.asarray(q_true, dtype=float) * np.array([1.0, -1.0, -1.0, -1.0])
    d = qmul_array(q_est, conj)  # exp(-phi)
    d = np.where(d[..., :1] < 0, -d, d)
    n = np.linalg.norm(d[..., 1:], axis=-1)
    k = np.where(n < 1e-12, 2.0, 2.0 * np.arctan2(n, d[..., 0]) / np.where(n < 1e-12, 1.0, n))
    return -k[..., None] * d[..., 1:]
