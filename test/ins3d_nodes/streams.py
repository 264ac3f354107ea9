"""A short simulated 3-D flight as the four contract topics' messages, in stamp order (what a
bag replay delivers), for the streaming tests."""
from __future__ import annotations

import functools

import numpy as np

from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
from flight_fdi.sim.trajectory import TrajectoryConfig

T0_NS = 1_700_000_000 * 1_000_000_000


@functools.lru_cache(maxsize=2)
def flight(duration_s: float = 420.0, seed: int = 3):
    """cruise_turns, navigation grade: the first turn starts at ~303 s."""
    cfg = Sim3DConfig(TrajectoryConfig(profile="cruise_turns", duration_s=duration_s,
                                       rate_hz=100.0), grade="navigation", seed=seed)
    return simulate3d(cfg)


def topic_messages(fl, imu_hz: float = 20.0, vel_hz: float = 20.0, fix_hz: float = 5.0):
    """[(ns, key, values)] sorted by stamp, decimated as ``bagio.ins3d_input.from_flight``."""
    rate = fl.config.trajectory.rate_hz
    t, ins, g = fl.t, fl.ins, fl.gnss
    ns = lambda s: T0_NS + int(round(float(s) * 1e9))
    every = int(round(rate / imu_hz))
    m = fl.gyro.rate.shape[0] // every
    w = fl.gyro.rate[:m * every].reshape(m, every, 3).mean(axis=1)
    f = fl.accel.rate[:m * every].reshape(m, every, 3).mean(axis=1)
    out = []
    for j, i in enumerate(every * np.arange(1, m + 1)):
        out.append((ns(t[i]), 0, "ins_imu", (ins.q[i], f[j], w[j])))
    for i in range(0, t.size, int(round(rate / vel_hz))):
        out.append((ns(t[i]), 1, "ins_velocity", (ins.v[i],)))
    for i in range(0, t.size, int(round(rate / fix_hz))):
        out.append((ns(t[i]), 2, "ins_fix", (np.radians(np.degrees(ins.lat[i])), ins.h[i])))
    var = np.broadcast_to(g.vel_var, g.v.shape)
    for i in range(g.t.size):
        out.append((ns(g.t[i]), 3, "ref_velocity", (g.v[i], var[i])))
    out.sort(key=lambda e: (e[0], e[1]))
    return [(a, k, v) for a, _, k, v in out]


def batch_input(msgs):
    """``bagio.ins3d_input.build_input`` of the same messages (relative times as the reader)."""
    from flight_fdi.bagio.ins3d_input import build_input

    t0 = min(ns for ns, _, _ in msgs)
    by = {}
    for ns, key, vals in msgs:
        by.setdefault(key, []).append(((ns - t0) * 1e-9, vals))
    col = lambda key, i: np.array([v[i] for _, v in by[key]])
    ts = lambda key: np.array([s for s, _ in by[key]])
    return build_input(ts("ins_imu"), col("ins_imu", 0), col("ins_imu", 1), col("ins_imu", 2),
                       ts("ins_velocity"), col("ins_velocity", 0), ts("ins_fix"),
                       col("ins_fix", 0), col("ins_fix", 1), ts("ref_velocity"),
                       col("ref_velocity", 0), col("ref_velocity", 1))


def assert_rows_are(events, refs) -> None:
    """The assembler's rows among ``events`` are the bag reader's ``refs`` (boundary, stamp,
    z, r bit for bit; the latency column: numpy.gradient's uniform-spacing branch may differ by
    rounding), and every row follows its boundary and precedes the next one."""
    from flight_fdi.core.ins3d.stream import Boundary, Row

    rows = [e for e in events if isinstance(e, Row)]
    np.testing.assert_array_equal([r.k for r in rows], refs.step)
    np.testing.assert_array_equal([r.t for r in rows], refs.t)
    np.testing.assert_array_equal(np.array([r.z for r in rows]), refs.z)
    np.testing.assert_array_equal(np.array([r.r for r in rows]), refs.r)
    np.testing.assert_allclose(np.array([r.a for r in rows]), refs.a, rtol=1e-12, atol=1e-15)
    order = [(e.k, 0 if isinstance(e, Boundary) else 1) for e in events]
    assert order == sorted(order)
