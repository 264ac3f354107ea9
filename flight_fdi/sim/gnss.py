"""Aiding sensors of the 3-D simulator: the GNSS reference (velocity and position) and the
barometric altimeter of the vertical channel.

GNSS, at ``rate_hz`` (1-10 Hz; it must divide the IMU rate), message j stamped t_j = j / rate::

    v_ref,j = v_true(t_j - latency_j) + w_j + m_j           (ENU, per axis)
    p_ref,j = p_true(t_j - latency_j) + w'_j + m'_j         (E, N, U metres -> lat, lon, h)

w white, m first-order Markov (correlation time tau, stationary from the start), horizontal and
vertical standard deviations separate. The latency is *unknown to the user*: the stamp is the
time the receiver claims, the value is the truth of ``latency`` seconds earlier (linear
interpolation of the truth at the IMU rate). Reference faults (``FaultSpec3D`` target ``ref``,
axis x/y/z = E/N/U): ``jump`` adds m (m/s) to the velocity over [start, end); ``outliers`` adds
+-m to random messages (freq per second on average); ``dropout`` removes the messages (velocity and
position) over [start, end); ``latency`` adds m seconds of latency over [start, end) (all axes).

The covariance published with each message is the stationary variance white^2 + markov^2.

Baro: h_baro(t_k) = h_true + b0 + b_gm(t_k) + drift t_k + white, at the IMU rate
(``BaroConfig``; the INS's own baro has no drift, the bag's height reference ``HEIGHT_REFERENCE``
one of 1 m/h).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from .earth import radii
from .errors import SimError
from .faults import FaultSpec
from .imu3d import AXES, gauss_markov


@dataclass(frozen=True)
class GnssConfig:
    """GNSS reference model (standard deviations per axis; h = horizontal, v = vertical)."""

    rate_hz: float = 10.0
    vel_white_h: float = 0.02        # m/s
    vel_white_v: float = 0.04
    vel_markov_h: float = 0.02       # m/s
    vel_markov_v: float = 0.03
    vel_tau_s: float = 30.0
    pos_white_h: float = 0.5         # m
    pos_white_v: float = 1.0
    pos_markov_h: float = 1.5        # m
    pos_markov_v: float = 3.0
    pos_tau_s: float = 60.0
    latency_s: float = 0.02

    def __post_init__(self) -> None:
        for name, val in asdict(self).items():
            if not isinstance(val, (int, float)) or not math.isfinite(val) or val < 0:
                raise SimError(f"GNSS {name.replace('_', ' ')} must be a number >= 0, got {val!r}")
        if not 0.1 <= self.rate_hz <= 100.0:
            raise SimError(f"GNSS rate must be within 0.1..100 Hz, got {self.rate_hz!r}")
        if self.latency_s > 1.0:
            raise SimError(f"GNSS latency must be within 0..1 s, got {self.latency_s!r}")
        if min(self.vel_tau_s, self.pos_tau_s) <= 0:
            raise SimError("GNSS correlation times must be > 0 s")

    def sigmas(self, what: str) -> tuple[np.ndarray, np.ndarray]:
        """(white, markov) standard deviations per ENU axis of 'vel' or 'pos'."""
        d = asdict(self)
        white = np.array([d[f"{what}_white_h"]] * 2 + [d[f"{what}_white_v"]])
        markov = np.array([d[f"{what}_markov_h"]] * 2 + [d[f"{what}_markov_v"]])
        return white, markov


@dataclass(frozen=True)
class BaroConfig:
    """Barometric altimeter error (m): turn-on bias, Gauss-Markov, white, and a slow linear
    drift (m/s: the day's pressure changing; 0 for the INS's own baro by default)."""

    bias: float = 5.0
    instability: float = 2.0
    tau_s: float = 600.0
    white: float = 0.5
    drift_mps: float = 0.0

    def __post_init__(self) -> None:
        for name, val in asdict(self).items():
            if not isinstance(val, (int, float)) or isinstance(val, bool) \
                    or not math.isfinite(val) or (val < 0 and name != "drift_mps"):
                raise SimError(f"baro {name.replace('_', ' ')} must be a number"
                               f"{'' if name == 'drift_mps' else ' >= 0'}, got {val!r}")
        if self.tau_s <= 0:
            raise SimError(f"baro tau s must be > 0, got {self.tau_s!r}")


#: the height reference the bag may carry (``Sim3DConfig.height_reference``): a second
#: barometer, independent of the INS's, richer than the analysis' model of it (white + one
#: Markov error): a turn-on offset of 10 m (the datum "first" absorbs it), a Gauss-Markov error
#: of 0.3 m over 20 s, white 0.1 m and a drift of 1 m/h
HEIGHT_REFERENCE = BaroConfig(bias=10.0, instability=0.3, tau_s=20.0, white=0.1,
                              drift_mps=1.0 / 3600.0)


@dataclass
class GnssOutput:
    """The reference messages actually sent (dropouts removed)."""

    t: np.ndarray              # (M,) stamp, s from the start
    v: np.ndarray              # (M, 3) ENU m/s
    lat: np.ndarray            # (M,) rad
    lon: np.ndarray
    h: np.ndarray              # (M,) m
    vel_error_markov: np.ndarray  # (M, 3) the correlated part of the velocity error
    latency: np.ndarray        # (M,) s
    outlier: np.ndarray        # (M, 3) bool
    vel_var: np.ndarray        # (3,) published variance per axis, (m/s)^2
    pos_var: np.ndarray        # (3,) m^2


def _at(t_truth: np.ndarray, y: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Linear interpolation of the columns of y (N, m) at times t (clamped to the flight)."""
    tc = np.clip(t, t_truth[0], t_truth[-1])
    return np.stack([np.interp(tc, t_truth, y[:, i]) for i in range(y.shape[1])], axis=1)


