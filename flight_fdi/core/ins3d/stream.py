"""The 3-D forward filter one message at a time (what ``filter_node`` with ``model: ins3d`` runs).

Two parts, both pure logic (no rclpy):

* :class:`Ins3dStream` -- the filter itself: ``predict`` takes one propagation step and
  ``update`` one reference row, calling the same compiled kernels as the batch
  ``filter.run_forward`` (``filter.propagate``, ``filter._update``) on the same scaled state,
  so its states, innovations and gates equal the batch filter's bit for bit
  (test/ins3d_nodes/test_stream.py).
* :class:`Ins3dAssembler` -- the contract topics (/ins/imu, /ins/velocity, /ins/fix,
  /reference/velocity) turned into those steps and rows as ``bagio.ins3d_input.build_input``
  does for a whole bag: the IMU stamps are the step boundaries, the INS velocity, latitude and
  height are linearly interpolated at them, a reference row is z = v_INS(t_ref) - v_ref with the
  INS acceleration (the latency column) interpolated from the central differences of the
  velocity samples, applied at the first boundary at or after its stamp. Times are seconds from
  the earliest first stamp of the four topics (exact from integer nanoseconds), as in the bag
  reader. An event waits until the samples it needs have arrived (the fix topic's next sample:
  0.2 s at 5 Hz), a boundary also until the reference stream has passed it (or ``wait_s`` of IMU
  time went by: a reference dropout does not stop the filter). ``finish()`` flushes the end of
  the record (the last samples clamp, as ``numpy.interp`` does). One difference to the batch
  reader: numpy's ``gradient`` uses its uniform-spacing formula when *every* velocity stamp is
  equally spaced; the stream always uses the general three-point formula (they differ by
  rounding, ~1e-16 relative).
"""
from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..gate import AlarmLogic, GateConfig
from .data import NavSteps, interpolate_height, nav_steps
from .filter import _update, propagate, scale_factors, white_variance
from .model import Ins3dModel


@dataclass
class Ins3dUpdate:
    """One reference update: innovation, its covariance, the gates and the alarm state."""

    nu: np.ndarray
    S: np.ndarray
    beta2: float
    beta2_row: np.ndarray
    exceeded: bool
    exceeded_row: np.ndarray
    alarm: int
    fused: bool


class Ins3dStream:
    """The forward filter of ``filter.run_forward``, one step or one row per call."""

    def __init__(self, model: Ins3dModel, gate: GateConfig = GateConfig(),
                 P0: np.ndarray | None = None, x0: np.ndarray | None = None) -> None:
        self.model, self.gate = model, gate
        n = model.n
        p0 = model.p0()
        self.s = np.sqrt(p0)
        P0 = np.diag(p0) if P0 is None else np.asarray(P0, dtype=float)
        x0 = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float)
        self._x = x0 / self.s
        self._P = P0 / (self.s[:, None] * self.s[None, :])
        self._bias, self._qc = model.kernel_params(), model.qc()
        self._F, self._Phi, self._Qd = np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
        self._T, self._xt = np.empty((n, n)), np.empty(n)
        self._nz, self._cnt = np.empty((n, n), dtype=np.int64), np.empty(n, dtype=np.int64)
        self._ratio, self._inv_ss = scale_factors(self.s)
        self.threshold, self.threshold_row = gate.threshold(model.rows), gate.threshold(1)
        self._alarm = AlarmLogic(gate.alarm_m, gate.alarm_n)
        rows = model.rows
        self._out = (np.empty((1, rows)), np.empty((1, rows, rows)), np.empty(1),
                     np.empty((1, rows)), np.zeros(1, dtype=np.bool_))
        self._no_gain = (np.empty((0, n, rows)), np.empty((0, rows, rows)))

    def predict(self, steps: NavSteps, k: int = 0) -> None:
        """Propagate over step ``k`` of ``steps``."""
        propagate(self._x, self._P, steps.C[k], steps.f_n[k], steps.v[k], steps.lat[k],
                  steps.h[k], steps.dt[k], self._bias, self._qc, self._ratio, self._inv_ss,
                  self._F, self._Phi, self._Qd, self._T, self._xt, self._nz, self._cnt)

    def update(self, z: np.ndarray, r: np.ndarray, a: np.ndarray) -> Ins3dUpdate:
        """Fuse one reference row: z (3,) = v_INS - v_ref, r (3,) its published variances,
        a (3,) the INS acceleration (the latency state's column)."""
        m = self.model
        r_white = white_variance(m, np.asarray(r, dtype=float)[None, :])[0]
        nu, S, b2, b2r, exc = self._out
        _update(self._x, self._P, self.s, np.asarray(z, dtype=float), r_white,
                np.asarray(a, dtype=float), *m.row_args(),
                self.threshold, self.gate.action == "reject", 0, nu, S, b2, b2r, exc,
                *self._no_gain)
        exceeded = bool(exc[0])
        return Ins3dUpdate(nu[0].copy(), S[0].copy(), float(b2[0]), b2r[0].copy(), exceeded,
                           b2r[0] > self.threshold_row, self._alarm.push(exceeded),
                           not (exceeded and self.gate.action == "reject"))

    @property
    def x(self) -> np.ndarray:
        """The state in physical units."""
        return self._x * self.s

    @property
    def sd(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self._P), 0.0)) * self.s

    @property
    def P(self) -> np.ndarray:
        return self._P * self.s[:, None] * self.s[None, :]


