"""Message <-> numpy conversion for the nodes (all ROS message construction lives here).

Stamps are float seconds (``sec + nanosec * 1e-9``; a float64 keeps ~0.1 us resolution for
stamps up to ~1e9 s, enough for 10-100 Hz data). Matrices are row-major flat lists in messages.
"""
from __future__ import annotations

import array
import math
from typing import Any, Sequence

import numpy as np

from ..bagio.cdr import message as wire

AXES = ("x", "y", "z")
AXIS_INDEX = {"x": 0, "y": 1, "z": 2}


# --- time --------------------------------------------------------------------------------------

def stamp_to_s(stamp: Any) -> float:
    """builtin_interfaces/Time -> float seconds."""
    return parts_to_s(stamp.sec, stamp.nanosec)


#: seconds a builtin_interfaces/Time can hold (int32 sec, nanosec in [0, 1e9))
STAMP_MIN_S = -(2**31)
STAMP_MAX_S = 2**31 - 1e-9


def stamp_fits(t: float) -> bool:
    """True when ``s_to_stamp(t)`` can represent ``t`` (finite, int32 seconds after rounding
    to the nanosecond). A received stamp may not: nanosec is a uint32 on the wire, so
    sec = 2^31 - 1 with nanosec >= 1e9 reads as a time after the last representable one."""
    if not math.isfinite(t) or abs(t) > 2.0**32:      # (t * 1e9 would overflow to inf)
        return False
    return STAMP_MIN_S * 1_000_000_000 <= int(round(t * 1e9)) < 2**31 * 1_000_000_000


def stamp_parts(t: float) -> tuple[int, int]:
    """float seconds -> (sec, nanosec) of a builtin_interfaces/Time (nanoseconds rounded).
    Negative times (sec < 0, nanosec >= 0) are valid stamps; ValueError when ``t`` does not
    fit (``stamp_fits``)."""
    if not stamp_fits(t):
        raise ValueError(f"cannot convert {t!r} s to a ROS time stamp")
    return divmod(int(round(t * 1e9)), 1_000_000_000)


def header_parts(msg: Any) -> tuple[int, int]:
    """(sec, nanosec) of a stamped message's header."""
    st = msg.header.stamp
    return st.sec, st.nanosec


def parts_to_s(sec: int, nanosec: int) -> float:
    """(sec, nanosec) of a received stamp -> float seconds (as :func:`stamp_to_s`)."""
    return sec + nanosec * 1e-9


def s_to_stamp(t: float):
    """float seconds -> builtin_interfaces/Time (see :func:`stamp_parts`)."""
    from builtin_interfaces.msg import Time

    sec, nanosec = stamp_parts(t)
    return Time(sec=sec, nanosec=nanosec)


def header(stamp, frame_id: str = ""):
    from std_msgs.msg import Header

    return Header(stamp=stamp, frame_id=frame_id)


# --- inputs ------------------------------------------------------------------------------------

def twist_velocity_raw(data: bytes) -> tuple[int, int, tuple[float, float, float]]:
    """Serialized geometry_msgs/TwistStamped -> (sec, nanosec, linear velocity (x, y, z)),
    straight from the CDR bytes (``bagio.cdr.message``; WireError when malformed)."""
    sec, nanosec, x, y, z = wire.decode_twist_stamped(data)
    return sec, nanosec, (x, y, z)


def twist_cov_velocity_raw(data: bytes) -> tuple[int, int, tuple[float, float, float],
                                                  tuple[float, float, float]]:
    """Serialized geometry_msgs/TwistWithCovarianceStamped -> (sec, nanosec, linear velocity,
    variance of each linear axis: the diagonal of the 6x6 covariance, not checked here -- the
    caller decides what a valid variance is), from the bytes."""
    sec, nanosec, x, y, z, c0, c7, c14 = wire.decode_twist_cov_stamped(data)
    return sec, nanosec, (x, y, z), (c0, c7, c14)


#: the velocity message types the filter node reads (either input)
VELOCITY_TYPES = ("geometry_msgs/msg/TwistStamped", "geometry_msgs/msg/TwistWithCovarianceStamped",
                  "nav_msgs/msg/Odometry")
_NAN3 = (float("nan"),) * 3


