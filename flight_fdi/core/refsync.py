"""Synchronisation of the INS and one or several reference streams into filter updates.

The filter node receives the INS velocity and i reference velocities as separate streams whose
messages arrive in any interleaving. :class:`ReferenceSync` turns them into a sequence of
updates, each at one stamp, with the INS velocity interpolated at every row's own stamp
(:class:`~flight_fdi.core.align.StreamingAligner`). The rules (SPEC seed 001, filter node
"Redundant references"):

* a reference sample joins the waiting update within ``tolerance_s`` of its stamp that has no
  sample of this reference yet (the nearest one), or opens a new update; updates are kept in
  stamp order and never reordered once processed;
* an update is *closed* when every reference is present, or some reference is more than
  ``wait_s`` (of stamps) ahead of it, or every missing reference has either never sent a sample,
  or its last sample is more than ``wait_s`` behind (dead or lagging) or past the update's
  stamp by more than ``tolerance_s``;
* a closed update is released once the INS has a sample at or after its latest row stamp (the
  INS may simply be delivered later than the references); a row whose INS value cannot be
  interpolated (a gap wider than ``max_gap_s``, a stamp older than the INS buffer) is dropped;
* a reference sample whose stamp is at or before the last released update is *late* (dropped,
  an update is never redone); an update waiting more than ``buffer_s`` behind the newest
  reference stamp will not get its INS data (dropped: ``ins_timeout``);
* a time jump (decided by the caller's :class:`~flight_fdi.core.timeline.StampLine`) clears what
  is waiting on the old time line.

With one reference, ``tolerance_s`` is 0: every sample is its own update.

Drops are reported through ``on_drop(reason, detail, n)`` (the node counts them as
``dropped_<reason>`` and logs the detail); no rclpy, no logging here.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from .align import StreamingAligner

__all__ = ["Epoch", "ReferenceSync", "Row", "Update"]


class Epoch:
    """Reference samples waiting to be fused as one update at stamp ``t``:
    ``samples[reference index] = (stamp, velocity (3,), variance (3,))``."""

    __slots__ = ("t", "samples")

    def __init__(self, t: float) -> None:
        self.t = t
        self.samples: dict[int, tuple[float, Any, Any]] = {}

    @property
    def latest(self) -> float:
        return max(s[0] for s in self.samples.values())


#: one row of an update: (reference index, INS velocity at its stamp, reference velocity,
#: reference variance)
Row = tuple


@dataclass
class Update:
    """One filter update at stamp ``t``: its rows (reference index order) and the indices of
    the references absent from it."""

    t: float
    rows: list = field(default_factory=list)
    missing: list[int] = field(default_factory=list)


def _no_drop(reason: str, detail: str, n: int) -> None:
    pass


class ReferenceSync:
    """Groups reference samples into updates and pairs them with the interpolated INS velocity
    (module docstring). ``n_refs`` references, indexed 0..n_refs-1."""

    def __init__(self, n_refs: int, tolerance_s: float = 0.0, wait_s: float = 0.5,
                 max_gap_s: float = 0.5, buffer_s: float = 2.0,
                 on_drop: Callable[[str, str, int], None] | None = None) -> None:
        self.n_refs = int(n_refs)
        self.tolerance_s = float(tolerance_s) if self.n_refs > 1 else 0.0
        self.wait_s = float(wait_s)
        self.max_gap_s = float(max_gap_s)
        self.buffer_s = float(buffer_s)
        self.on_drop = on_drop or _no_drop
        self.pending: deque[Epoch] = deque()
        self.ref_last_t: list[float | None] = [None] * self.n_refs  # last sample per reference
        self.last_ref_t: float | None = None     # newest reference stamp (any reference)
        self.last_epoch_t: float | None = None   # stamp of the last update released
        self.last_ins_t: float | None = None
        self.aligner = self._new_aligner()

    def _new_aligner(self) -> StreamingAligner:
        return StreamingAligner(max_gap_s=self.max_gap_s, buffer_s=self.buffer_s)

    @property
    def waiting(self) -> int:
        """Reference samples waiting in open or unreleased updates."""
        return sum(len(e.samples) for e in self.pending)

    # ------------------------------------------------------------------ input
    def add_ins(self, t: float, v: Any) -> list[Update]:
        """An INS sample (CoreError from the aligner propagates: nothing changes); returns the
        updates it releases."""
        self.aligner.add_ins(t, v)
        self.last_ins_t = t
        return self.drain()

    def add_reference(self, k: int, t: float, v: Any, var: Any) -> list[Update] | None:
        """A reference sample of reference ``k``; returns the updates released, or None when
        the sample is late (its stamp was already processed: the caller counts it)."""
        self.ref_last_t[k] = t
        if self.last_ref_t is None or t > self.last_ref_t:
            self.last_ref_t = t
        if self.last_epoch_t is not None and t <= self.last_epoch_t:
            return None
        self._insert(k, t, v, var)
        # an update that waited longer than the INS buffer for its INS data will not get it
        newest = self.last_ref_t
        while self.pending and self.pending[0].t < newest - self.buffer_s:
            old = self.pending.popleft()
            self.on_drop("ins_timeout", f"reference sample at t={old.t:.3f} s: no INS data "
                         f"after it within {self.buffer_s} s", len(old.samples))
        return self.drain()

    def _insert(self, k: int, t: float, v: Any, var: Any) -> None:
        """Put a sample into the nearest waiting update within the tolerance that has no sample
        of reference ``k`` yet, or into a new update, in stamp order."""
        tol = self.tolerance_s
        best = None
        for e in self.pending:
            if k not in e.samples and abs(e.t - t) <= tol and \
                    (best is None or abs(e.t - t) < abs(best.t - t)):
                best = e
        if best is None:
            best = Epoch(t)
            pos = len(self.pending)
            while pos > 0 and self.pending[pos - 1].t > t:
                pos -= 1
            self.pending.insert(pos, best)
        best.samples[k] = (t, v, var)

    def closed(self, e: Epoch) -> bool:
        """The update at ``e.t`` waits for no more references (module docstring)."""
        if len(e.samples) == self.n_refs:
            return True
        tol, wait = self.tolerance_s, self.wait_s
        if self.last_ref_t is not None and self.last_ref_t > e.t + wait:
            return True
        for k, last in enumerate(self.ref_last_t):
            if k in e.samples:
                continue
            if last is None or e.t - wait <= last <= e.t + tol:
                return False  # may still come
        return True

    # ------------------------------------------------------------------ output
    def drain(self) -> list[Update]:
        """The updates that are closed and whose INS values are available, in stamp order."""
        out: list[Update] = []
        while self.pending:
            e = self.pending[0]
            if not self.closed(e):
                break
            newest = self.aligner.newest_t
            if newest is None or e.latest > newest:
                # wait for the INS sample after t, even when t is more than max_gap_s ahead of
                # the newest one: INS messages may simply be delivered later than references
                # (a real INS dropout ends as a "gap", or the sample expires after buffer_s)
                break
            self.pending.popleft()
            self.last_epoch_t = e.t
            update = Update(e.t)
            for k in sorted(e.samples):
                t_k, v_ref, var = e.samples[k]
                v_ins = self.aligner.at(t_k)
                if v_ins is None:
                    reason = self.aligner.last_reason
                    self.on_drop(f"ins_{reason}", f"reference sample at t={t_k:.3f} s: no INS "
                                 f"value ({reason}; max_gap_s {self.max_gap_s} s, buffer_s "
                                 f"{self.buffer_s} s)", 1)
                    continue
                update.rows.append((k, np.asarray(v_ins, dtype=float).reshape(-1), v_ref, var))
            if update.rows:
                present = {r[0] for r in update.rows}
                update.missing = [k for k in range(self.n_refs) if k not in present]
                out.append(update)
        return out

    # ------------------------------------------------------------------ time jumps
    def ins_time_jump(self, t: float, reset_s: float) -> None:
        """The INS stamps jumped to ``t`` (confirmed): a new INS buffer; updates waiting beyond
        ``t + reset_s`` (on the old time line) are dropped (``time_jump``)."""
        self.aligner = self._new_aligner()
        self.last_ins_t = None
        limit = t + reset_s
        keep = deque(e for e in self.pending if e.t <= limit)
        stale = self.waiting - sum(len(e.samples) for e in keep)
        if stale:
            self.pending = keep
            self.on_drop("time_jump", f"{stale} reference samples waiting across a time jump",
                         stale)

    def reference_time_jump(self, t: float, reset_s: float) -> None:
        """The reference stamps jumped to ``t`` (confirmed): everything waiting is dropped
        (``time_jump``), every reference starts on the new line, and the INS buffer is renewed
        when it is still on the old one (newer than ``t + reset_s``)."""
        waiting = self.waiting
        if waiting:
            self.on_drop("time_jump", f"{waiting} reference samples waiting across a time jump",
                         waiting)
            self.pending.clear()
        self.ref_last_t = [None] * self.n_refs
        self.last_ref_t = None
        self.last_epoch_t = None
        if self.last_ins_t is not None and self.last_ins_t > t + reset_s:
            self.aligner = self._new_aligner()
            self.last_ins_t = None