def simulate_gnss(t_truth: np.ndarray, lat: np.ndarray, lon: np.ndarray, h: np.ndarray,
                  v: np.ndarray, cfg: GnssConfig, faults: tuple[FaultSpec, ...],
                  rng: np.random.Generator, duration_s: float) -> GnssOutput:
    """The GNSS messages of one flight (truth sampled at t_truth)."""
    m = int(math.floor(duration_s * cfg.rate_hz + 1e-9)) + 1
    t = np.arange(m) / cfg.rate_hz
    latency = np.full(m, cfg.latency_s)
    for f in faults:
        if f.target == "ref" and f.type == "latency":
            latency[f.active(t, duration_s)] += f.magnitude
    ts = t - latency
    v_ref = _at(t_truth, v, ts)
    pos = _at(t_truth, np.stack([lat, lon, h], axis=1), ts)
    dt = 1.0 / cfg.rate_hz
    vw, vm = cfg.sigmas("vel")
    pw, pm = cfg.sigmas("pos")
    markov_v = gauss_markov(rng, m, 1.0, cfg.vel_tau_s, dt) * vm
    markov_p = gauss_markov(rng, m, 1.0, cfg.pos_tau_s, dt) * pm
    v_ref += markov_v + rng.standard_normal((m, 3)) * vw
    dp = markov_p + rng.standard_normal((m, 3)) * pw   # E, N, U metres
    r_n, r_m = radii(pos[:, 0])
    lat_ref = pos[:, 0] + dp[:, 1] / (r_m + pos[:, 2])
    lon_ref = pos[:, 1] + dp[:, 0] / ((r_n + pos[:, 2]) * np.cos(pos[:, 0]))
    h_ref = pos[:, 2] + dp[:, 2]
    outlier = np.zeros((m, 3), dtype=bool)
    keep = np.ones(m, dtype=bool)
    u_out = rng.random((2, m))
    for f in faults:
        if f.target != "ref" or f.type == "latency":
            continue
        a = AXES.index(f.axis or "x")
        active = f.active(t, duration_s)
        if f.type == "jump":
            v_ref[active, a] += f.magnitude
        elif f.type == "outliers":
            hit = (u_out[0] < f.freq_hz / cfg.rate_hz) & active  # type: ignore[operator]
            v_ref[hit, a] += np.where(u_out[1][hit] < 0.5, -1.0, 1.0) * f.magnitude
            outlier[hit, a] = True
        else:  # dropout
            keep &= ~active
    return GnssOutput(t[keep], v_ref[keep], lat_ref[keep], lon_ref[keep], h_ref[keep],
                      markov_v[keep], latency[keep], outlier[keep], vw**2 + vm**2, pw**2 + pm**2)


def simulate_baro(h_true: np.ndarray, dt: float, cfg: BaroConfig,
                  rng: np.random.Generator) -> np.ndarray:
    """Barometric height at the IMU rate."""
    n = h_true.size
    err = (cfg.bias * rng.standard_normal()
           + gauss_markov(rng, n, cfg.instability, cfg.tau_s, dt, 1)[:, 0]
           + cfg.white * rng.standard_normal(n))
    if cfg.drift_mps:
        err = err + cfg.drift_mps * dt * np.arange(n)
    return h_true + err


def held(t_msg: np.ndarray, y: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The last message value at or before each t (the first one before any message)."""
    if t_msg.size == 0:
        raise SimError("no reference message to hold (the dropouts cover the whole flight)")
    i = np.searchsorted(t_msg, t + 1e-9, side="right") - 1
    return y[np.clip(i, 0, None)]