def velocity_decoder(msgtype: str, odometry_twist_frame: str = "child"):
    """f(data) -> (sec, nanosec, linear velocity (x, y, z), variance per axis; NaN where the
    type has none) for one of VELOCITY_TYPES, from the CDR bytes (``bagio.cdr.message``;
    WireError when malformed). Odometry: see wire.decode_odometry (rotated into header.frame_id
    unless ``odometry_twist_frame`` is "header")."""
    if msgtype == VELOCITY_TYPES[0]:
        def twist(data: bytes):
            sec, nanosec, x, y, z = wire.decode_twist_stamped(data)
            return sec, nanosec, (x, y, z), _NAN3
        return twist
    if msgtype == VELOCITY_TYPES[1]:
        return twist_cov_velocity_raw
    if msgtype == VELOCITY_TYPES[2]:
        rotate = odometry_twist_frame != "header"

        def odometry(data: bytes):
            sec, nanosec, x, y, z, c0, c1, c2 = wire.decode_odometry(data, rotate)
            return sec, nanosec, (x, y, z), (c0, c1, c2)
        return odometry
    raise ValueError(f"unsupported velocity message type {msgtype!r}; one of "
                     f"{', '.join(VELOCITY_TYPES)}")


def message_class(msgtype: str):
    """The rclpy message class of "pkg/msg/Name"."""
    import importlib

    pkg, _, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def twist_stamped(t: float, v: Sequence[float], frame_id: str = ""):
    """(t, [vx, vy, vz]) -> geometry_msgs/TwistStamped (for tests, the player and benchmarks)."""
    from geometry_msgs.msg import TwistStamped

    msg = TwistStamped()
    msg.header = header(s_to_stamp(t), frame_id)
    msg.twist.linear.x, msg.twist.linear.y, msg.twist.linear.z = (float(c) for c in v)
    return msg


def twist_cov_stamped(t: float, v: Sequence[float], var: Sequence[float] | float,
                      frame_id: str = ""):
    """(t, [vx, vy, vz], variance per linear axis) -> geometry_msgs/TwistWithCovarianceStamped."""
    from geometry_msgs.msg import TwistWithCovarianceStamped

    msg = TwistWithCovarianceStamped()
    msg.header = header(s_to_stamp(t), frame_id)
    lin = msg.twist.twist.linear
    lin.x, lin.y, lin.z = (float(c) for c in v)
    var3 = np.broadcast_to(np.asarray(var, dtype=float), (3,))
    cov = np.zeros(36)
    cov[[0, 7, 14]] = var3
    msg.twist.covariance = cov
    return msg


def vector3_values(msg: Any) -> tuple[float, np.ndarray]:
    """geometry_msgs/Vector3Stamped -> (t [s], vector (3,)) (the attitude mode's angle, rate and
    control inputs: one value per axis x, y, z)."""
    v = msg.vector
    return stamp_to_s(msg.header.stamp), np.array([v.x, v.y, v.z], dtype=float)


# --- outputs -----------------------------------------------------------------------------------

def _flat(a: Any) -> array.array:
    """Row-major float64 values as array('d'): the generated message setters take it as is
    (a list is checked element by element)."""
    return array.array("d", np.ascontiguousarray(a, dtype=float).reshape(-1).tobytes())


def _floats(a: Any) -> list[float]:
    """Row-major float values as a list (a list of floats is taken as it is)."""
    if type(a) is list and all(type(v) is float for v in a):
        return a
    return np.asarray(a, dtype=float).reshape(-1).tolist()


def _over(a: float, b: float) -> float:
    """a / b with NumPy's result for b = 0 (inf, or NaN for 0 / 0) instead of an exception."""
    if b == 0.0:
        return math.nan if a == 0.0 or math.isnan(a) else math.copysign(math.inf, a)
    return a / b


def _innovation_fields(channel: str, row_names: Sequence[str], result: Any,
                       row_failed: Sequence[bool] | None,
                       row_excluded: Sequence[bool] | None) -> dict:
    """The fields of flight_fdi_msgs/Innovation after the header (plain Python values)."""
    nu = _floats(result.nu)
    m = len(nu)
    S = _floats(result.S)
    if len(S) != m * m:
        raise ValueError(f"innovation: S has {len(S)} entries for {m} rows")
    failed = [False] * m if row_failed is None else [bool(f) for f in row_failed]
    excluded = [False] * m if row_excluded is None else [bool(f) for f in row_excluded]
    if len(row_names) != m or len(failed) != m or len(excluded) != m:
        raise ValueError(f"innovation: {m} rows but {len(row_names)} names, "
                         f"{len(failed)} failed and {len(excluded)} excluded flags")
    return dict(channel=channel, row_names=list(row_names), innovation=nu,
                innovation_covariance=S, beta2=float(result.beta2),
                gate_threshold=float(result.threshold), gate_exceeded=bool(result.exceeded),
                alarm_state=int(result.alarm_state),
                row_beta2=[_over(nu[k] ** 2, S[k * m + k]) for k in range(m)],
                row_excluded=excluded, row_failed=failed)


