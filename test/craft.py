"""Bags with any topic names and velocity message types, from a simulated flight (tests of the
input contract)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from flight_fdi.bagio import cdr, open_writer
from flight_fdi.sim import SimConfig, simulate
from flight_fdi.sim.faults import parse_fault

TWIST, TWIST_COV, ODOM = cdr.TWIST_STAMPED, cdr.TWIST_COV_STAMPED, cdr.ODOMETRY


def flight(duration_s: float = 300.0, faults: tuple = (), seed: int = 3):
    return simulate(SimConfig(duration_s=duration_s, seed=seed,
                              faults=tuple(parse_fault(f) for f in faults)))


def yaw_quaternion(yaw: np.ndarray) -> np.ndarray:
    """(K, 4) x, y, z, w of a rotation by ``yaw`` about z (body -> navigation frame)."""
    return np.stack([np.zeros_like(yaw), np.zeros_like(yaw), np.sin(yaw / 2), np.cos(yaw / 2)], 1)


def encode(msgtype: str, stamp: np.ndarray, v_nav: np.ndarray, var: float | None,
           yaw: np.ndarray | None = None, child: str = "base_link") -> list[bytes]:
    """Messages carrying the navigation-frame velocity ``v_nav`` (K, 2) in ``msgtype``; for
    Odometry with ``yaw``, the twist is given in the body (child) frame as REP 105 says."""
    k = stamp.size
    lin = np.zeros((k, 3))
    lin[:, :2] = v_nav
    if msgtype == ODOM:
        if yaw is None:
            return cdr.encode_odometry(stamp, "map", "", np.tile([0, 0, 0, 1.0], (k, 1)), lin,
                                       None if var is None else np.eye(3) * var)
        q = yaw_quaternion(yaw)
        c, s = np.cos(yaw), np.sin(yaw)
        body = np.stack([c * lin[:, 0] + s * lin[:, 1], -s * lin[:, 0] + c * lin[:, 1],
                         lin[:, 2]], 1)  # R(yaw)^T v_nav
        return cdr.encode_odometry(stamp, "map", child, q, body,
                                   None if var is None else np.eye(3) * var)
    tw = np.zeros((k, 6))
    tw[:, :3] = lin
    if msgtype == TWIST:
        return cdr.encode(TWIST, stamp, "map", tw)
    cov = np.zeros((k, 36))
    cov[:, [0, 7, 14]] = np.broadcast_to(np.asarray(var, dtype=float), (k,))[:, None]
    return cdr.encode(TWIST_COV, stamp, "map", tw, cov)


def write(path: Path, fl, ins_topic: str = "/ins/velocity", ins_type: str = TWIST,
          ref_topics: tuple = ("/reference/velocity",), ref_type: str = TWIST_COV,
          yaw_rate: float = 0.0, ref_stamps=None, ref_values=None, ins_stamps=None,
          ref_var=None, storage: str = "mcap") -> Path:
    """A bag of ``fl`` (a SimulatedFlight) with the given topics and types. ``yaw_rate``
    (rad/s): the body turns (Odometry twists are then body-frame). ``ref_stamps`` /
    ``ref_values`` / ``ins_stamps`` replace the stamps and values (bad-input tests); messages
    are written in list order (receive order)."""
    yaw_ins = yaw_rate * fl.t
    ins_s = fl.stamp_ns if ins_stamps is None else np.asarray(ins_stamps, dtype=np.int64)
    ins = encode(ins_type, ins_s, fl.v_ins, 1e-4, yaw_ins if yaw_rate else None)
    ref_s = fl.stamp_ref_ns if ref_stamps is None else np.asarray(ref_stamps, dtype=np.int64)
    v_ref = fl.v_ref if ref_values is None else ref_values
    yaw_ref = yaw_rate * fl.t_ref
    var = fl.sigma_ref ** 2 if ref_var is None else ref_var
    refs = [encode(ref_type, ref_s, v_ref, var, yaw_ref if yaw_rate else None)
            for _ in ref_topics]
    rows = [(int(fl.stamp_ns[i]), ins_topic, ins_type, d) for i, d in enumerate(ins)]
    for topic, msgs in zip(ref_topics, refs):
        rows += [(int(fl.stamp_ref_ns[i]) + 1, topic, ref_type, d) for i, d in enumerate(msgs)]
    rows.sort(key=lambda r: r[0])
    with open_writer(path, storage=storage) as bag:
        for t_ns, topic, msgtype, data in rows:
            bag.write_raw(topic, msgtype, data, t_ns)
    return path
