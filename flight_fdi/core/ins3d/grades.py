"""IMU grade presets (1-sigma per axis, SI units) shared by the 3-D simulator (``sim.imu3d``)
and the ins3d error model's bias states (``core.ins3d.model``); numbers in docs/sim3d.md."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

G0 = 9.80665                           # standard gravity, m/s^2 (the "g" of mg and micro-g)
DEG_H = math.pi / 180.0 / 3600.0       # rad/s per deg/h
DEG_RTH = math.pi / 180.0 / 60.0       # rad/sqrt(s) per deg/sqrt(h)
UG = 1e-6 * G0                         # m/s^2 per micro-g
MPS_RTH = 1.0 / 60.0                   # m/s/sqrt(s) per m/s/sqrt(h)
AXES = ("x", "y", "z")


@dataclass(frozen=True)
class ImuGrade:
    """One IMU grade (SI units, 1-sigma values per axis)."""

    name: str
    gyro_bias: float              # turn-on bias, rad/s
    gyro_instability: float       # Gauss-Markov sigma, rad/s
    gyro_tau_s: float
    arw: float                    # rad/sqrt(s)
    gyro_scale: float             # dimensionless
    gyro_misalign: float          # rad
    accel_bias: float             # m/s^2
    accel_instability: float      # m/s^2
    accel_tau_s: float
    vrw: float                    # m/s/sqrt(s)
    accel_scale: float
    accel_misalign: float
    gyro_quantum: float = 0.0     # rad per pulse (0: not quantized)
    accel_quantum: float = 0.0    # m/s per pulse
    heading_sigma: float = 0.0    # rad; 0: heading from gyrocompassing (east gyro bias)

    def to_dict(self) -> dict:
        return asdict(self)


GRADES = {
    "navigation": ImuGrade(
        "navigation", gyro_bias=0.005 * DEG_H, gyro_instability=0.003 * DEG_H, gyro_tau_s=3600.0,
        arw=0.002 * DEG_RTH, gyro_scale=5e-6, gyro_misalign=10e-6,
        accel_bias=30 * UG, accel_instability=10 * UG, accel_tau_s=3600.0,
        vrw=0.01 * MPS_RTH, accel_scale=50e-6, accel_misalign=20e-6,
        gyro_quantum=1e-7, accel_quantum=1e-4),
    "tactical": ImuGrade(
        "tactical", gyro_bias=1.0 * DEG_H, gyro_instability=0.3 * DEG_H, gyro_tau_s=600.0,
        arw=0.05 * DEG_RTH, gyro_scale=150e-6, gyro_misalign=0.3e-3,
        accel_bias=300 * UG, accel_instability=50 * UG, accel_tau_s=600.0,
        vrw=0.05 * MPS_RTH, accel_scale=300e-6, accel_misalign=0.3e-3,
        gyro_quantum=1e-6, accel_quantum=1e-3, heading_sigma=math.radians(0.2)),
    "mems": ImuGrade(
        "mems", gyro_bias=50.0 * DEG_H, gyro_instability=5.0 * DEG_H, gyro_tau_s=300.0,
        arw=0.2 * DEG_RTH, gyro_scale=1000e-6, gyro_misalign=1e-3,
        accel_bias=5000 * UG, accel_instability=200 * UG, accel_tau_s=300.0,
        vrw=0.1 * MPS_RTH, accel_scale=1000e-6, accel_misalign=1e-3,
        gyro_quantum=1e-5, accel_quantum=1e-3, heading_sigma=math.radians(1.0)),
    "perfect": ImuGrade("perfect", 0, 0, 3600.0, 0, 0, 0, 0, 0, 3600.0, 0, 0, 0),
}


__all__ = ["AXES", "DEG_H", "DEG_RTH", "G0", "GRADES", "ImuGrade", "MPS_RTH", "UG"]