def innovation_msg(stamp, channel: str, row_names: Sequence[str], result: Any,
                   row_failed: Sequence[bool] | None = None,
                   row_excluded: Sequence[bool] | None = None, frame_id: str = ""):
    """flight_fdi_msgs/Innovation from the core's UpdateResult (nu, S, beta2, threshold,
    exceeded, alarm_state); per-row beta^2 = nu_k^2 / S_kk. ``row_failed`` / ``row_excluded``
    (one flag per row, default all false): the references declared failed, and the rows struck
    out or inflated in this update (see filter_node)."""
    from flight_fdi_msgs.msg import Innovation

    return Innovation(header=header(stamp, frame_id),
                      **_innovation_fields(channel, row_names, result, row_failed, row_excluded))


def innovation_bytes(stamp: tuple[int, int], channel: str, row_names: Sequence[str],
                     result: Any, row_failed: Sequence[bool] | None = None,
                     row_excluded: Sequence[bool] | None = None, frame_id: str = "") -> bytes:
    """:func:`innovation_msg` serialized (``stamp`` = (sec, nanosec)), without building the
    message: what the filter node publishes per update (the same bytes rclpy would send)."""
    return wire.encode_innovation(stamp[0], stamp[1], frame_id, **_innovation_fields(
        channel, row_names, result, row_failed, row_excluded))


def _filter_state_fields(channel: str, state_names: Sequence[str], x: Any, P: Any, z: Any,
                         R: Any, H: Any, u: Any, dt: float, fused: bool, gated: bool,
                         reset: bool) -> dict:
    """The fields of flight_fdi_msgs/FilterState after the header (plain Python values)."""
    return dict(channel=channel, state_names=list(state_names), x=_floats(x), p=_floats(P),
                z=_floats(z), r=_floats(R), h=_floats(H), u=_floats(u), dt=float(dt),
                fused=bool(fused), gated=bool(gated), reset=bool(reset))


def filter_state_msg(stamp, channel: str, state_names: Sequence[str], x: Any, P: Any,
                     z: Any = (), R: Any = (), H: Any = (), u: Any = (), dt: float = 0.0,
                     fused: bool = False, gated: bool = False, reset: bool = False,
                     frame_id: str = ""):
    """flight_fdi_msgs/FilterState: x(i/i), P(i/i) and the measurement step that produced them."""
    from flight_fdi_msgs.msg import FilterState

    return FilterState(header=header(stamp, frame_id), **_filter_state_fields(
        channel, state_names, x, P, z, R, H, u, dt, fused, gated, reset))


def filter_state_bytes(stamp: tuple[int, int], channel: str, state_names: Sequence[str],
                       x: Any, P: Any, z: Any = (), R: Any = (), H: Any = (), u: Any = (),
                       dt: float = 0.0, fused: bool = False, gated: bool = False,
                       reset: bool = False, frame_id: str = "") -> bytes:
    """:func:`filter_state_msg` serialized (``stamp`` = (sec, nanosec)), without building
    the message."""
    return wire.encode_filter_state(stamp[0], stamp[1], frame_id, **_filter_state_fields(
        channel, state_names, x, P, z, R, H, u, dt, fused, gated, reset))


def model_info_msg(stamp, channel: str, model: Any, gate: Any, frame_id: str = ""):
    """flight_fdi_msgs/ModelInfo from a LinearModel and a GateConfig."""
    from flight_fdi_msgs.msg import ModelInfo

    B = model.B
    names = list(model.params)
    return ModelInfo(
        header=header(stamp, frame_id), channel=channel, model_name=model.name,
        state_names=list(model.state_names), state_units=list(model.state_units),
        measurement_names=list(model.measurement_names),
        n=model.n, m=model.m, p=0 if B is None else int(B.shape[1]),
        a=_flat(model.A), qc=_flat(model.Qc), h=_flat(model.H), r=_flat(model.R),
        p0=_flat(model.P0), b=[] if B is None else _flat(B), scale=_flat(model.scale),
        param_names=names, param_values=[float(model.params[k]) for k in names],
        gate_rule=str(gate.rule), gate_probability=float(gate.probability),
        alarm_m=int(gate.alarm_m), alarm_n=int(gate.alarm_n), gate_action=str(gate.action))
