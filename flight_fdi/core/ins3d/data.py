"""Input arrays of the 3-D INS error model: the navigation solution per propagation step and the
reference measurements (the four contract topics of docs/sim3d.md, already decoded).

``NavSteps`` holds, for each propagation step k (t_k -> t_k+1, the /ins/imu message grid), the
mid-interval navigation values the time-varying F is built from:

- ``C`` (K, 3, 3): C_b^n (body x fwd / y left / z up -> ENU), the mean of the INS attitude at the
  two ends of the step (the quaternion mean, normalised);
- ``f_n`` (K, 3): the measured specific force of the step (the /ins/imu mean over the interval,
  body) rotated into ENU by ``C``;
- ``w_b`` (K, 3): the measured body rate of the step (only for reports: turn detection);
- ``v`` (K, 3) ENU m/s, ``lat`` (K,) rad, ``h`` (K,) m: INS values at mid-step;
- ``dt`` (K,) the actual step lengths, ``t`` (K + 1,) the step boundaries (s).

``RefRows`` holds the reference measurements: stamps ``t`` (M,), the innovation input
z = v_INS(t) - v_ref(t) (M, 3) ENU and its variance ``r`` (M, 3) per row; ``step`` (M,) is the
index of the step boundary the update is applied at (the first boundary at or after the stamp);
``a`` (M, 3) the INS acceleration over the Earth at the stamps (the latency state's H column).
With a height reference (``with_height``, ``Ins3dModel.height_row``) the third row is
z = h_INS(t) - h_ref(t) (m), its variance m^2 and its ``a`` the INS vertical velocity.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..rotation import dcm_array
from ..errors import CoreError


@dataclass
class NavSteps:
    """The navigation solution per propagation step (see the module docstring)."""

    t: np.ndarray
    dt: np.ndarray
    C: np.ndarray
    f_n: np.ndarray
    w_b: np.ndarray
    v: np.ndarray
    lat: np.ndarray
    h: np.ndarray

    def __len__(self) -> int:
        return int(self.dt.size)


def nav_steps(t: np.ndarray, q: np.ndarray, f_b: np.ndarray, w_b: np.ndarray, v: np.ndarray,
              lat: np.ndarray, h: np.ndarray) -> NavSteps:
    """Steps from INS states at the boundaries t (K+1,): q (K+1, 4) (w, x, y, z), v (K+1, 3),
    lat/h (K+1,); f_b, w_b (K, 3) the mean measured specific force and rate of each step."""
    t = np.asarray(t, dtype=float)
    n = t.size
    q = np.asarray(q, dtype=float)
    if n < 2 or q.shape != (n, 4) or np.shape(v) != (n, 3) or np.shape(lat) != (n,) \
            or np.shape(h) != (n,) or np.shape(f_b) != (n - 1, 3) or np.shape(w_b) != (n - 1, 3):
        raise CoreError("nav_steps: need K+1 >= 2 states (t, q, v, lat, h) and K (f_b, w_b)")
    dt = np.diff(t)
    if not np.all(np.isfinite(dt)) or np.any(dt <= 0):
        raise CoreError("nav_steps: the step times must increase strictly")
    q1 = q[1:] * np.where(np.sum(q[1:] * q[:-1], axis=1) < 0, -1.0, 1.0)[:, None]
    qm = q[:-1] + q1
    qm /= np.linalg.norm(qm, axis=1)[:, None]
    C = dcm_array(qm)
    f_n = np.einsum("kij,kj->ki", C, np.asarray(f_b, dtype=float))
    mid = lambda y: 0.5 * (np.asarray(y, dtype=float)[:-1] + np.asarray(y, dtype=float)[1:])
    return NavSteps(t, dt, np.ascontiguousarray(C), f_n, np.asarray(w_b, dtype=float), mid(v),
                    mid(lat), mid(h))


@dataclass
class RefRows:
    """Reference velocity measurements as innovation inputs (see the module docstring)."""

    t: np.ndarray
    z: np.ndarray
    r: np.ndarray
    step: np.ndarray
    a: np.ndarray | None = None     # (M, 3) INS acceleration dv/dt (ENU) at the stamps

    def __post_init__(self) -> None:
        if self.a is None:
            self.a = np.zeros_like(self.z)


def ref_rows(steps: NavSteps, t_ins: np.ndarray, v_ins: np.ndarray, t_ref: np.ndarray,
             v_ref: np.ndarray, r_ref: np.ndarray) -> RefRows:
    """z = v_INS(t_ref) - v_ref (INS velocity linearly interpolated at the reference stamps);
    references outside the step grid are dropped."""
    t_ref = np.asarray(t_ref, dtype=float)
    keep = (t_ref >= steps.t[0]) & (t_ref <= steps.t[-1])
    t_ref = t_ref[keep]
    v_ref = np.asarray(v_ref, dtype=float)[keep]
    r_ref = np.broadcast_to(np.asarray(r_ref, dtype=float), (keep.size, 3))[keep]
    if np.any(r_ref <= 0) or not np.all(np.isfinite(r_ref)):
        raise CoreError("ref_rows: the reference variances must be finite and > 0")
    v_ins = np.asarray(v_ins, dtype=float)
    v_i = np.stack([np.interp(t_ref, t_ins, v_ins[:, i]) for i in range(3)], axis=1)
    acc = np.gradient(v_ins, t_ins, axis=0)
    a_i = np.stack([np.interp(t_ref, t_ins, acc[:, i]) for i in range(3)], axis=1)
    step = np.searchsorted(steps.t, t_ref - 1e-9 * np.maximum(1.0, np.abs(t_ref)), side="left")
    return RefRows(t_ref, v_i - v_ref, np.ascontiguousarray(r_ref), step.astype(np.int64), a_i)

def with_height(refs: RefRows, t_ins: np.ndarray, h_ins: np.ndarray, v_up: np.ndarray,
                h_ref: np.ndarray, r_h: float | np.ndarray,
                t_v: np.ndarray | None = None) -> RefRows:
    """``refs`` with the third row a height reference at the same stamps: z = h_INS(t) -
    ``h_ref`` (M,) m, its variance ``r_h`` (m^2), and as its latency column the INS vertical
    velocity ``v_up`` (a reference late by tau reports h(t - tau) ~ h(t) - v_U tau); INS values
    linearly interpolated at the stamps (``v_up`` sampled at ``t_v``, default ``t_ins``)."""
    h_ref = np.asarray(h_ref, dtype=float)
    r_h = np.broadcast_to(np.asarray(r_h, dtype=float), h_ref.shape)
    if h_ref.shape != refs.t.shape:
        raise CoreError(f"with_height: {h_ref.size} heights for {refs.t.size} reference stamps")
    if not (np.all(np.isfinite(h_ref)) and np.all(np.isfinite(r_h)) and np.all(r_h > 0)):
        raise CoreError("with_height: the heights must be finite and their variances > 0")
    z, r, a = refs.z.copy(), refs.r.copy(), refs.a.copy()
    z[:, 2] = np.interp(refs.t, t_ins, h_ins) - h_ref
    r[:, 2] = r_h
    a[:, 2] = np.interp(refs.t, t_ins if t_v is None else t_v, v_up)
    return RefRows(refs.t, z, r, refs.step, a)


def interpolate_height(t: np.ndarray, t_h: np.ndarray, h: np.ndarray, r: np.ndarray,
                       max_gap: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(heights, variances, found) at stamps ``t`` from samples (``t_h`` increasing, h, r):
    linear between the samples at or before and at or after each stamp when they are at most
    ``max_gap`` apart (an exact stamp: that sample); ``found`` False elsewhere. The height
    reference's row at the reference stamps (``bagio.height_input``, ``stream.Ins3dAssembler``:
    one formula for both)."""
    t_h = np.asarray(t_h, dtype=float)
    j = np.searchsorted(t_h, t, side="left")          # first sample at or after t
    exact = (j < t_h.size) & (t_h[np.minimum(j, t_h.size - 1)] == t)
    inside = (j > 0) & (j < t_h.size)
    a, b = np.maximum(j - 1, 0), np.minimum(j, t_h.size - 1)
    found = exact | (inside & (t_h[b] - t_h[a] <= max_gap))
    w = np.where(inside & ~exact, (t - t_h[a]) / np.where(t_h[b] > t_h[a], t_h[b] - t_h[a], 1.0),
                 1.0)
    hz = np.where(exact, h[b], (1.0 - w) * h[a] + w * h[b])
    rz = np.where(exact, r[b], (1.0 - w) * r[a] + w * r[b])
    return hz, rz, found