# ----------------------------------------------------------------------------- the assembler

@dataclass
class Boundary:
    """Step boundary k (an /ins/imu stamp); ``step`` the propagation step k-1 -> k (None: k = 0)."""

    k: int
    t: float
    ns: int
    step: NavSteps | None


@dataclass
class Row:
    """A reference row for the update at boundary ``k`` (the RefRows fields of one row)."""

    k: int
    t: float
    ns: int
    z: np.ndarray
    r: np.ndarray
    a: np.ndarray


class _Series:
    """One topic's samples (relative time, values), pruned from the front."""

    def __init__(self) -> None:
        self.t: list[float] = []
        self.y: list[np.ndarray] = []
        self.base = 0                      # absolute index of t[0]

    def add(self, t: float, y: np.ndarray) -> None:
        self.t.append(t)
        self.y.append(y)

    def covers(self, t: float, finished: bool) -> bool:
        return finished or (bool(self.t) and self.t[-1] >= t)

    def interp(self, t: float) -> np.ndarray:
        """numpy.interp over the whole series (clamped at both ends)."""
        i = bisect.bisect_right(self.t, t)
        if i == 0:
            return self.y[0]
        if i == len(self.t):
            return self.y[-1]
        tw, yw = [self.t[i - 1], self.t[i]], np.stack([self.y[i - 1], self.y[i]])
        return np.array([np.interp(t, tw, yw[:, c]) for c in range(yw.shape[1])])

    def gradient(self, i: int) -> np.ndarray:
        """numpy.gradient (edge order 1, non-uniform spacing) at local sample i; the last
        sample is an edge only once the series is complete."""
        t, y = self.t, self.y
        if i == 0 and self.base == 0:
            return (y[1] - y[0]) / (t[1] - t[0])
        if i == len(t) - 1:
            return (y[i] - y[i - 1]) / (t[i] - t[i - 1])
        dx1, dx2 = t[i] - t[i - 1], t[i + 1] - t[i]
        a = -(dx2) / (dx1 * (dx1 + dx2))
        b = (dx2 - dx1) / (dx1 * dx2)
        c = dx1 / (dx2 * (dx1 + dx2))
        return a * y[i - 1] + b * y[i] + c * y[i + 1]

    def prune(self, t: float, keep: int = 3) -> None:
        """Forget samples older than the ``keep``-th before time t (in blocks)."""
        cut = bisect.bisect_left(self.t, t) - keep
        if cut > 256:
            del self.t[:cut], self.y[:cut]
            self.base += cut


TOPIC_KEYS = ("ins_imu", "ins_velocity", "ins_fix", "ref_velocity")
#: the optional height reference's key (``Ins3dAssembler(height=HeightRule(...))``)
HEIGHT = "height"


