"""The time line of one stamped input stream: one wild stamp is an outlier, not a new time line.

A stream's header stamps normally increase. What the filter node must tell apart:

* a **duplicate** (the same stamp again) and a sample slightly **out of order** (at most
  ``jump_s`` older than the last one): dropped;
* an **isolated wild stamp** (a stamp of 0 from a driver that lost its time source, a bit flip):
  it jumps back by more than ``jump_s`` -- or forward by more than ``forward_jump_s`` -- and the
  next sample continues the old time line. It is an **outlier**: dropped and counted, the filter
  is not touched;
* a **new time line** (a bag replayed in a loop, a clock reset): the jump persists -- ``confirm``
  samples in a row continue the new line (each advancing by less than ``jump_s``). Only then is
  the new line adopted (the filter resets), and the samples held while it was a candidate are
  released in order, so a real reset loses nothing.

While a candidate line is pending, a sample that continues the old line dismisses the candidate
(its held samples become outliers); a sample that fits neither starts a new candidate (the old
candidate's samples become outliers). ``confirm = 1`` adopts a new line at the first jumped
sample (the behaviour before outliers were recognised).

Pure logic (no ROS): :class:`StampLine` decides, the caller keeps the payloads it hands in and
gets back. Times are float seconds.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from .errors import CoreError

__all__ = ["StampLine", "Verdict", "ACCEPT", "DUPLICATE", "OUT_OF_ORDER", "HELD", "OUTLIER",
           "NEW_LINE"]

ACCEPT = "accept"              # on the time line: use the sample
DUPLICATE = "duplicate"        # the last accepted stamp again: drop
OUT_OF_ORDER = "out_of_order"  # older than the last accepted stamp by at most jump_s: drop
HELD = "held"                  # starts or continues a candidate new line: kept by the StampLine
OUTLIER = "outlier"            # repeats the candidate's last stamp: drop (counted as outlier)
NEW_LINE = "new_line"          # the candidate is confirmed: reset, then use ``released``


@dataclass
class Verdict:
    """What to do with the sample just checked (``kind``), and with earlier ones:
    ``dismissed`` -- payloads of held samples now known to be outliers (drop and count);
    ``released`` -- on NEW_LINE, the payloads of the new line in order (the current one last);
    ``jump`` -- on NEW_LINE, (last stamp of the old line, first stamp of the new one)."""

    kind: str
    dismissed: list = field(default_factory=list)
    released: list = field(default_factory=list)
    jump: tuple[float, float] | None = None


_ACCEPTED = Verdict(ACCEPT)  # shared: callers only read verdicts


class StampLine:
    """The time line of one stream (see the module docstring).

    ``StampLine(jump_s, confirm=3, forward_jump_s=inf)``; ``check(t, payload)`` -> Verdict;
    ``last`` (last accepted stamp, None before the first), ``pending`` (samples held),
    ``reset()`` forgets everything (held samples are returned).
    """

    def __init__(self, jump_s: float, confirm: int = 3, forward_jump_s: float = math.inf) -> None:
        if not (isinstance(jump_s, (int, float)) and math.isfinite(jump_s) and jump_s > 0):
            raise CoreError(f"StampLine: jump_s must be a finite number > 0, got {jump_s!r}")
        if isinstance(confirm, bool) or not isinstance(confirm, int) or confirm < 1:
            raise CoreError(f"StampLine: confirm must be an integer >= 1, got {confirm!r}")
        if not (isinstance(forward_jump_s, (int, float)) and forward_jump_s > 0):
            raise CoreError(f"StampLine: forward_jump_s must be > 0, got {forward_jump_s!r}")
        self.jump_s = float(jump_s)
        self.confirm = confirm
        self.forward_jump_s = float(forward_jump_s)
        self.last: float | None = None
        self._held: list[tuple[float, Any]] = []

    @property
    def pending(self) -> int:
        return len(self._held)

    def reset(self) -> list:
        """Forget the time line; returns the payloads that were held (the caller drops them)."""
        held = [p for _, p in self._held]
        self._held = []
        self.last = None
        return held

    def _on_line(self, t: float) -> str | None:
        """ACCEPT / DUPLICATE / OUT_OF_ORDER when ``t`` belongs to the current line, else None."""
        last = self.last
        if last is None:
            return ACCEPT
        if t > last:
            return ACCEPT if t - last <= self.forward_jump_s else None
        if t == last:
            return DUPLICATE
        return OUT_OF_ORDER if last - t <= self.jump_s else None

    def check(self, t: float, payload: Any = None) -> Verdict:
        last = self.last
        if not self._held and last is not None and last < t <= last + self.forward_jump_s:
            self.last = t  # the common case, without allocating a Verdict
            return _ACCEPTED
        kind = self._on_line(t)
        if kind is not None:
            dismissed = [p for _, p in self._held]
            self._held = []
            if kind == ACCEPT:
                self.last = t
            return Verdict(kind, dismissed=dismissed)
        # a jump away from the line: a candidate new line, or its continuation
        dismissed: list = []
        if self._held:
            t_c = self._held[-1][0]
            if t == t_c:
                return Verdict(OUTLIER)
            if not (t_c < t <= t_c + self.jump_s):  # fits neither line: a new candidate
                dismissed = [p for _, p in self._held]
                self._held = []
        self._held.append((t, payload))
        if len(self._held) < self.confirm:
            return Verdict(HELD, dismissed=dismissed)
        released = [p for _, p in self._held]
        jump = (self.last, self._held[0][0])
        self._held = []
        self.last = t
        return Verdict(NEW_LINE, dismissed=dismissed, released=released, jump=jump)
