"""The 3-D contract topics of a bag as arrays, for ``ins3d_input.read_ins3d``.

``read_series`` decodes each topic as a whole with the one CDR codec (``cdr.decode_doubles``:
every contract type is a header followed by doubles, NavSatFix with its status between; each
message's own frame_id length gives its own offsets) from the raw messages of the bag reader
(``reader.read_topics_raw``: MCAP chunks scanned with numpy where the bag allows, rosbags'
iterator otherwise) -- ~0.1 s for an 1800-s flight where rosbags' per-message decode takes
several seconds. ``read_series_messages`` is that per-message decode, kept as the reference the
tests (test/bagio/test_ins3d_series.py) and bench/bench_read3d.py compare with: both give the
same arrays bit for bit. ``arrays`` turns either into the inputs of ``ins3d_input.build_input``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from . import cdr
from .errors import BagError
from .ins3d_input import TYPES

#: per contract role, the doubles read (``cdr.decode_doubles`` columns), in this order
COLUMNS = {"ins_imu": (3, 0, 1, 2, 25, 26, 27, 13, 14, 15),  # q (w, x, y, z), f_b, w_b
           "ins_velocity": (0, 1, 2),                         # twist.linear
           "ins_fix": (0, 2),                                 # latitude (deg), altitude
           "ref_velocity": (0, 1, 2, 6, 13, 20)}              # linear, covariance[0, 7, 14]

#: {role: (header stamps ns (N,) int64, values (N, len(COLUMNS[role])))}, in receive order
Series = dict[str, tuple[np.ndarray, np.ndarray]]


def read_series(path: str | Path, names: dict[str, str],
                check: Callable[[dict[str, str]], None] | None = None) -> Series:
    """The contract topics ``names`` ({role: topic}) of a bag, each decoded as a whole;
    ``check`` receives the bag's {topic: type} before anything is read (``read_topics_raw``)."""
    from .reader import read_topics_raw
    return decode_series(read_topics_raw(path, list(names.values()), check=check), names, path)


def decode_series(raw: dict, names: dict[str, str], path: str | Path) -> Series:
    """``read_series`` of the raw messages ``raw`` ({topic: ``reader.RawSeries``}) already
    read (``ins3d_input.read_ins3d`` reads a height topic in the same pass)."""
    return {role: cdr.decode_doubles(TYPES[role], raw[topic].payloads, COLUMNS[role],
                                     f"bag '{path}' {topic}")
            for role, topic in names.items()}


def read_series_messages(path: str | Path, names: dict[str, str]) -> Series:
    """``read_series`` through rosbags' per-message decode (``reader.read_messages``): the
    reference (tests, bench), several seconds for an 1800-s flight."""
    from .reader import read_messages
    got: dict[str, list] = {topic: [] for topic in names.values()}
    for topic, _, _, msg in read_messages(path, list(got)):
        got[topic].append(msg)
    out = {}
    for role, topic in names.items():
        ms = got[topic]
        stamps = np.array([int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec)
                           for m in ms], dtype=np.int64)
        values = np.array([_values(role, m) for m in ms], dtype=float)
        out[role] = stamps, values.reshape(len(ms), len(COLUMNS[role]))
    return out


def _values(role: str, m) -> list[float]:
    """The values of COLUMNS[role] of a decoded message."""
    if role == "ins_imu":
        o, a, w = m.orientation, m.linear_acceleration, m.angular_velocity
        return [o.w, o.x, o.y, o.z, a.x, a.y, a.z, w.x, w.y, w.z]
    if role == "ins_velocity":
        lin = m.twist.linear
        return [lin.x, lin.y, lin.z]
    if role == "ins_fix":
        return [m.latitude, m.altitude]
    lin, cov = m.twist.twist.linear, m.twist.covariance
    return [lin.x, lin.y, lin.z, cov[0], cov[7], cov[14]]


def arrays(series: Series, names: dict[str, str], path: str | Path) -> tuple:
    """(t_imu, q, f_b, w_b, t_vel, v, t_fix, lat, h, t_ref, v_ref, r_ref, t0_ns): each topic's
    messages sorted by header stamp (stable: equal stamps keep the receive order), times in s
    from ``t0_ns``, the earliest stamp (exact: integer differences); BagError for a topic with
    fewer than two messages."""
    for role, topic in names.items():
        if series[role][0].size < 2:
            raise BagError(f"{path}: topic {topic} has fewer than two messages")
    ordered = {}
    for role, (stamps, values) in series.items():
        order = np.argsort(stamps, kind="stable")
        ordered[role] = stamps[order], values[order]
    t0_ns = int(min(s[0] for s, _ in ordered.values()))

    def seconds(role: str) -> np.ndarray:
        return (ordered[role][0] - t0_ns) * 1e-9

    def cols(role: str, a: int, b: int) -> np.ndarray:   # contiguous, as numpy builds them
        return np.ascontiguousarray(ordered[role][1][:, a:b])

    return (seconds("ins_imu"), cols("ins_imu", 0, 4), cols("ins_imu", 4, 7),
            cols("ins_imu", 7, 10), seconds("ins_velocity"), cols("ins_velocity", 0, 3),
            seconds("ins_fix"), np.radians(cols("ins_fix", 0, 1)[:, 0]),
            cols("ins_fix", 1, 2)[:, 0], seconds("ref_velocity"), cols("ref_velocity", 0, 3),
            cols("ref_velocity", 3, 6), t0_ns)


__all__ = ["COLUMNS", "Series", "arrays", "decode_series", "read_series", "read_series_messages"]
