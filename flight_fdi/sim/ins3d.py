"""The 3-D flight simulator: trajectory -> ideal IMU -> sensor errors and faults -> alignment ->
forward strapdown mechanization (the INS solution), plus the GNSS reference and the baro.

``simulate3d(Sim3DConfig(...))`` runs one seeded flight (no I/O); ``bag3d.write_bag3d`` stores
it. Steps:

1. ``trajectory.generate``: the true trajectory at the IMU rate (default 100 Hz).
2. ``strapdown.inverse``: the ideal increments (dtheta, dv) that reproduce it exactly.
3. ``imu3d.corrupt``: the grade's errors and the faults, per sensor, in body axes.
4. ``imu3d.alignment_error``: the initial attitude error phi0 consistent with the accelerometer
   error and (gyrocompassing) the east gyro error at t = 0 (``alignment='consistent'``), or none
   (``'perfect'``). Initial position and velocity are the truth.
5. ``strapdown.mechanize`` (second order) with the vertical channel ``baro`` (default: third-order
   loop on the barometric height, time constant ``tau_vertical_s``), ``reference`` (the same loop
   on the GNSS height, held between messages) or ``free`` (undamped).
6. ``gnss.simulate_gnss``: the reference messages; with ``height_reference`` a second,
   independent barometer (``gnss.simulate_baro``), the bag's optional height topic.

Random numbers: ``SeedSequence(seed)`` spawns independent streams for the gyros, the
accelerometers, the alignment, the GNSS, the baro and the height reference, so a faulty and a
nominal flight with one seed differ by the fault's effect only.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import SimError
from .faults import FaultSpec3D
from .gnss import BaroConfig, GnssConfig, GnssOutput, held, simulate_baro, simulate_gnss
from .imu3d import GRADES, ImuGrade, SensorOutput, alignment_error, corrupt, grade
from .rotation import attitude_error_array, qexp_array, qmul_array, qrot
from .strapdown import NavSolution, inverse, mechanize
from .trajectory import Trajectory, TrajectoryConfig, generate

FORMAT = "flight_fdi.sim3d/1"
VERTICAL_MODES = ("baro", "reference", "free")
ALIGNMENTS = ("consistent", "perfect")


@dataclass(frozen=True)
class Sim3DConfig:
    """What to simulate (the trajectory, the IMU, the aiding sensors, the faults)."""

    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    grade: str | ImuGrade = "navigation"
    quantize: bool = False
    gnss: GnssConfig = field(default_factory=GnssConfig)
    baro: BaroConfig = field(default_factory=BaroConfig)
    #: a second barometer, independent of the INS's, whose heights a bag may carry as its
    #: height reference (``bag3d.write_bag3d``'s ``height_topic``; e.g. ``gnss.HEIGHT_REFERENCE``)
    height_reference: BaroConfig | None = None
    vertical: str = "baro"
    tau_vertical_s: float = 100.0
    alignment: str = "consistent"
    faults: tuple[FaultSpec3D, ...] = ()
    seed: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "faults", tuple(self.faults))
        grade(self.grade)
        if self.vertical not in VERTICAL_MODES:
            raise SimError(f"vertical channel must be one of {', '.join(VERTICAL_MODES)}, "
                           f"got {self.vertical!r}")
        if self.alignment not in ALIGNMENTS:
            raise SimError(f"alignment must be one of {', '.join(ALIGNMENTS)}, "
                           f"got {self.alignment!r}")
        if not math.isfinite(self.tau_vertical_s) or not 1.0 <= self.tau_vertical_s <= 1e5:
            raise SimError(f"vertical loop time constant must be within 1..1e5 s, "
                           f"got {self.tau_vertical_s!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) \
                or self.seed < 0:
            raise SimError(f"seed must be an integer >= 0, got {self.seed!r}")
        d, rate = self.trajectory.duration_s, self.trajectory.rate_hz
        for f in self.faults:
            if not isinstance(f, FaultSpec3D):
                raise SimError(f"faults must be FaultSpec3D objects, got {f!r}")
            f.check_against(d, rate, self.gnss.rate_hz)
            if f.type == "latency" and not 0.0 <= self.gnss.latency_s + f.magnitude <= 1.0:
                raise SimError(f"{f.label}: the reference latency must be within 0..1 s "
                               f"({self.gnss.latency_s:g} s + {f.magnitude:g} s)")

    @property
    def imu_grade(self) -> ImuGrade:
        return grade(self.grade)


@dataclass
class Flight3D:
    """Everything one 3-D simulation produced (times in s from the start, IMU rate)."""

    config: Sim3DConfig
    truth: Trajectory
    ideal_dtheta: np.ndarray      # (N-1, 3) ideal increments (rad), body
    ideal_dv: np.ndarray          # (N-1, 3) m/s, body
    gyro: SensorOutput
    accel: SensorOutput
    phi0: np.ndarray              # (3,) initial attitude error, ENU rad
    ins: NavSolution              # the INS solution (N states)
    gnss: GnssOutput
    aid_h: np.ndarray | None      # (N,) height fed to the vertical loop (None: free)
    height_ref: np.ndarray | None = None   # (N,) the height reference's heights (None: none)

    @property
    def t(self) -> np.ndarray:
        return self.truth.t

    @property
    def dt(self) -> float:
        return self.truth.dt

    def velocity_error(self) -> np.ndarray:
        """(N, 3) v_INS - v_true, ENU."""
        return self.ins.v - self.truth.nav.v

    def attitude_error(self) -> np.ndarray:
        """(N, 3) phi (ENU, rad): C_INS = (I - [phi x]) C_true."""
        return attitude_error_array(self.ins.q, self.truth.nav.q)

    def description(self) -> dict[str, Any]:
        """The JSON document of /sim/fault and metadata.yaml: settings, presets, faults."""
        c = self.config
        tc = c.trajectory
        return {
            "format": FORMAT, "model": "ins3d", "seed": int(c.seed),
            "trajectory": {**{k: getattr(tc, k) for k in (
                "profile", "duration_s", "rate_hz", "lat_deg", "lon_deg", "alt_m",
                "heading_deg", "aoa_deg")}, "speed_mps": tc.speed},
            "imu": {**c.imu_grade.to_dict(), "quantize": c.quantize,
                    "gyro_matrix": self.gyro.matrix.tolist(),
                    "accel_matrix": self.accel.matrix.tolist()},
            "gnss": vars(c.gnss).copy(), "baro": vars(c.baro).copy(),
            **({} if c.height_reference is None else
               {"height_reference": vars(c.height_reference).copy()}),
            "vertical": c.vertical, "tau_vertical_s": c.tau_vertical_s,
            "alignment": c.alignment, "phi0_rad": self.phi0.tolist(),
            "faults": [f.to_dict("x") for f in c.faults],
        }


def _initial_attitude(cfg: Sim3DConfig, truth: Trajectory, ideal_dv: np.ndarray,
                      gyro: SensorOutput, accel: SensorOutput, ideal_dth: np.ndarray,
                      rng: np.random.Generator) -> np.ndarray:
    """phi0 from the sensor errors at t = 0 (``imu3d.alignment_error``)."""
    if cfg.alignment == "perfect":
        return np.zeros(3)
    q0 = truth.nav.q[0]
    dt = truth.dt
    b_body = accel.systematic(ideal_dv[:1] / dt)[0]
    e_body = gyro.systematic(ideal_dth[:1] / dt)[0]
    f_n = np.array(qrot(*q0, *(ideal_dv[0] / dt)))
    b_n = np.array(qrot(*q0, *b_body))
    e_n = np.array(qrot(*q0, *e_body))
    return alignment_error(f_n, b_n, e_n, float(truth.nav.lat[0]), cfg.imu_grade.heading_sigma,
                           rng)


def simulate3d(cfg: Sim3DConfig) -> Flight3D:
    """Run one seeded 3-D flight."""
    truth = generate(cfg.trajectory)
    dt = truth.dt
    dth, dv = inverse(truth.nav, dt)
    # (the sixth stream, the height reference's, leaves the first five as they were)
    rng_g, rng_a, rng_al, rng_gnss, rng_baro, rng_href = (
        np.random.default_rng(s) for s in np.random.SeedSequence(cfg.seed).spawn(6))
    t_int = truth.t[:-1]
    d = cfg.trajectory.duration_s
    g = cfg.imu_grade
    gyro = corrupt(dth / dt, t_int, dt, "gyro", g, cfg.faults, rng_g, d, cfg.quantize)
    accel = corrupt(dv / dt, t_int, dt, "accel", g, cfg.faults, rng_a, d, cfg.quantize)
    phi0 = _initial_attitude(cfg, truth, dv, gyro, accel, dth, rng_al)
    nav = truth.nav
    gnss = simulate_gnss(truth.t, nav.lat, nav.lon, nav.h, nav.v, cfg.gnss, cfg.faults,
                         rng_gnss, d)
    aid_h = None
    if cfg.vertical == "baro":
        aid_h = simulate_baro(nav.h, dt, cfg.baro, rng_baro)
    elif cfg.vertical == "reference":
        aid_h = held(gnss.t, gnss.h, truth.t)
    lat0, lon0, h0, v0, q0 = nav.initial()
    q0_ins = qmul_array(qexp_array(-phi0[None, :]), q0[None, :])[0]
    ins = mechanize(gyro.rate * dt, accel.rate * dt, dt, (lat0, lon0, h0, v0, q0_ins),
                    aid_h=aid_h, tau_vertical_s=None if aid_h is None else cfg.tau_vertical_s)
    href = None if cfg.height_reference is None else \
        simulate_baro(nav.h, dt, cfg.height_reference, rng_href)
    return Flight3D(cfg, truth, dth, dv, gyro, accel, phi0, ins, gnss, aid_h, href)


__all__ = ["ALIGNMENTS", "Flight3D", "GRADES", "Sim3DConfig", "VERTICAL_MODES", "simulate3d"]
