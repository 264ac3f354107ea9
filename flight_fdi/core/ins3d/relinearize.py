"""Relinearisation of the ins3d model about the estimated errors, for an INS whose errors leave
the small-angle regime (docs/ins3d_relinearize.md).

**Why.** The model is linear in the errors. A free MEMS-grade INS is 5-20 deg off within
minutes (a 50 deg/h turn-on gyro bias) and hundreds of m/s off in velocity (Schuler). What the
linear model then leaves out -- about g |phi|^2 / 2 on the vertical channel (9 deg of tilt:
0.12 m/s^2) and the transport rate's |dv|^2 / R (300 m/s: 14 mg) -- GLR explains as an
accelerometer z fault on every nominal flight.

**The model about an estimate.** With (phi_hat, dv_hat) the first pass's smoothed attitude and
velocity errors and R = exp([phi_hat x]), the velocity error's exact rate, linearised about the
estimate instead of about zero, is

    dv' = f_c x phi + C_c ba + (the linear terms) + u,    f_c = R f,  C_c = R C,
    u = f - f_c - f_c x phi_hat + w_en(dv_hat) x dv_hat     (``remainder``)

(f the INS's specific force in ENU; f - exp([phi x]) f is the attitude's exact term, and
w_en(dv) x dv the part of the Coriolis and transport terms quadratic in dv; u vanishes to first
order). The same linear model thus holds for the **total** error state -- not for an error
relative to the estimate: a fault's effect stays in the data, none of it is absorbed by the first
pass's estimate -- with its Jacobians at the estimated true attitude (C_c, f_c: F's f x phi,
C ba and C bg blocks, and every fault signature) plus the known input u. The input is removed
from the data: its response w through the model's own transition (from zero), H w, is subtracted
from every reference innovation. The forward filter, backward sweep, seed method and GLR then run
unchanged on (C_c, f_c, z - H w). A pass is kept only when it raises the no-fault likelihood
(the forward filter's -2 ln L falls); a second pass repeats it about the kept pass's estimate
when that moved phi_hat by more than ``TOLERANCE_RAD``. The nonlinear check of a large gyro
fault (``nonlinear``) removes its candidates exactly from the flight as recorded.

Left out: the attitude equation's second-order terms (the left Jacobian, ~ phi x (C bg) / 2)
and the estimate's own error e (a remainder ~ g |phi_hat| |e|). Beyond ``VALID_RAD`` of
attitude error the analysis names no sensor with confidence (``analysis``: ambiguous, reason
``attitude``); when the nonlinear check named a fault, the attitude error is the forward
filter's on the flight without that fault (removed exactly): what is left if it is the cause.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

from ..earth import A, nav_rates
from ..rotation import qdcm, qexp
from .data import NavSteps, RefRows
from .model import IPHI, IV, Ins3dModel
from .dynamics import fill_F, transition

#: the first pass's largest smoothed attitude error (rad, vector norm) above which the model
#: is relinearised (0.02 rad: g |phi|^2 / 2 = 0.2 mg, a navigation-grade bias level)
RELINEARIZE_RAD = 0.02
#: ... or whose velocity error's second-order term (``velocity_remainder``) exceeds this
#: (m/s^2, 10 ug: a velocity error of ~25 m/s)
RELINEARIZE_MPS2 = 1e-4
#: a further pass when the estimate moved by more than this (rad)
TOLERANCE_RAD = 0.005
MAX_PASSES = 2
#: the largest attitude error (rad) the relinearised model is trusted to name a sensor at
VALID_RAD = 0.25


@njit(cache=True, nogil=True)
def remainder(f_n, fc, phi, dv, lat, h):
    """The rate of the velocity error the model linear about (phi, dv) leaves out (m/s^2, ENU):
    the attitude's f - f_c - f_c x phi (f_c = exp([phi x]) f) and the transport rate's
    w_en(dv) x dv (module docstring)."""
    w_ie, w_en = np.empty(3), np.empty(3)
    nav_rates(lat, h, dv[0], dv[1], w_ie, w_en)      # w_en is linear in the velocity
    return f_n - fc - np.cross(fc, phi) + np.cross(w_en, dv)


@njit(cache=True, nogil=True)
def _relinearize(C, f_n, v, lat, h, dt, phi, dv, bias, Cc, fc, w):
    """Cc, fc (K, ...): C and f_n rotated by exp([phi_k x]); w (K+1, n): the response of the
    model (about Cc, fc) to the remainders from zero."""
    n = w.shape[1]
    F, Phi, F2 = np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    R = np.empty((3, 3))
    x = np.zeros(n)
    for k in range(dt.size):
        w[k] = x
        p = phi[k]
        qdcm(*qexp(p[0], p[1], p[2]), R)
        Cc[k] = R @ C[k]
        fc[k] = R @ f_n[k]
        u = remainder(f_n[k], fc[k], p, dv[k], lat[k], h[k])
        fill_F(F, Cc[k], fc[k], v[k], lat[k], h[k], bias)
        transition(F, dt[k], Phi, F2)
        x = Phi @ x
        for i in range(3):
            x[IV + i] += u[i] * dt[k]
    w[dt.size] = x


def at_steps(refs: RefRows, x_updates: np.ndarray, K: int) -> np.ndarray:
    """(K, m) per step: the values at the last update at or before the step's start (the first
    update's before it)."""
    j = np.searchsorted(refs.step, np.arange(K), side="right") - 1
    return np.ascontiguousarray(x_updates[np.clip(j, 0, None)], dtype=float)


