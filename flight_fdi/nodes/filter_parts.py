"""The per-channel, per-reference and per-update state of filter_node (INS velocity mode)."""
from __future__ import annotations

from typing import Any

from ..core.kalman import GateConfig, KalmanFilter
from ..core.models import LinearModel
from ..core.references import ReferenceConfig, RedundantFilter
from ..core.timeline import StampLine
from . import convert
from . import diagnostics as diag


class Channel:
    """One axis: its filter, the stamp of its last step, its counts and last result.

    With redundant references ``rf`` is the core RedundantFilter (its ``kf`` is ``self.kf``);
    with one reference ``rf`` is None and the plain KalmanFilter steps on its own."""

    def __init__(self, name: str, column: int, model: LinearModel, gate: GateConfig,
                 ref_names: list[str] | None = None,
                 ref_config: ReferenceConfig | None = None) -> None:
        self.name = name
        self.axis = convert.AXIS_INDEX[name]
        self.column = column  # index in the INS vector given to the aligner
        if ref_names is None:
            self.rf = None
            self.kf = KalmanFilter(model, gate)
        else:
            self.rf = RedundantFilter(model, ref_names, gate, ref_config)
            self.kf = self.rf.kf
        self.last_t: float | None = None
        self.last_step_clock: float | None = None
        self.counters = diag.Counters(("fused", "gated", "rejected", "covariance_invalid",
                                       "alarms_raised", "resets"))
        self.result = None
        self.rows_used: int | None = None
        self.alarm_since: float | None = None
        self.last_reset: tuple[float, str] | None = None  # (wall time, reason) of the last reset

    def reset(self) -> None:
        if self.rf is None:
            self.kf.reset()
        else:
            self.rf.reset()  # the filter and the health of every reference
        self.last_t = None
        self.alarm_since = None


class Reference:
    """One reference input: its resolved topic name, its time line and its counts."""

    def __init__(self, index: int, name: str) -> None:
        self.index = index
        self.name = name
        self.line: StampLine | None = None  # its time line (set by the node)
        self.counters = diag.Counters(("samples", "missing", "dropped_late"))


def count_step(ch: Any, t: float, res: Any, now: float) -> None:
    """Note a filter step of channel ``ch`` (a Channel or the attitude mode's AxisChannel) at
    stamp ``t`` and node time ``now``: its result and the fused / gated / rejected counts."""
    ch.last_t = t
    ch.last_step_clock = now
    ch.result = res
    if res.fused:
        ch.counters.inc("fused")
    if res.exceeded:
        ch.counters.inc("gated")
        if not res.fused:
            ch.counters.inc("rejected")


def reference_topics(values: dict[str, Any]) -> list[str]:
    """The reference topics: ``reference_topics`` without its empty entries, or else
    ``[reference_topic]``."""
    named = [t for t in values["reference_topics"] if t]
    return named if named else [values["reference_topic"]]
