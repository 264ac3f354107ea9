"""The beta^2 gate and the M-of-N alarm of the forward filter (SPEC section 2).

Gate: ``beta2 = nu^T S^-1 nu`` is chi-square with m degrees of freedom on a healthy system. A sample
*exceeds* the gate when ``beta2 > threshold(m)``; an *alarm* is raised when M of the last N
updates exceeded and cleared when fewer than M of the last N did (:class:`AlarmLogic`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from .errors import CoreError
from .special import chi2_isf

# alarm states, as in msg_defs/msg/Innovation.msg
ALARM_CLEAR = 0
ALARM_RAISED = 1
ALARM_ACTIVE = 2
ALARM_CLEARED = 3

GATE_RULES = ("chi2", "seed")
GATE_ACTIONS = ("flag", "reject")


def is_int(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


@lru_cache(maxsize=256)
def _gate_threshold(rule: str, probability: float, m: int) -> float:
    if rule == "seed":
        return m + 3.0 * math.sqrt(2.0 * m)
    # the chi2(m) upper quantile chi2.isf(p, m), accurate for tiny p (core/special: no SciPy)
    return chi2_isf(probability, m)


@dataclass(frozen=True)
class GateConfig:
    """The beta^2 gate and the persistence rule of the alarm.

    rule: ``"chi2"`` -- the chi-square(m) quantile with per-sample false-alarm ``probability``;
          ``"seed"`` -- the seed's 3-sigma rule m + 3 sqrt(2m) (``probability`` is then unused).
    alarm_m, alarm_n: an alarm is raised when ``alarm_m`` of the last ``alarm_n`` updates exceeded
          the gate, and cleared when fewer than ``alarm_m`` of the last ``alarm_n`` did.
    action: ``"flag"`` -- fuse a gated sample anyway (post-flight analysis then sees the fault);
            ``"reject"`` -- do not fuse a gated sample.
    """

    rule: str = "chi2"
    probability: float = 1e-3
    alarm_m: int = 3
    alarm_n: int = 5
    action: str = "flag"

    def __post_init__(self) -> None:
        if self.rule not in GATE_RULES:
            raise CoreError(f"GateConfig.rule must be one of {GATE_RULES}, got {self.rule!r}")
        p = self.probability
        if (isinstance(p, (bool, np.bool_)) or not isinstance(p, (int, float, np.floating))
                or not math.isfinite(p) or not 0.0 < p < 1.0):
            raise CoreError(f"GateConfig.probability must be a number in (0, 1), got {p!r}")
        if not is_int(self.alarm_m) or self.alarm_m < 1:
            raise CoreError(f"GateConfig.alarm_m must be an integer >= 1, got {self.alarm_m!r}")
        if not is_int(self.alarm_n) or self.alarm_n < self.alarm_m:
            raise CoreError(f"GateConfig.alarm_n must be an integer >= alarm_m ({self.alarm_m}), "
                            f"got {self.alarm_n!r}")
        if self.action not in GATE_ACTIONS:
            raise CoreError(f"GateConfig.action must be one of {GATE_ACTIONS}, got {self.action!r}")
        object.__setattr__(self, "probability", float(p))
        object.__setattr__(self, "alarm_m", int(self.alarm_m))
        object.__setattr__(self, "alarm_n", int(self.alarm_n))

    def threshold(self, m: int) -> float:
        """Gate threshold on beta^2 for an m-row measurement."""
        if not is_int(m) or m < 1:
            raise CoreError(f"GateConfig.threshold: m must be an integer >= 1, got {m!r}")
        return _gate_threshold(self.rule, self.probability, int(m))


class AlarmLogic:
    """M-of-N persistence: ``push(exceeded)`` returns the alarm state of that update."""

    def __init__(self, m_of: int, n_of: int) -> None:
        self.m_of = int(m_of)
        self.n_of = int(n_of)
        self.reset()

    def reset(self) -> None:
        self._window = [False] * self.n_of
        self._pos = 0
        self._count = 0
        self.active = False

    def push(self, exceeded: bool) -> int:
        exceeded = bool(exceeded)
        self._count += exceeded - self._window[self._pos]
        self._window[self._pos] = exceeded
        self._pos = (self._pos + 1) % self.n_of
        if self.active:
            if self._count < self.m_of:
                self.active = False
                return ALARM_CLEARED
            return ALARM_ACTIVE
        if self._count >= self.m_of:
            self.active = True
            return ALARM_RAISED
        return ALARM_CLEAR


def alarm_states(exceeded: np.ndarray, gate: GateConfig) -> np.ndarray:
    """Alarm state of every update of a record, from its gate exceedances (vectorised).

    The rule of :class:`AlarmLogic` is memoryless in the window count: the alarm is active after
    update k exactly when at least M of the last N updates exceeded, so the states follow from a
    moving sum and its change.
    """
    e = np.asarray(exceeded, dtype=np.int64).reshape(-1)
    c = np.cumsum(e)
    count = c.copy()
    count[gate.alarm_n:] -= c[:-gate.alarm_n]
    active = count >= gate.alarm_m
    prev = np.concatenate(([False], active[:-1]))
    state = np.full(e.size, ALARM_CLEAR, dtype=np.uint8)
    state[active & ~prev] = ALARM_RAISED
    state[active & prev] = ALARM_ACTIVE
    state[~active & prev] = ALARM_CLEARED
    return state

