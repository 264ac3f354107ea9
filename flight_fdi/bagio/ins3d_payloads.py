"""The contract topics written as CDR messages (``sim.bag3d``, ``eval.real3d``): the INS's IMU,
velocity and fix, the reference velocity and a height reference -- the messages
``ins3d_input.read_ins3d`` reads back (docs/sim3d.md, "Topics")."""
from __future__ import annotations

import numpy as np

from .errors import BagError

#: frames of the contract topics (docs/sim3d.md, "Topics")
ENU_FRAME, BODY_FRAME = "enu", "base_link"
#: the variance written on the covariance diagonal of what a message does not measure
UNMEASURED_VARIANCE = 1e6


def imu_payloads(stamps_ns: np.ndarray, q: np.ndarray, w_b: np.ndarray,
                 f_b: np.ndarray) -> list[bytes]:
    """/ins/imu messages (sensor_msgs/Imu, ``BODY_FRAME``): orientation = q_b^n (w, x, y, z
    given), angular_velocity = w_b, linear_acceleration = f_b; covariances 0 (unknown)."""
    from . import cdr

    vals = np.zeros((len(stamps_ns), 37))
    vals[:, 0:3], vals[:, 3] = q[:, 1:4], q[:, 0]
    vals[:, 13:16], vals[:, 25:28] = w_b, f_b
    return cdr.encode_doubles(cdr.IMU, stamps_ns, BODY_FRAME, vals)


def velocity_payloads(stamps_ns: np.ndarray, v: np.ndarray,
                      var: np.ndarray | None = None) -> tuple[str, list[bytes]]:
    """(type, messages) of ENU velocities ``v`` (``ENU_FRAME``): TwistStamped (the INS), or with
    the per-axis variances ``var`` TwistWithCovarianceStamped (the reference; the angular part
    ``UNMEASURED_VARIANCE``)."""
    from . import cdr

    twist = np.zeros((len(stamps_ns), 6))
    twist[:, :3] = v
    if var is None:
        return cdr.TWIST_STAMPED, cdr.encode(cdr.TWIST_STAMPED, stamps_ns, ENU_FRAME, twist)
    cov = np.zeros(36)
    cov[[0, 7, 14]] = var
    cov[[21, 28, 35]] = UNMEASURED_VARIANCE
    return cdr.TWIST_COV_STAMPED, cdr.encode(cdr.TWIST_COV_STAMPED, stamps_ns, ENU_FRAME,
                                             twist, cov)


def ins_fix_payloads(stamps_ns: np.ndarray, lat: np.ndarray, lon: np.ndarray,
                     h: np.ndarray) -> list[bytes]:
    """/ins/fix messages (sensor_msgs/NavSatFix, ``BODY_FRAME``): latitude and longitude (rad
    given, degrees written), height; covariance unknown."""
    from . import cdr

    llh = np.stack([np.degrees(lat), np.degrees(lon), h], axis=1)
    return cdr.encode_navsatfix(stamps_ns, BODY_FRAME, 0, 0, llh, np.zeros(9), 0)


def height_payloads(msgtype: str, stamps_ns: np.ndarray, frame: str, h: np.ndarray,
                    var: np.ndarray | float, lat: np.ndarray | None = None,
                    lon: np.ndarray | None = None) -> list[bytes]:
    """Height reference messages (``bagio.height_input``): ``sensor_msgs/FluidPressure`` (the
    ISA pressure of the heights ``h`` m, its variance ``var`` m^2 converted to Pa^2),
    ``sensor_msgs/NavSatFix`` (altitude ``h``, ``lat``/``lon`` rad (0 when not given), the
    covariance DIAGONAL_KNOWN with ``var`` on Up and ``UNMEASURED_VARIANCE`` horizontally,
    status FIX) or ``geometry_msgs/PointStamped`` (z = h; no variance)."""
    from . import cdr
    from .height_input import dh_dp, isa_pressure

    n = len(stamps_ns)
    h = np.asarray(h, dtype=float)
    var = np.broadcast_to(np.asarray(var, dtype=float), (n,))
    if msgtype == cdr.FLUID_PRESSURE:
        p = isa_pressure(h)
        return cdr.encode_doubles(msgtype, stamps_ns, frame,
                                  np.stack([p, var / dh_dp(p) ** 2], axis=1))
    if msgtype == cdr.NAVSATFIX:
        zero = np.zeros(n)
        llh = np.stack([np.degrees(zero if lat is None else lat),
                        np.degrees(zero if lon is None else lon), h], axis=1)
        cov = np.zeros((n, 9))
        cov[:, [0, 4]] = UNMEASURED_VARIANCE
        cov[:, 8] = var
        return cdr.encode_navsatfix(stamps_ns, frame, 0, 1, llh, cov, 2)
    if msgtype == cdr.POINT_STAMPED:
        return cdr.encode_doubles(msgtype, stamps_ns, frame,
                                  np.stack([np.zeros(n), np.zeros(n), h], axis=1))
    raise BagError(f"height_payloads: no height message of type {msgtype!r}")