@dataclass(frozen=True)
class HeightRule:
    """A height reference as the third row (``bagio.height_input.HeightSpec``'s numbers): the
    widest interpolation gap (s), the datum ``first`` (True: offset to the INS height at the
    first sample inside the IMU record, the prior ``h0_sigma`` its sigma) or absolute, and the
    variance of a sample without a usable one (m^2)."""

    max_gap_s: float
    first: bool
    variance: float


class Ins3dAssembler:
    """The contract topics, one message at a time, to :class:`Boundary` and :class:`Row` events
    in the batch filter's order (see the module docstring). ``add_*`` return the events that
    became complete, or a drop reason string (``out_of_order``, ``duplicate_stamp``,
    ``non_finite``, ``invalid_covariance``); ``late`` counts reference rows that arrived after
    their boundary had been passed (only after a ``wait_s`` time-out)."""

    def __init__(self, wait_s: float = 1.0, height: HeightRule | None = None) -> None:
        self.wait_s = float(wait_s)
        self.height = height
        self.hgt = _Series()                      # (t, [h, variance]) inside the IMU record
        self._hgt_held: list = []                 # height messages before t0
        self.offset: float | None = None if height is not None and height.first else 0.0
        self.h0_sigma: float | None = None        # the datum's prior (``Ins3dModel.h0_sigma``)
        self.no_height = 0                        # reference rows without a height
        self.height_outside = 0                   # heights outside the IMU record
        self.height_from_message = 0              # heights whose variance was the message's
        self.t0_ns: int | None = None
        self._held: dict[str, list] = {k: [] for k in TOPIC_KEYS}
        self._last_ns: dict[str, int] = {}
        self.imu, self.vel, self.fix = _Series(), _Series(), _Series()
        self._imu_fw: list[np.ndarray] = []       # (f, w) per IMU message, same indexing as imu
        self._imu_ns: list[int] = []
        self._nav: dict[int, tuple] = {}          # boundary k -> (q, v, lat, h)
        self.refs: deque = deque()                # (t, ns, v_ref, r) waiting
        self._ref_last_t = -np.inf
        self.k = -1                               # last boundary emitted
        self.finished = False
        self.late = 0
        self.outside = 0

    # -- input
    def _accept(self, key: str, ns: int, values: np.ndarray) -> str | None:
        if not np.all(np.isfinite(values)):
            return "non_finite"
        last = self._last_ns.get(key)
        if last is not None and ns <= last:
            return "duplicate_stamp" if ns == last else "out_of_order"
        self._last_ns[key] = ns
        return None

    def add(self, key: str, ns: int, *values: np.ndarray) -> list | str:
        """One message of topic ``key`` (TOPIC_KEYS, or HEIGHT) with its stamp in ns: ins_imu
        (q (w, x, y, z), f, w), ins_velocity (v), ins_fix (lat rad, h), ref_velocity (v, r),
        height (h m, its variance m^2 or NaN: unknown)."""
        flat = np.concatenate([np.atleast_1d(np.asarray(v, dtype=float))
                               for v in (values[:1] if key == HEIGHT else values)])
        why = self._accept(key, int(ns), flat)
        if why is not None:
            return why
        if key == "ref_velocity" and np.any(np.asarray(values[1]) <= 0):
            return "invalid_covariance"
        if self.t0_ns is None:                    # t0: the contract topics' (as the bag reader)
            (self._hgt_held if key == HEIGHT else self._held[key]).append((int(ns), values))
            if all(self._held.values()):
                self.t0_ns = min(h[0][0] for h in self._held.values())
                for k, held in [*self._held.items(), (HEIGHT, self._hgt_held)]:
                    for ns_, vals in held:
                        self._store(k, ns_, vals)
                self._held, self._hgt_held = {}, []
                return self._drain()
            return []
        self._store(key, int(ns), values)
        return self._drain()

    def _store(self, key: str, ns: int, values: tuple) -> None:
        t = (ns - self.t0_ns) * 1e-9
        if key == "ins_imu":
            self.imu.add(t, np.asarray(values[0], dtype=float))
            self._imu_fw.append((np.asarray(values[1], dtype=float),
                                 np.asarray(values[2], dtype=float)))
            self._imu_ns.append(ns)
        elif key == "ins_velocity":
            self.vel.add(t, np.asarray(values[0], dtype=float))
        elif key == "ins_fix":
            self.fix.add(t, np.array([float(values[0]), float(values[1])]))
        elif key == HEIGHT:
            if t < self.imu.t[0]:
                self.height_outside += 1
                return
            var = float(values[1])
            known = math.isfinite(var) and var > 0
            self.height_from_message += known
            self.hgt.add(t, np.array([float(values[0]), var if known else self.height.variance,
                                      float(known)]))
        else:
            self.refs.append((t, ns, np.asarray(values[0], dtype=float),
                              np.asarray(values[1], dtype=float)))
            self._ref_last_t = t

    def finish(self) -> list:
        """The events that wait for samples that will not come (end of the record)."""
        if self.t0_ns is None:
            return []
        self.finished = True
        events = self._drain()
        self.outside += len(self.refs)            # after the last IMU stamp
        self.refs.clear()
        if self.height is not None and self.imu.t:
            after = len(self.hgt.t) - bisect.bisect_right(self.hgt.t, self.imu.t[-1])
            self.height_outside += after
            self.height_from_message -= int(sum(y[2] for y in self.hgt.y[len(self.hgt.t) - after:]))
        return events

    # -- events
    @staticmethod
    def _eps(t: float) -> float:
        return 1e-9 * max(1.0, abs(t))

    def _boundary_t(self, k: int) -> float | None:
        i = k - self.imu.base
        return self.imu.t[i] if 0 <= i < len(self.imu.t) else None

    def _step_of(self, t: float) -> int | None:
        """Index of the first boundary at or after t (None: not received yet)."""
        i = bisect.bisect_left(self.imu.t, t - self._eps(t))
        return None if i == len(self.imu.t) else i + self.imu.base

    def _nav_at(self, k: int) -> tuple:
        nav = self._nav.get(k)
        if nav is None:
            t = self._boundary_t(k)
            lat_h = self.fix.interp(t)
            nav = (self.imu.y[k - self.imu.base], self.vel.interp(t), lat_h[0], lat_h[1])
            self._nav[k] = nav
        return nav

    def _ready_boundary(self, k: int) -> bool:
        t = self._boundary_t(k)
        return t is not None and self.vel.covers(t, self.finished) and \
            self.fix.covers(t, self.finished)

    def _datum(self) -> bool:
        """Whether the height's datum is known (``HeightRule.first``: the first sample inside
        the IMU record and the fix around it have come; ``offset``, ``h0_sigma``)."""
        if self.offset is not None:
            return True
        if not self.hgt.t or not self.fix.covers(self.hgt.t[0], self.finished):
            return False
        h0, var0, _ = self.hgt.y[0]
        self.offset = float(self.fix.interp(self.hgt.t[0])[1] - h0)
        self.h0_sigma = math.sqrt(float(var0))
        return True

    def _height_at(self, t: float) -> tuple[float, float] | str | None:
        """(height + datum offset, its variance) at a reference stamp t (``interpolate_height``
        between the samples around it, as the bag reader), ``"wait"`` while a sample it needs
        may still come, None when there is none within the rule's gap (the row is dropped:
        ``no_height``). A sample is used once the IMU record reaches it (the bag reader drops
        the heights after the IMU record's end); a row gives up waiting for a sample after it
        when the IMU is ``max_gap_s`` + ``wait_s`` past its stamp (a sample that could pair
        would have come by then)."""
        s, rule = self.hgt, self.height
        if self.offset is None:
            return None                           # the record ended without a height
        i = bisect.bisect_left(s.t, t)
        if i < len(s.t) and s.t[i] == t:
            j = [i]
        elif i < len(s.t) and (self.finished or self.imu.t[-1] >= s.t[i]):
            if (self.finished and s.t[i] > self.imu.t[-1]) or i == 0 \
                    or s.t[i] - s.t[i - 1] > rule.max_gap_s:
                return None
            j = [i - 1, i]
        elif self.finished or self.imu.t[-1] - t > rule.max_gap_s + self.wait_s:
            return None                           # a sample after t within the gap came by now
        else:
            return "wait"
        y = np.stack([s.y[k] for k in j])
        hz, rz, _ = interpolate_height(np.array([t]), np.array([s.t[k] for k in j]),
                                       y[:, 0] + self.offset, y[:, 1], rule.max_gap_s)
        return float(hz[0]), float(rz[0])

    def _row(self) -> Row | str | None:
        """The first waiting reference as a row when it can be computed, else None (or
        ``"no_height"``: it has no height sample)."""
        t, ns, v_ref, r = self.refs[0]
        vel = self.vel
        i = bisect.bisect_right(vel.t, t)         # first sample after t
        if not self.finished and i + 1 >= len(vel.t):
            return None                           # needs samples i and i + 1 (gradient at i)
        v_i = vel.interp(t)
        if i == 0:
            a_i = vel.gradient(0)
        elif i == len(vel.t):
            a_i = vel.gradient(i - 1)
        else:
            g0, g1 = vel.gradient(i - 1), vel.gradient(i)
            tw = [vel.t[i - 1], vel.t[i]]
            a_i = np.array([np.interp(t, tw, [g0[c], g1[c]]) for c in range(3)])
        z = v_i - v_ref
        if self.height is not None:               # the third row: the height (data.with_height)
            got = self._height_at(t)
            if got is None or got == "wait":
                return "no_height" if got is None else None
            z, r, a_i = z.copy(), np.asarray(r, dtype=float).copy(), a_i.copy()
            z[2] = self.fix.interp(t)[1] - got[0]
            r[2], a_i[2] = got[1], v_i[2]
        return Row(-1, t, ns, z, r, a_i)

    def _updates(self, events: list) -> None:
        """Rows of the current boundary ``self.k``."""
        while self.refs:
            t = self.refs[0][0]
            if t < self.imu.t[0] and self.imu.base == 0:
                self.refs.popleft()
                self.outside += 1
                continue
            k = self._step_of(t)
            if k is None or k > self.k:
                return
            if k < self.k:                        # its boundary was passed (time-out)
                self.refs.popleft()
                self.late += 1
                continue
            row = self._row()
            if row is None:
                return
            self.refs.popleft()
            if isinstance(row, str):
                self.no_height += 1
                continue
            row.k = k
            events.append(row)

    def _can_advance(self) -> bool:
        k = self.k
        if not self._ready_boundary(k + 1):
            return False
        t_k = self._boundary_t(k)
        if self.refs:
            s = self._step_of(self.refs[0][0])
            if s is not None and s <= k:
                return False                      # a row of boundary k still waits
        return (self.finished or self._ref_last_t - self._eps(self._ref_last_t) > t_k
                or self.imu.t[-1] - t_k > self.wait_s)

    def _drain(self) -> list:
        events: list = []
        if self.height is not None and not self._datum() and not self.finished:
            return events                         # the prior of the first step needs it
        if self.k < 0:
            if not self.imu.t:
                return events
            self.k = 0
            events.append(Boundary(0, self.imu.t[0], self._imu_ns[0], None))
        while True:
            self._updates(events)
            if not self._can_advance():
                break
            k = self.k + 1
            q0, v0, lat0, h0 = self._nav_at(k - 1)
            q1, v1, lat1, h1 = self._nav_at(k)
            f, w = self._imu_fw[k - self.imu.base]
            step = nav_steps(np.array([self._boundary_t(k - 1), self._boundary_t(k)]),
                             np.stack([q0, q1]), f[None, :], w[None, :], np.stack([v0, v1]),
                             np.array([lat0, lat1]), np.array([h0, h1]))
            self._nav.pop(k - 1, None)
            self.k = k
            events.append(Boundary(k, self._boundary_t(k), self._imu_ns[k - self.imu.base],
                                   step))
            self._prune()
        return events

    def _prune(self) -> None:
        t = self._boundary_t(self.k)
        before = self.imu.base
        self.imu.prune(t)
        cut = self.imu.base - before
        if cut:
            del self._imu_fw[:cut], self._imu_ns[:cut]
        self.vel.prune(t - self.wait_s)
        self.fix.prune(t)
        if self.height is not None and self.offset is not None:
            self.hgt.prune(t - self.wait_s - self.height.max_gap_s)


__all__ = ["Boundary", "HEIGHT", "HeightRule", "Ins3dAssembler", "Ins3dStream", "Ins3dUpdate",
           "Row", "TOPIC_KEYS"]