def relinearized(model: Ins3dModel, steps: NavSteps, refs: RefRows,
                 x_updates: np.ndarray) -> tuple[NavSteps, RefRows]:
    """The flight (``steps``, ``refs`` sorted by step) as the model linearised about the
    estimated errors ``x_updates`` (M, n) at the updates (their attitude and velocity errors)
    sees it (module docstring): the measurements less the known input's response w at the
    boundaries (the relinearised filter's state is the total error less w)."""
    K = len(steps)
    x = at_steps(refs, np.asarray(x_updates)[:, :IPHI + 3], K)
    Cc, fc = np.empty_like(steps.C), np.empty_like(steps.f_n)
    w = np.empty((K + 1, model.n))
    _relinearize(steps.C, steps.f_n, steps.v, steps.lat, steps.h, steps.dt,
                 np.ascontiguousarray(x[:, IPHI:IPHI + 3]), np.ascontiguousarray(x[:, IV:IV + 3]),
                 model.kernel_params(), Cc, fc, w)
    out = NavSteps(steps.t, steps.dt, Cc, fc, steps.w_b, steps.v, steps.lat, steps.h)
    z = refs.z - w[refs.step][:, model.row_states]
    return out, RefRows(refs.t, np.ascontiguousarray(z), refs.r, refs.step, refs.a)


def largest_attitude(x_s: np.ndarray) -> float:
    """The largest attitude error (rad, vector norm) of smoothed states (M, n)."""
    return float(np.linalg.norm(x_s[:, IPHI:IPHI + 3], axis=1).max(initial=0.0))


def velocity_remainder(x_s: np.ndarray) -> float:
    """The largest second-order rate term of the velocity error, |dv|^2 / R (m/s^2; R the
    Earth's semi-major axis): what the model, linear in dv (Coriolis, transport rate), leaves
    out."""
    return float((np.sum(x_s[:, IV:IV + 3]**2, axis=1) / A).max(initial=0.0))


@dataclass
class Relinearization:
    """The flight as recorded (``steps``, ``refs`` and its forward pass: what the nonlinear
    check removes a fault from exactly) and, per pass kept (the first: the linear model's),
    the largest smoothed attitude error (rad) and the forward pass' -2 ln L; the last is the
    one the decision used."""

    steps: NavSteps
    refs: RefRows
    forward: object
    attitude_max_rad: list[float] = field(default_factory=list)
    neg2_log_likelihood: list[float] = field(default_factory=list)

    @property
    def passes(self) -> int:
        return len(self.attitude_max_rad) - 1

    def record(self) -> dict:
        return {"passes": self.passes,
                "attitude_error_max_deg": [float(np.degrees(a)) for a in self.attitude_max_rad],
                "neg2_log_likelihood": list(self.neg2_log_likelihood)}


@dataclass(frozen=True)
class Validity:
    """Whether the (relinearised) model may name a sensor with confidence on this flight: the
    smoothed attitude error up to ``VALID_RAD``. The velocity error's second-order term
    (``velocity_remainder``, modelled by the relinearisation) is reported beside it."""

    attitude_max_rad: float
    velocity_remainder: float

    @classmethod
    def of(cls, x_s: np.ndarray) -> "Validity":
        return cls(largest_attitude(x_s), velocity_remainder(x_s))

    @property
    def valid(self) -> bool:
        return self.attitude_max_rad <= VALID_RAD

    def record(self) -> dict:
        return {"valid": self.valid,
                "attitude_error_max_deg": float(np.degrees(self.attitude_max_rad)),
                "attitude_error_limit_deg": float(np.degrees(VALID_RAD)),
                "velocity_remainder_mps2": self.velocity_remainder}


__all__ = ["MAX_PASSES", "RELINEARIZE_MPS2", "RELINEARIZE_RAD", "Relinearization", "TOLERANCE_RAD",
           "VALID_RAD", "Validity", "at_steps", "largest_attitude", "relinearized",
           "remainder"]
