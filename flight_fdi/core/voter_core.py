"""The triple-IMU voter engine shared by ``voter_node`` and ``flight-fdi vote`` (seed 002 on real
sensors).

Per matched triple (IMU1..IMU3 samples of one instant; ``P`` rows (6 quantities, 3 IMUs)):

1. **Alignment** (tables with a model, see :class:`VoterModel`): IMU2 and IMU3 moved onto IMU1's
   time by their time offsets (given, or estimated by cross-correlation over the learning phase,
   :mod:`flight_fdi.core.voter_align`), then mapped into IMU1's axes (mounting maps).
2. **Statistic**: pair differences x1 = P1 - P2, x2 = P2 - P3, x3 = P1 - P3, a ``prefilter``-sample
   moving average (removes the vibration near the Nyquist frequency that real units do not share:
   its window sum does not cancel at the window's ends), then the mean of the last N (growing
   until N exist) -- the seed's window mean. With ``prefilter`` 1 it is exactly the seed's.
   With a ``linear`` section the per-pair linear model (lever arm, scale:
   :mod:`flight_fdi.core.voter_linear`) is subtracted from the differences first. The moving
   means are compiled kernels (:mod:`flight_fdi.core.voter_kernel`).
3. **Per-unit offset model**: real units disagree by constant offsets far larger than a fault.
   Each pair's nominal offset b is the statistic at the end of the **learning phase** (the first
   ``learn_s`` seconds of the flight, no decisions during it) -- with ``offset_blocks`` B > 1
   the median of the means of B blocks of that window instead (:func:`block_median`: robust
   to a transient at the start of a recording); with ``track_tau_s`` > 0 it then
   follows the statistic with a first-order filter of that time constant, frozen whenever a
   quantity is not healthy (a fault is not learnt). The thresholds bound the deviation
   statistic - b, so a constant offset is not a fault and a sudden change is. ``learn_s`` 0:
   b = 0 (the seed's simulated IMUs, tables without a model). ``baseline`` "grow" (the step
   detector): b is the mean of every earlier sample admitted while its quantity was healthy
   (:func:`flight_fdi.core.voter_kernel.step_deviation`).
4. **Vote**: eps_k = deviation of x_k inside the table's bounds at the flight time, the seed's
   truth table (:func:`flight_fdi.core.voting.vote_array`). With a ``sequential`` section the
   CUSUM of each pair's sample residual (prefiltered difference - b) must also be below its
   threshold (:mod:`flight_fdi.core.voter_sequential`).
5. **Persistence** (:class:`Persistence`): a single fault naming IMU k on a quantity for
   ``confirm`` consecutive decisions isolates IMU k there; isolations latch (sticky) and are
   released after ``release_after_windows`` complete windows of healthy votes in a row; the
   selected output is the first IMU isolated on no quantity, so it never flaps.

:class:`VoterCore` takes triples in batches of any size (the node: one at a time; the offline
command: the whole flight at once) and gives the same decisions: the statistics of a batch are
computed with cumulative sums over the batch and the carried tails of the previous ones.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from .errors import CoreError
from .voter_align import check_mounting, correct_mounting, delay, estimate_time_offsets
from . import voter_linear, voter_sequential
from .voter_kernel import step_deviation, tail_means
from .voting import QUANTITIES, SINGLE_FAULT, HEALTHY, MARGINAL, ThresholdTable, vote_array

#: defaults chosen on the real recordings (docs/voter_real.md)
DEFAULT_CONFIRM_S = 1.0
DEFAULT_RELEASE_WINDOWS = 3
#: offset models: the first learn_s seconds (fixed) or the growing baseline of the step detector
BASELINES = ("learn", "grow")


@dataclass(frozen=True)
class VoterModel:
    """The real-sensor model of a threshold table (its ``model`` section)."""

    prefilter: int = 1                  # samples of the moving average before the window mean
    learn_s: float = 0.0                # learning phase (offsets, time offsets); 0: none
    track_tau_s: float = 0.0            # slow offset tracking time constant; 0: frozen
    time_offsets_s: tuple[float, float, float] | None = (0.0, 0.0, 0.0)  # None: estimate
    max_lag_s: float = 0.2              # search range of the time offset estimate
    mounting: Mapping[str, Any] | None = None
    baseline: str = "learn"             # offset: "learn" (first learn_s) or "grow" (step detector)
    linear: Mapping[str, Any] | None = None   # per-pair linear model (core/voter_linear.py)
    offset_blocks: int = 1              # offset: median of this many block means of the window
    sequential: Mapping[str, Any] | None = None   # CUSUM section (core/voter_sequential.py)
    extra: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def from_table(cls, table: ThresholdTable) -> "VoterModel":
        return cls.from_dict(table.model, "threshold table model")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "voter model") -> "VoterModel":
        d = dict(d or {})
        try:
            prefilter = d.pop("prefilter", 1)
            learn = float(d.pop("learn_s", 0.0))
            track = float(d.pop("track_tau_s", 0.0))
            max_lag = float(d.pop("max_lag_s", 0.2))
            tau = d.pop("time_offsets_s", [0.0, 0.0, 0.0])
            tau = None if tau is None else tuple(float(v) for v in tau)
            baseline = d.pop("baseline", "learn")
            blocks = d.pop("offset_blocks", 1)
        except (TypeError, ValueError):
            raise CoreError(f"{source}: prefilter, learn_s, track_tau_s, max_lag_s and "
                            "time_offsets_s must be numbers") from None
        if isinstance(prefilter, bool) or not isinstance(prefilter, (int, float)) \
                or prefilter != int(prefilter) or not 1 <= prefilter <= 100000:
            raise CoreError(f"{source}: prefilter must be an integer >= 1, got {prefilter!r}")
        for name, v in (("learn_s", learn), ("track_tau_s", track), ("max_lag_s", max_lag)):
            if not math.isfinite(v) or v < 0:
                raise CoreError(f"{source}: {name} must be >= 0, got {v!r}")
        if tau is not None and (len(tau) != 3 or tau[0] != 0.0
                                or not all(math.isfinite(v) and abs(v) < 10 for v in tau)):
            raise CoreError(f"{source}: time_offsets_s must be [0, tau2, tau3] in seconds "
                            f"(|tau| < 10), got {tau!r}")
        if tau is None and learn <= 0:
            raise CoreError(f"{source}: estimating the time offsets needs a learning phase "
                            "(learn_s > 0)")
        if isinstance(blocks, bool) or not isinstance(blocks, (int, float)) \
                or blocks != int(blocks) or not 1 <= blocks <= 1000:
            raise CoreError(f"{source}: offset_blocks must be an integer >= 1, got {blocks!r}")
        if baseline not in BASELINES:
            raise CoreError(f"{source}: baseline must be one of {', '.join(BASELINES)}, "
                            f"got {baseline!r}")
        if baseline == "grow" and (learn <= 0 or track > 0):
            raise CoreError(f"{source}: the grow baseline needs a learning phase (learn_s > 0) "
                            "and replaces the offset tracking (track_tau_s 0)")
        mounting = check_mounting(d.pop("mounting", None), source)
        linear = voter_linear.check(d.pop("linear", None), source)
        sequential = voter_sequential.check(d.pop("sequential", None), source)
        if sequential and (baseline != "learn" or track > 0 or learn <= 0):
            raise CoreError(f"{source}: the sequential detector needs the fixed offset of a "
                            "learning phase (baseline learn, learn_s > 0, track_tau_s 0)")
        return cls(int(prefilter), learn, track, tau, max_lag, mounting, baseline, linear,
                   int(blocks), sequential, d)

    def to_dict(self) -> dict[str, Any]:
        return {"prefilter": self.prefilter, "learn_s": self.learn_s,
                "track_tau_s": self.track_tau_s,
                "time_offsets_s": None if self.time_offsets_s is None
                else list(self.time_offsets_s),
                "max_lag_s": self.max_lag_s, "mounting": self.mounting,
                "baseline": self.baseline, "linear": self.linear,
                "offset_blocks": self.offset_blocks, "sequential": self.sequential,
                **dict(self.extra)}


class Persistence:
    """Isolation with confirmation and a latch, per quantity (see the module docstring)."""

    def __init__(self, n_quantities: int, confirm: int, release: int, sticky: bool = True
                 ) -> None:
        if confirm < 1 or release < 0:
            raise CoreError("persistence: confirm must be >= 1 and release >= 0")
        self.confirm, self.release, self.sticky = int(confirm), int(release), bool(sticky)
        self.isolated = [0] * n_quantities
        self._cand = [0] * n_quantities
        self._cand_n = [0] * n_quantities
        self._healthy = [0] * n_quantities

    def update(self, status: Sequence[int], faulty: Sequence[int]) -> list[tuple[int, int, int]]:
        """One decision; returns the changes (quantity index, old isolated IMU, new)."""
        changes = []
        for i, (s, f) in enumerate(zip(status, faulty)):
            ch = self._step(i, int(s), int(f))
            if ch:
                changes.append(ch)
        return changes

    def update_batch(self, status: np.ndarray, faulty: np.ndarray
                     ) -> tuple[np.ndarray, list[tuple[int, int, int, int]]]:
        """Decisions (m, Q) in order: (isolated IMU after each (m, Q), changes (row, quantity,
        old, new)). A quantity with nothing isolated, pending or single-faulted in the batch
        only counts its healthy run (vectorised); the others step decision by decision."""
        m, Q = status.shape
        isolated = np.empty((m, Q), dtype=np.int8)
        changes = []
        for i in range(Q):
            col = status[:, i]
            if not self.isolated[i] and not self._cand_n[i] and not np.any(col == SINGLE_FAULT):
                bad = np.flatnonzero(col != HEALTHY)
                self._healthy[i] = (self._healthy[i] + m if bad.size == 0
                                    else m - 1 - int(bad[-1]))
                isolated[:, i] = 0
                continue
            fcol = faulty[:, i].tolist()
            for r, s in enumerate(col.tolist()):
                ch = self._step(i, s, fcol[r])
                if ch:
                    changes.append((r,) + ch)
                isolated[r, i] = self.isolated[i]
        changes.sort()
        return isolated, changes

    def _step(self, i: int, s: int, f: int) -> tuple[int, int, int] | None:
        """One decision of quantity i; the change (i, old, new) or None."""
        if s == SINGLE_FAULT:
            if self._cand[i] == f:
                self._cand_n[i] += 1
            else:
                self._cand[i], self._cand_n[i] = int(f), 1
        else:
            self._cand[i] = self._cand_n[i] = 0
        self._healthy[i] = self._healthy[i] + 1 if s == HEALTHY else 0
        new = self.isolated[i]
        if self._cand_n[i] >= self.confirm:
            new = self._cand[i]
        elif not self.sticky:
            if s in (HEALTHY, MARGINAL):
                new = 0
        elif self.release and new and self._healthy[i] >= self.release:
            new = 0
        if new != self.isolated[i]:
            old, self.isolated[i] = self.isolated[i], new
            return (i, old, new)
        return None


def select(isolated: Sequence[int], current: int, avoid: set[int] = frozenset()) -> int:
    """The first of IMU1..IMU3 isolated on no quantity (and not in ``avoid`` if possible);
    ``current`` when every IMU is isolated."""
    iso = {int(v) for v in isolated if v}
    for skip in (iso | set(avoid), iso):
        free = [k for k in (1, 2, 3) if k not in skip]
        if free:
            return free[0]
    return current


def block_median(rows: np.ndarray, blocks: int) -> np.ndarray:
    """The offset learnt from the window ``rows`` (n, ...): the median of the means of ``blocks``
    contiguous blocks (1: the window mean). A transient in part of the learning phase (the
    first second of some real flights, docs/voter_real.md) then does not shift the offset."""
    if blocks <= 1 or rows.shape[0] < blocks:
        return rows.mean(axis=0)
    return np.median(np.stack([b.mean(axis=0) for b in np.array_split(rows, blocks)]), axis=0)


def _tail_means(tail: np.ndarray, new: np.ndarray, width: int) -> np.ndarray:
    """Means of the last ``width`` values (fewer at the flight start) at every row of ``new``
    (m, ...), ``tail`` holding the rows just before it (:func:`voter_kernel.tail_means`)."""
    m, C = new.shape[0], int(np.prod(new.shape[1:]))
    out = tail_means(np.ascontiguousarray(tail.reshape(tail.shape[0], C)),
                     np.ascontiguousarray(new.reshape(m, C)), int(width))
    return out.reshape(new.shape)


@dataclass
class Decisions:
    """The decisions of one batch (m decided samples)."""

    index: np.ndarray          # (m,) sample index in the flight (0 = first triple)
    t_flight: np.ndarray       # (m,) s since the first triple
    deviation: np.ndarray      # (m, Q, 3) statistic - offset (the voted value)
    eps: np.ndarray            # (m, Q, 3)
    status: np.ndarray         # (m, Q)
    faulty: np.ndarray         # (m, Q)
    isolated: np.ndarray       # (m, Q) latched isolation after the decision
    lower: np.ndarray          # (m, Q, 3) bounds in force
    upper: np.ndarray
    events: list = field(default_factory=list)   # (t_flight, quantity index, old, new)
    cusum: np.ndarray | None = None    # (m, Q, 3) signed CUSUM statistic (sequential detector)

    def __len__(self) -> int:
        return int(self.index.size)


class VoterCore:
    """The voter on a stream of matched triples (see the module docstring).

    ``push(stamp_ns (n,), P (n, 6, 3))`` -> :class:`Decisions` of the samples that became
    decidable (alignment delays them by the largest time offset; none in the learning phase).
    ``finish()`` ends a recording shorter than the learning phase (it still estimates the time
    offsets and decides); the last samples held back by the alignment delay stay undecided."""

    def __init__(self, table: ThresholdTable, confirm: int = 1, release_after_windows: int = 3,
                 sticky: bool = True, time_offsets_s: Sequence[float] | None = None,
                 model: VoterModel | None = None) -> None:
        self.table = table
        self.model = model if model is not None else VoterModel.from_table(table)
        self.rate_hz = float(table.rate_hz)
        self.window = int(table.window)
        self.qi = np.array([QUANTITIES.index(q) for q in table.quantities])
        Q = len(self.qi)
        tau = time_offsets_s if time_offsets_s is not None else self.model.time_offsets_s
        if tau is not None and (len(tau) != 3 or tau[0] != 0):
            raise CoreError(f"time offsets must be [0, tau2, tau3], got {list(tau)!r}")
        self.tau: np.ndarray | None = None if tau is None else np.asarray(tau, dtype=float)
        self.tau_peak: np.ndarray | None = None
        self.persistence = Persistence(Q, confirm, release_after_windows * self.window, sticky)
        self.t0_ns: int | None = None
        self._raw_t = np.zeros(0)
        self._raw_P = np.zeros((0, 6, 3))
        self._raw_base = 0          # absolute sample index of _raw_P[0]
        self._count = 0             # triples received
        self._next = 0              # next sample index to align
        self._started = False
        self._d_tail = np.zeros((0, Q, 3))
        self._s_tail = np.zeros((0, Q, 3))
        self.offset: np.ndarray | None = None
        self._b_sum: np.ndarray | None = None      # step detector baseline (sum, count)
        self._b_count = np.zeros(0)
        self._healthy = np.ones(0, dtype=bool)
        self._n_learn = 0
        self._w_prev: np.ndarray | None = None      # mean rate before the batch (linear model)
        self.decisions = 0
        self.cusum = (voter_sequential.Cusum(self.model.sequential, table.quantities,
                                             self.rate_hz) if self.model.sequential else None)

    # ------------------------------------------------------------------ input
    def push(self, stamp_ns: Any, P: Any) -> Decisions:
        stamp_ns = np.asarray(stamp_ns, dtype=np.int64).reshape(-1)
        P = np.asarray(P, dtype=float).reshape(-1, 6, 3)
        if stamp_ns.size != P.shape[0]:
            raise CoreError("push: stamps and triples differ in number")
        if stamp_ns.size and self.t0_ns is None:
            self.t0_ns = int(stamp_ns[0])
        t = (stamp_ns - (self.t0_ns or 0)) * 1e-9
        self._raw_t = np.concatenate([self._raw_t, t])
        self._raw_P = np.concatenate([self._raw_P, P])
        self._count += stamp_ns.size
        return self._process(final=False)

    def finish(self) -> Decisions:
        return self._process(final=True)

    # ------------------------------------------------------------------ stages
    def _start(self, final: bool) -> bool:
        learn = self.model.learn_s
        if not self._raw_t.size:
            return False
        if learn > 0 and self._raw_t[-1] < learn and not final:
            return False
        if self.tau is None:
            n = int(np.searchsorted(self._raw_t, learn))
            try:
                self.tau, self.tau_peak = estimate_time_offsets(
                    self._raw_P[:n], self.rate_hz, self.model.max_lag_s, self.model.prefilter)
            except CoreError:
                self.tau, self.tau_peak = np.zeros(3), np.zeros(3)   # too short: no estimate
        self._started = True
        return True

    def _aligned(self, end: int) -> np.ndarray:
        """Triples _next .. end-1 aligned in time and mounting (absolute indices)."""
        idx = np.arange(self._next, end)
        local = idx - self._raw_base
        out = self._raw_P[local].copy()
        for k in (1, 2):
            s = float(self.tau[k]) * self.rate_hz
            if s:
                out[:, :, k] = delay(self._raw_P[:, :, k], s, local)
        return correct_mounting(out, self.model.mounting)

    def _process(self, final: bool) -> Decisions:
        if not self._started and not self._start(final):
            return self._empty()
        # a sample is decided once IMU2's and IMU3's samples of its instant have arrived; at
        # the end of a recording the last ones never do (not decided: extrapolating them would
        # compare different instants)
        lag = float(np.max(self.tau)) * self.rate_hz
        end = self._count - int(math.ceil(max(0.0, lag) - 1e-9))
        if end <= self._next:
            return self._empty()
        A = self._aligned(end)
        d = voter_linear.pair_diffs(A[:, self.qi, :])
        if self.model.linear:
            Phi = voter_linear.features(A, self.rate_hz, self._w_prev)
            self._w_prev = A[-1, 0:3, :].mean(axis=-1)
            d = voter_linear.apply(d, Phi, self.model.linear["coef"], self.table.quantities)
        M, N = self.model.prefilter, self.window
        pf = _tail_means(self._d_tail, d, M) if M > 1 else d
        idx = np.arange(self._next, end)
        t = self._raw_t[idx - self._raw_base]
        self._d_tail = np.concatenate([self._d_tail, d])[-(M - 1):] if M > 1 else self._d_tail
        if self.model.baseline == "grow":
            return self._decide_step(idx, t, pf, end)
        stat = _tail_means(self._s_tail, pf, N)
        keep = t >= self.model.learn_s - 1e-9 if self.model.learn_s > 0 else np.ones(t.size, bool)
        if self.offset is None and self.model.offset_blocks > 1 and np.any(keep) \
                and self.model.learn_s > 0:
            j0 = int(np.argmax(keep))
            self.offset = block_median(np.concatenate([self._s_tail, pf[:j0 + 1]])[-N:],
                                       self.model.offset_blocks)
        self._s_tail = np.concatenate([self._s_tail, pf])[-(N - 1):] if N > 1 else self._s_tail
        self._next = end
        self._trim()
        return self._decide(idx[keep], t[keep], stat[keep], pf[keep])

    def _trim(self) -> None:
        """Drop raw triples no later interpolation needs."""
        lo = min(0.0, float(np.min(self.tau)) * self.rate_hz)
        first = max(0, self._next - int(math.ceil(-lo)) - 2)
        cut = first - self._raw_base
        if cut > 1024:
            self._raw_t, self._raw_P = self._raw_t[cut:], self._raw_P[cut:]
            self._raw_base = first

    def _deviation(self, stat: np.ndarray) -> np.ndarray:
        if self.offset is None:
            self.offset = stat[0].copy() if self.model.learn_s > 0 else np.zeros(stat.shape[1:])
        return stat - self.offset

    def _decide(self, idx: np.ndarray, t: np.ndarray, stat: np.ndarray, pf: np.ndarray
                ) -> Decisions:
        if not idx.size:
            return self._empty()
        lo, up = self.table.bounds_at(t)
        if self.model.track_tau_s > 0:
            return self._decide_tracking(idx, t, stat, lo, up)
        dev = self._deviation(stat)
        eps = (dev >= lo) & (dev <= up)
        g = None
        if self.cusum is not None:      # the sequential detector on the sample residual
            g, ok = self.cusum.step(pf - self.offset)
            eps &= ok
        status, faulty, _ = vote_array(eps)
        isolated, events = self._persist(t, status, faulty)
        self.decisions += idx.size
        return Decisions(idx, t, dev, eps, status, faulty, isolated, lo, up, events, g)

    def _decide_step(self, idx: np.ndarray, t: np.ndarray, pf: np.ndarray, end: int
                     ) -> Decisions:
        """The step detector (baseline "grow", :func:`voter_kernel.step_deviation`)."""
        m, Q = pf.shape[0], pf.shape[1]
        if self._b_sum is None:
            n_learn = int(np.searchsorted(self._raw_t, self.model.learn_s - 1e-9))
            self._n_learn = n_learn
            self._b_sum, self._b_count = np.zeros(Q * 3), np.zeros(Q * 3)
            self._healthy = np.ones(Q, dtype=bool)
        lo, up = self.table.bounds_at(t)
        flat = np.ascontiguousarray(pf.reshape(m, -1))
        dev, inside = step_deviation(
            np.ascontiguousarray(self._s_tail.reshape(self._s_tail.shape[0], Q * 3)), flat,
            int(idx[0]), self.window, self._n_learn,
            np.ascontiguousarray(lo.reshape(m, -1), dtype=float),
            np.ascontiguousarray(up.reshape(m, -1), dtype=float),
            np.repeat(np.arange(Q), 3), self._b_sum, self._b_count, self._healthy)
        self._s_tail = np.concatenate([self._s_tail, pf])[-self.window:]
        self._next = end
        self._trim()
        keep = idx >= self._n_learn
        if not np.any(keep):
            return self._empty()
        dev, eps = dev.reshape(m, Q, 3)[keep], inside.reshape(m, Q, 3)[keep]
        idx, t, lo, up = idx[keep], t[keep], lo[keep], up[keep]
        status, faulty, _ = vote_array(eps)
        isolated, events = self._persist(t, status, faulty)
        self.decisions += idx.size
        self.offset = (self._b_sum / np.maximum(self._b_count, 1)).reshape(Q, 3)
        return Decisions(idx, t, dev, eps, status, faulty, isolated, lo, up, events)

    def _decide_tracking(self, idx, t, stat, lo, up) -> Decisions:
        """Decisions with the slow offset filter (sequential: it freezes on non-healthy votes)."""
        if self.offset is None:
            self._deviation(stat)
        a = min(1.0, 1.0 / (self.track_samples()))
        dev = np.empty_like(stat)
        eps = np.empty(stat.shape, dtype=bool)
        status = np.empty(stat.shape[:2], dtype=np.int8)
        faulty = np.empty_like(status)
        for i in range(idx.size):
            dev[i] = stat[i] - self.offset
            eps[i] = (dev[i] >= lo[i]) & (dev[i] <= up[i])
            s, f, _ = vote_array(eps[i])
            status[i], faulty[i] = s, f
            ok = (s == HEALTHY)[:, None]
            self.offset = np.where(ok, self.offset + a * dev[i], self.offset)
        isolated, events = self._persist(t, status, faulty)
        self.decisions += idx.size
        return Decisions(idx, t, dev, eps, status, faulty, isolated, lo, up, events)

    def track_samples(self) -> float:
        return self.model.track_tau_s * self.rate_hz

    def _persist(self, t: np.ndarray, status: np.ndarray, faulty: np.ndarray):
        isolated, changes = self.persistence.update_batch(status, faulty)
        return isolated, [(float(t[r]), q, old, new) for r, q, old, new in changes]

    def _empty(self) -> Decisions:
        Q = len(self.qi)
        z3 = np.zeros((0, Q, 3))
        z = np.zeros((0, Q), dtype=np.int8)
        return Decisions(np.zeros(0, np.int64), np.zeros(0), z3, z3.astype(bool), z, z, z,
                         z3, z3, cusum=None if self.cusum is None else z3)
