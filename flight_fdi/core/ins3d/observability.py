"""Observability report of the ins3d model over one flight: which states the flight excites.

The information Gramian of the initial state (noise-free model, Q = 0), in scaled coordinates
x' = T^-1 x (T = diag(sqrt(P0)), so the prior information is the identity)::

    W(t) = sum_{t_j <= t} Phi(t_j, t_0)' H' R_j^-1 H Phi(t_j, t_0)

accumulated along the time-varying Phi of the flight at the reference updates. Per state the
report gives ``ratio`` = sqrt(diag((I + W)^-1)): the posterior standard deviation of that
initial-state element over its prior one (1: the flight taught nothing about it; 0.1: known to a
tenth of its prior), at the report times, and ``excited_at``: the first report time at which
the ratio fell below ``threshold``. The Gramian's eigen-directions are returned as well (an
unobservable *combination*, e.g. a tilt and a horizontal accelerometer bias on a straight leg,
shows as a small eigenvalue whose vector mixes them).

Manoeuvres (``manoeuvres``): intervals where the heading rate or the horizontal specific force
exceeds a threshold -- where the report says states become observable.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..errors import CoreError
from .data import NavSteps, RefRows
from .filter import scaled_H, white_variance
from .model import Ins3dModel
from .dynamics import fill_F, transition
from .sparse import mul_left


@njit(cache=True, nogil=True)
def _gramian(C, f_n, v, lat, h, dt, kp, s, ref_step, r, acc, il, im, rows, hu, report_step, W_o):
    n = s.size
    F = np.empty((n, n))
    Phi = np.empty((n, n))
    F2 = np.empty((n, n))
    M = np.eye(n)                       # Phi(t_k, t_0), scaled
    M2 = np.empty((n, n))
    W = np.zeros((n, n))
    j = 0
    o = 0
    for k in range(dt.size + 1):
        if k > 0:
            fill_F(F, C[k - 1], f_n[k - 1], v[k - 1], lat[k - 1], h[k - 1], kp)
            transition(F, dt[k - 1], Phi, F2)
            for a in range(n):          # M <- T^-1 Phi T M
                for b in range(n):
                    Phi[a, b] *= s[b] / s[a]
            M2[:, :] = 0.0
            mul_left(Phi, M, M2, False)
            M[:, :] = M2
        while j < ref_step.size and ref_step[j] == k:
            HM = scaled_H(s, acc[j], il, im, rows, hu) @ M
            for i in range(rows):
                w = 1.0 / r[j, i]
                for a in range(n):
                    for b in range(n):
                        W[a, b] += w * HM[i, a] * HM[i, b]
            j += 1
        while o < report_step.size and report_step[o] == k:
            W_o[o] = W
            o += 1


@dataclass
class ObservabilityReport:
    """Per-state information the flight gave about the initial state (module docstring)."""

    names: tuple[str, ...]
    t: np.ndarray              # (T,) report times
    ratio: np.ndarray          # (T, n) posterior / prior standard deviation
    excited_at: dict[str, float | None]
    eigenvalues: np.ndarray    # (n,) of W at the end (scaled: 1 = as much as the prior)
    eigenvectors: np.ndarray   # (n, n) columns
    threshold: float

    def summary(self) -> list[str]:
        """One line per state: final ratio and when it became observable."""
        out = []
        for i, nm in enumerate(self.names):
            at = self.excited_at[nm]
            when = f"from {at:.0f} s" if at is not None else "not excited"
            out.append(f"{nm:6s} sd/prior {self.ratio[-1, i]:.3f}  {when}")
        return out


def observability(model: Ins3dModel, steps: NavSteps, refs: RefRows, every_s: float = 10.0,
                  threshold: float = 0.5, P0: np.ndarray | None = None) -> ObservabilityReport:
    """The information report of one flight at report times every ``every_s`` seconds."""
    if not every_s > 0 or not 0 < threshold < 1:
        raise CoreError("observability: every_s must be > 0 and threshold in (0, 1)")
    n = model.n
    s = np.sqrt(np.diag(P0)) if P0 is not None else np.sqrt(model.p0())
    t_rep = np.arange(steps.t[0], steps.t[-1] + 1e-9, every_s)
    rep = np.searchsorted(steps.t, t_rep - 1e-9)
    W = np.zeros((rep.size, n, n))
    order = np.argsort(refs.step, kind="stable")
    _gramian(steps.C, steps.f_n, steps.v, steps.lat, steps.h, steps.dt,
             model.kernel_params(), s, refs.step[order], white_variance(model, refs.r[order]),
             np.ascontiguousarray(refs.a[order]), *model.row_args(), rep.astype(np.int64), W)
    prior = np.eye(n)
    if P0 is not None:
        Si = np.diag(1.0 / s)
        prior = np.linalg.inv(Si @ P0 @ Si)
    post = np.linalg.inv(prior[None] + W)
    ratio = np.sqrt(np.clip(np.diagonal(post, axis1=1, axis2=2), 0, None)
                    / np.diag(np.linalg.inv(prior))[None])
    excited = {}
    for i, nm in enumerate(model.names):
        hit = np.flatnonzero(ratio[:, i] < threshold)
        excited[nm] = float(t_rep[hit[0]]) if hit.size else None
    lam, vec = np.linalg.eigh(W[-1])
    return ObservabilityReport(model.names, t_rep, ratio, excited, lam, vec, threshold)


#: the sensor-bias states a fault hypothesis names (``bias_line``)
_SENSOR = {"ba": "accelerometer", "bg": "gyro"}


def bias_line(excited_at: dict[str, float | None]) -> str | None:
    """The text result's line on the sensor biases (``ObservabilityReport.excited_at``, as in
    the result's ``ins3d.observability``): from when the flight knew each initial bias to half
    its prior sigma, and which it never did. Not a detectability verdict: a bias step later in
    flight can be seen where the initial bias was not learnt (its prior may already be tight,
    or it is confounded with the initial tilt). The vertical gyro's is learnt only through
    turns. None without the report."""
    if not excited_at:
        return None
    parts = []
    for name, at in excited_at.items():
        kind, _, axis = name.partition("_")
        if kind in _SENSOR:
            when = "never" if at is None else f"from {at:.0f} s"
            parts.append(f"{_SENSOR[kind]} {axis} {when}")
    return "sensor bias known to half its prior sigma: " + ", ".join(parts) if parts else None


def manoeuvres(steps: NavSteps, rate_deg_s: float = 0.5, accel_mps2: float = 0.2,
               gap_s: float = 5.0, min_s: float = 2.0) -> list[tuple[float, float, str]]:
    """Intervals (t0, t1, kind) of turns (heading rate > ``rate_deg_s``) and of speed changes
    (|d v_h / dt| > ``accel_mps2``); gaps shorter than ``gap_s`` are bridged, intervals shorter
    than ``min_s`` dropped."""
    heading = np.unwrap(np.arctan2(steps.v[:, 0], steps.v[:, 1]))
    rate = np.degrees(np.abs(np.diff(heading) / steps.dt[1:]))
    speed = np.hypot(steps.v[:, 0], steps.v[:, 1])
    acc = np.abs(np.diff(speed) / steps.dt[1:])
    out = []
    for kind, on in (("turn", rate > rate_deg_s), ("acceleration", acc > accel_mps2)):
        edges = np.flatnonzero(np.diff(np.concatenate(([0], on.astype(np.int8), [0]))))
        spans: list[list[float]] = []
        for a, b in zip(edges[::2], edges[1::2]):
            t0, t1 = float(steps.t[a + 1]), float(steps.t[b])
            if spans and t0 - spans[-1][1] < gap_s:
                spans[-1][1] = t1
            else:
                spans.append([t0, t1])
        out += [(a, b, kind) for a, b in spans if b - a >= min_s]
    return sorted(out)


__all__ = ["ObservabilityReport", "bias_line", "manoeuvres", "observability"]
