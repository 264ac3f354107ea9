"""IMU error model of the 3-D simulator: grade presets, sensor errors, body-axis faults, and the
initial alignment those errors imply.

For each sensor (gyro, accelerometer) the ideal mean rate over an interval r_k (rad/s or m/s^2,
body axes; ``strapdown.inverse`` / dt) becomes::

    r~_k = (I + S + M) r_k + b0 + b_gm(t_k) + n_k/sqrt(dt)      then the faults, then quantization

- S = diag(scale-factor errors), M = axis misalignment (off-diagonal, not symmetric), both drawn
  once per flight, N(0, sigma^2) per element;
- b0: turn-on bias, N(0, sigma^2) per axis; b_gm: first-order Gauss-Markov bias instability,
  b_gm(t_k+1) = exp(-dt/tau) b_gm(t_k) + w_k, stationary standard deviation sigma, starting in
  its stationary distribution;
- n_k: white noise from the angle / velocity random walk ARW, VRW (units rad/sqrt(s),
  m/s/sqrt(s)): the standard deviation of an increment is ARW sqrt(dt);
- faults (``faults.FaultSpec3D``, target accel or gyro, body axis x/y/z): e(t) of the catalogue
  added to that axis's output (``stuck`` replaces the output by m, ``scale`` adds m times the
  true rate), over the intervals that start in [start, end);
- quantization (optional): the increments r~ dt are quantized with the remainder carried on, as a
  real IMU's pulse counter does (the running sum is exact to one quantum).

``GRADES`` holds the presets (numbers in ``docs/sim3d.md``). Random numbers come from one
``SeedSequence`` per flight, one stream per sensor, so faults never change the noise.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from ..core.earth import OMEGA_IE
from ..core.ins3d.grades import (AXES, DEG_H, DEG_RTH, GRADES, MPS_RTH, UG,  # noqa: F401
                                 ImuGrade)  # the presets live in core; re-exported here
from .errors import SimError
from .faults import FaultSpec


def grade(name: str | ImuGrade) -> ImuGrade:
    if isinstance(name, ImuGrade):
        return name
    if name not in GRADES:
        raise SimError(f"unknown IMU grade {name!r}; choose one of {', '.join(GRADES)}")
    return GRADES[name]


def gauss_markov(rng: np.random.Generator, n: int, sigma: float, tau_s: float,
                 dt: float, m: int = 3) -> np.ndarray:
    """(n, m) first-order Gauss-Markov series at step dt, stationary from the first sample."""
    if sigma == 0.0:
        return np.zeros((n, m))
    beta = math.exp(-dt / tau_s)
    w = rng.standard_normal((n, m)) * (sigma * math.sqrt(1.0 - beta * beta))
    w[0] = sigma * rng.standard_normal(m)
    return lfilter([1.0], [1.0, -beta], w, axis=0)


@dataclass
class SensorOutput:
    """One sensor triad over N-1 intervals."""

    rate: np.ndarray          # (N-1, 3) measured mean rate (rad/s or m/s^2)
    bias: np.ndarray          # (N-1, 3) true b0 + b_gm
    fault: np.ndarray         # (N-1, 3) error added by the faults
    matrix: np.ndarray        # (3, 3) I + S + M

    def systematic(self, ideal: np.ndarray, index: np.ndarray | slice = slice(None)
                   ) -> np.ndarray:
        """The error without white noise and quantization, (S + M) r + b + fault, at the
        intervals ``index`` (``ideal`` = the ideal rates of those intervals)."""
        return _apply(self.matrix - np.eye(3), ideal) + self.bias[index] + self.fault[index]


def _apply(m: np.ndarray, r: np.ndarray) -> np.ndarray:
    """r @ m.T for (N, 3) r, column by column (no BLAS threads on a shared machine)."""
    return r[:, :1] * m[:, 0] + r[:, 1:2] * m[:, 1] + r[:, 2:3] * m[:, 2]


def corrupt(ideal: np.ndarray, t: np.ndarray, dt: float, sensor: str, g: ImuGrade,
            faults: tuple[FaultSpec, ...], rng: np.random.Generator, duration_s: float,
            quantize: bool) -> SensorOutput:
    """Apply the ``sensor`` ('gyro' or 'accel') error model of grade ``g`` to ideal rates."""
    gy = sensor == "gyro"
    b0, sig, tau = ((g.gyro_bias, g.gyro_instability, g.gyro_tau_s) if gy
                    else (g.accel_bias, g.accel_instability, g.accel_tau_s))
    white, sf, mis = (g.arw, g.gyro_scale, g.gyro_misalign) if gy else (g.vrw, g.accel_scale,
                                                                         g.accel_misalign)
    quantum = g.gyro_quantum if gy else g.accel_quantum
    n = ideal.shape[0]
    matrix = np.eye(3) + np.diag(sf * rng.standard_normal(3))
    off = mis * rng.standard_normal((3, 3))
    matrix += off - np.diag(np.diag(off))
    bias = b0 * rng.standard_normal(3) + gauss_markov(rng, n, sig, tau, dt)
    noise = rng.standard_normal((n, 3)) * (white / math.sqrt(dt))
    clean = _apply(matrix, ideal)
    clean += bias
    clean += noise
    out = clean.copy() if any(f.target == sensor for f in faults) else clean
    for f in faults:
        if f.target != sensor:
            continue
        i = AXES.index(f.axis or "x")
        if f.type == "stuck":
            out[f.active(t, duration_s), i] = f.magnitude
        else:
            out[:, i] += f.instrument_error(t, ideal[:, i], duration_s)
    fault = out - clean if out is not clean else np.zeros_like(out)
    if quantize and quantum > 0:
        total = np.round(np.cumsum(out * dt, axis=0) / quantum) * quantum
        out = np.diff(total, axis=0, prepend=0.0) / dt
    return SensorOutput(out, bias, fault, matrix)


def alignment_error(f_n: np.ndarray, b_n: np.ndarray, eps_n: np.ndarray, lat: float,
                    heading_sigma: float, rng: np.random.Generator) -> np.ndarray:
    """phi0 (ENU, rad): the attitude error an alignment leaves, consistent with the sensor errors.

    Levelling makes the measured specific force look as the true one: the horizontal components
    of f^n x phi + b^n vanish (b^n = C b_a, the accelerometer error at the start, in ENU):
    phi_N = (b_E + f_N phi_U) / f_U, phi_E = (f_E phi_U - b_N) / f_U. Gyrocompassing
    (``heading_sigma`` = 0) points the east axis where the gyros see no Earth rate: the east
    component of omega_ie x phi + eps^n vanishes, phi_U = (Omega_U phi_N - eps_E) / Omega_N --
    the classical heading error -eps_E / (Omega cos L). Otherwise (grades whose gyro bias is
    too large to gyrocompass) the heading error is drawn as N(0, heading_sigma^2), as from an
    external (magnetic or GNSS in-motion) heading.
    """
    w_n, w_u = OMEGA_IE * math.cos(lat), OMEGA_IE * math.sin(lat)
    fe, fn, fu = (float(x) for x in f_n)
    phi_u = heading_sigma * float(rng.standard_normal()) if heading_sigma > 0 else 0.0
    phi_n = phi_e = 0.0
    for _ in range(4):  # the two conditions couple weakly: fixed-point iteration
        phi_n = (b_n[0] + fn * phi_u) / fu
        phi_e = (fe * phi_u - b_n[1]) / fu
        if heading_sigma == 0:
            phi_u = (w_u * phi_n - eps_n[0]) / w_n
    return np.array([phi_e, phi_n, phi_u])