@njit(cache=True)
def _weighted_means(y, w, b, dt, out):
    """out[i] = sum_{k in [b_i, b_i+1)} y_k w_k / dt_i (y, out: one row per step)."""
    for i in range(b.size - 1):
        for c in range(y.shape[1]):
            acc = 0.0
            for k in range(b[i], b[i + 1]):
                acc += y[k, c] * w[k]
            out[i, c] = acc / dt[i]


def coarsen(steps: NavSteps, refs: RefRows, max_dt: float = 0.1) -> tuple[NavSteps, RefRows]:
    """The same flight on a coarser step grid: consecutive steps are merged into one between the
    boundaries that carry reference updates, and at least every ``max_dt`` seconds (a merged
    step is at most ``max_dt`` plus one original step long). A merged step carries the
    dt-weighted means of C, f_n, w_b, v, lat and h of its steps: F is linear in them (in v to
    first order), so the merged step's F is the mean F of its steps and Phi = expm of the
    integral of F up to the commutators of F over one step (measured in test_backward.py).
    At 100-Hz INS steps and 10-Hz references this is the 10-Hz grid: ten times fewer
    covariance propagations."""
    if not max_dt > 0:
        raise CoreError("coarsen: max_dt must be > 0")
    K = len(steps)
    t = steps.t
    keep = np.zeros(K + 1, dtype=bool)
    keep[[0, K]] = True
    keep[refs.step] = True
    # between two update boundaries further apart than max_dt: one more every max_dt
    last = np.maximum.accumulate(np.where(keep, np.arange(K + 1), 0))
    bins = np.floor((t - t[last]) / max_dt + 1e-9).astype(np.int64)
    keep[1:] |= (bins[1:] != bins[:-1]) & (last[1:] == last[:-1])
    b = np.flatnonzero(keep)                       # kept boundaries, b[0] = 0, b[-1] = K
    dt = np.add.reduceat(steps.dt, b[:-1])

    def mean(y: np.ndarray) -> np.ndarray:
        out = np.empty((b.size - 1,) + y.shape[1:])
        _weighted_means(np.ascontiguousarray(y).reshape(K, -1), steps.dt, b, dt,
                        out.reshape(b.size - 1, -1))
        return out

    coarse = NavSteps(t[b], dt, mean(steps.C), mean(steps.f_n), mean(steps.w_b),
                      mean(steps.v), mean(steps.lat), mean(steps.h))
    step = np.searchsorted(b, refs.step).astype(np.int64)
    return coarse, RefRows(refs.t, refs.z, refs.r, step, refs.a)


__all__ = ["NavSteps", "RefRows", "coarsen", "interpolate_height", "nav_steps", "ref_rows",
           "with_height"]
