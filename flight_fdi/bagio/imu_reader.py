"""Fast reading of three sensor_msgs/Imu streams for the triple-IMU voter (no rclpy).

``read_imu_triples(bag, topics)`` decodes the header stamps, angular velocities and linear
accelerations of the three topics with numpy (the message has a fixed layout after the header's
frame_id) and matches the streams by header stamp: a triple is three samples with the same stamp
(within ``match_tolerance_ns``). Non-finite samples, duplicate and out-of-order stamps are dropped
and counted, as voter_node does.

The Imu messages are decoded by the one CDR codec (``cdr.decode_doubles``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import cdr
from .errors import BagError
from .reader import read_topics_raw, topic_list

IMU_MSG = "sensor_msgs/msg/Imu"
#: the doubles of angular_velocity and linear_acceleration among the Imu's 37 (orientation 4,
#: its covariance 9, angular_velocity 3, its covariance 9, linear_acceleration 3, ...)
_IMU_COLUMNS = (13, 14, 15, 25, 26, 27)


@dataclass
class ImuTriples:
    """Matched samples of three IMUs: ``stamp_ns`` (T,) of IMU1, ``P`` (T, 6, 3) (gyro x/y/z
    rad/s, accel x/y/z m/s^2; IMU1..IMU3) and counts of what was dropped."""

    stamp_ns: np.ndarray
    P: np.ndarray
    first_ns: int                       # the first message's receive time in the bag
    first_stamp_ns: int                 # the earliest header stamp of the three topics
    received: list[int] = field(default_factory=list)
    dropped: dict[str, int] = field(default_factory=dict)


def decode_imu(payloads, what: str) -> tuple[np.ndarray, np.ndarray]:
    """(stamp_ns (N,), values (N, 6) gyro x/y/z, accel x/y/z) of serialized Imu messages
    (the one CDR codec: ``cdr.decode_doubles``)."""
    return cdr.decode_doubles(cdr.IMU, payloads, _IMU_COLUMNS, what)


def _check_topics(p: Path, available: dict[str, str], topics) -> None:
    for t in topics:
        if t not in available:
            raise BagError(f"bag '{p}': no topic {t} (topics: {topic_list(available)})")
        if available[t] != IMU_MSG:
            raise BagError(f"bag '{p}': {t} holds {available[t]}, not {IMU_MSG}")


def read_imu_triples(path: str | Path, topics=("/imu1/data", "/imu2/data", "/imu3/data"),
                     match_tolerance_ns: int = 2_000_000) -> ImuTriples:
    """The matched triples of a bag (see the module docstring); BagError names the problem."""
    p = Path(path)
    raw = read_topics_raw(p, topics, check=lambda available: _check_topics(p, available, topics))
    streams, dropped, received = [], {}, []
    first_ns = min((int(raw[t].log_ns.min()) for t in topics if raw[t].log_ns.size),
                   default=0)
    for k, t in enumerate(topics):
        stamp, v = decode_imu(raw[t].payloads, f"bag '{p}' {t}")
        received.append(int(stamp.size))
        ok = np.all(np.isfinite(v), axis=1)
        dropped[f"imu{k + 1}_nonfinite"] = int((~ok).sum())
        stamp, v = stamp[ok], v[ok]
        keep = np.ones(stamp.size, bool)
        keep[1:] = stamp[1:] > np.maximum.accumulate(stamp)[:-1]
        dup = np.zeros(stamp.size, bool)
        dup[1:] = stamp[1:] == stamp[:-1]
        dropped[f"imu{k + 1}_duplicate"] = int((~keep & dup).sum())
        dropped[f"imu{k + 1}_out_of_order"] = int((~keep & ~dup).sum())
        streams.append((stamp[keep], v[keep]))
    if any(s[0].size == 0 for s in streams):
        raise BagError(f"bag '{p}': an IMU topic holds no valid message")
    first_stamp = int(min(s[0][0] for s in streams))
    s1, v1 = streams[0]
    P = np.empty((s1.size, 6, 3))
    P[:, :, 0] = v1
    matched = np.ones(s1.size, bool)
    for k in (1, 2):
        sk, vk = streams[k]
        j = np.clip(np.searchsorted(sk, s1), 1, max(1, sk.size - 1))
        j = np.where(np.abs(sk[np.minimum(j, sk.size - 1)] - s1)
                     < np.abs(sk[j - 1] - s1), np.minimum(j, sk.size - 1), j - 1)
        near = np.abs(sk[j] - s1) <= match_tolerance_ns
        matched &= near
        P[:, :, k] = vk[j]
    for k in range(3):
        dropped[f"imu{k + 1}_unmatched"] = int(streams[k][0].size - matched.sum())
    if matched.sum() < 2:
        raise BagError(f"bag '{p}': fewer than 2 matched IMU triples (stamps of the three "
                       "topics do not coincide)")
    return ImuTriples(s1[matched], P[matched], first_ns, first_stamp, received, dropped)
