"""Reading one flight (INS channel, references, simulator truth) from a bag, no rclpy.

``read_flight`` extracts one INS channel and its reference from a recorded or simulated flight,
fast (the velocity messages are decoded straight from their CDR bytes, see ``cdr``; the raw
messages come from the one reader, :func:`flight_fdi.bagio.reader.read_raw`), and reports every
message it had to drop and why.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from . import cdr
from .errors import BagError
from .inputs import (SUPPORTED_TYPES, InputSpec, Series, clean_series, decode_topic,
                     merge_references)
from .reader import RawSeries, open_bag, read_raw, reason, topic_list

INS_TOPIC = "/ins/velocity"
REF_TOPIC = "/reference/velocity"
TRUTH_TOPIC = "/sim/truth"
FAULT_TOPIC = "/sim/fault"
FILTER_STATE = cdr.FILTER_STATE
STRING = cdr.STRING

#: twist column and covariance index of each channel's linear velocity
CHANNELS = {"x": (0, 0), "y": (1, 7), "z": (2, 14)}

PROBLEM_KEYS = ("ins_nonfinite_velocity", "ins_duplicate_stamp", "ins_out_of_order_stamp",
                "ref_nonfinite_velocity", "ref_duplicate_stamp", "ref_out_of_order_stamp",
                "ref_invalid_covariance")


@dataclass
class FlightData:
    """One INS channel, its reference and (for simulated flights) the truth, read from a bag.

    Times are header stamps in seconds since the Unix epoch (float64). Absolute float seconds
    keep only ~0.2 us resolution; use ``ins_rel_s`` / ``ref_rel_s`` (computed from the exact
    integer nanoseconds) for sample intervals.
    """

    path: str
    channel: str
    t_ins: np.ndarray                 # (N,) s
    v_ins: np.ndarray                 # (N,) m/s, twist.linear.<channel>
    t_ref: np.ndarray                 # (M,) s
    v_ref: np.ndarray                 # (M,) m/s
    r_ref: np.ndarray                 # (M,) m^2/s^2 variance of the channel, NaN when invalid
    t0: float                         # s, stamp of the first INS/reference message kept
    stamp_ins_ns: np.ndarray          # (N,) int64 exact header stamps
    stamp_ref_ns: np.ndarray          # (M,) int64
    t0_ns: int
    problems: dict[str, int] = field(default_factory=dict)
    t_truth: np.ndarray | None = None         # (K,) s
    x_truth: np.ndarray | None = None         # (K, n) true error state
    truth_state_names: tuple[str, ...] | None = None
    #: the simulator's description of the flight and its injected faults (see flight_fdi.sim),
    #: None when the bag has no /sim/fault message
    fault: dict | None = None
    topics: dict[str, str] = field(default_factory=dict)  # topic -> message type in the bag
    spec: InputSpec | None = None     # the input contract it was read with
    series: list = field(default_factory=list)  # [INS Series, reference Series...]

    def input_section(self, aligned: np.ndarray) -> dict:
        """``input`` of the result (flight_fdi.bagio.inputs.input_section); ``aligned``: which
        reference samples the analysis used (AnalysisResult.aligned)."""
        from .inputs import input_section

        return input_section(self.series[0], self.series[1:], self.stamp_ins_ns,
                             self.stamp_ref_ns, np.asarray(aligned, dtype=bool))

    @property
    def ins_rel_s(self) -> np.ndarray:
        """INS stamps in seconds since ``t0`` (exact to the nanosecond)."""
        return (self.stamp_ins_ns - self.t0_ns) * 1e-9

    @property
    def ref_rel_s(self) -> np.ndarray:
        return (self.stamp_ref_ns - self.t0_ns) * 1e-9

    @property
    def faults(self) -> list[dict]:
        """The injected faults (empty for a nominal or a recorded flight)."""
        return list((self.fault or {}).get("faults", []))

    def problem_summary(self) -> str:
        """One line naming the non-zero problem counts ("" when there were none)."""
        return ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in self.problems.items() if v)


def read_flight(path: str | Path, channel: str = "x", ins_topic: str = INS_TOPIC,
                ref_topic: str | Sequence[str] = REF_TOPIC, truth_topic: str = TRUTH_TOPIC,
                fault_topic: str = FAULT_TOPIC, with_truth: bool = True,
                spec: InputSpec | None = None) -> FlightData:
    """Read one INS channel, its reference velocity and (if present) the simulator's truth.

    ``spec`` (:class:`~flight_fdi.bagio.inputs.InputSpec`) names the topics, the channel, the
    navigation frame and the Odometry twist frame; without it ``channel``, ``ins_topic`` and
    ``ref_topic`` (one topic or several) build one. Either input may be TwistStamped,
    TwistWithCovarianceStamped or Odometry (see :mod:`.inputs`); several references are merged.
    A reference whose variance is not finite or <= 0 (or that has none) is kept with
    r_ref = NaN (the model's R). Unused messages are counted per topic and reason
    (``series``; legacy totals in ``problems``: ``PROBLEM_KEYS``). Header stamps are sorted
    when merely shuffled (:func:`~flight_fdi.bagio.inputs.clean_series`). Any topic missing,
    of an unsupported type or without a usable sample: BagError, one line.
    """
    if spec is None:
        spec = InputSpec(ins_topic=ins_topic, reference_topics=(
            (ref_topic,) if isinstance(ref_topic, str) else tuple(ref_topic)), channel=channel)
    channel = spec.component
    p = Path(path)
    reader = open_bag(p)
    try:
        topics = {c.topic: c.msgtype for c in reader.connections}
        counts: dict[str, int] = {}
        for c in reader.connections:
            counts[c.topic] = counts.get(c.topic, 0) + c.msgcount
        for topic in (spec.ins_topic, *spec.reference_topics):
            _check_topic(p, topic, topics, counts)
        wanted = {spec.ins_topic, *spec.reference_topics}
        has_truth = with_truth and topics.get(truth_topic) == FILTER_STATE
        has_fault = topics.get(fault_topic) == STRING
        if has_truth:
            wanted.add(truth_topic)
        if has_fault:
            wanted.add(fault_topic)
        raw = read_raw(reader, p, wanted)
    finally:
        reader.close()

    def series(topic: str) -> Series:
        what = f"bag '{p}': {topic} message"
        s, v, r, note = decode_topic(topics[topic], raw[topic].payloads, spec, what)
        out = clean_series(topic, topics[topic], s, v, r, spec.reorder_window_s, note)
        if out.stamp.size < (2 if topic == spec.ins_topic else 1):
            reasons = ", ".join(f"{n} {k}" for k, n in out.dropped.items() if n) or "too few"
            raise BagError(f"bag '{p}': {topic}: no usable samples ({out.stamp.size} of "
                           f"{out.messages} messages usable; {reasons})")
        return out

    ins = series(spec.ins_topic)
    refs = [series(t) for t in spec.reference_topics]
    s_ref, v_ref, r_ref = merge_references(refs)
    r_ref = np.where(np.isfinite(r_ref) & (r_ref > 0), r_ref, np.nan)
    s_ins, v_ins = ins.stamp, ins.v
    if s_ref[-1] < s_ins[0] or s_ref[0] > s_ins[-1]:
        raise BagError(f"bag '{p}': no reference sample lies within the INS record "
                       f"({spec.ins_topic}: {s_ins[0] * 1e-9:.3f} .. {s_ins[-1] * 1e-9:.3f} s, "
                       f"references {s_ref[0] * 1e-9:.3f} .. {s_ref[-1] * 1e-9:.3f} s)")
    problems = dict.fromkeys(PROBLEM_KEYS, 0)
    for pre, sr in (("ins", [ins]), ("ref", refs)):
        problems[f"{pre}_nonfinite_velocity"] = sum(x.dropped["non_finite"] for x in sr)
        problems[f"{pre}_duplicate_stamp"] = sum(x.dropped["duplicate_stamp"] for x in sr)
        problems[f"{pre}_out_of_order_stamp"] = sum(x.dropped["out_of_order"] for x in sr)
    problems["ref_invalid_covariance"] = int(sum(
        (~(np.isfinite(x.r) & (x.r > 0))).sum() for x in refs if x.msgtype != cdr.TWIST_STAMPED))
    t0_ns = int(min(s_ins[0], s_ref[0]))
    data = FlightData(
        path=str(p), channel=channel,
        t_ins=s_ins * 1e-9, v_ins=v_ins, t_ref=s_ref * 1e-9, v_ref=v_ref, r_ref=r_ref,
        t0=t0_ns * 1e-9, stamp_ins_ns=s_ins, stamp_ref_ns=s_ref, t0_ns=t0_ns,
        problems=problems, topics=topics, spec=spec, series=[ins, *refs])
    if has_truth:
        _attach_truth(data, raw[truth_topic], channel, p, truth_topic)
    if has_fault:
        _attach_fault(data, raw[fault_topic], p, fault_topic)
    return data


def _check_topic(path: Path, topic: str, topics: dict[str, str], counts: dict[str, int]) -> None:
    if topic not in topics or counts.get(topic, 0) == 0:
        raise BagError(f"bag '{path}': no messages on {topic} (topics: {topic_list(topics)}; "
                       "name the inputs with --ins-topic / --reference-topic or an "
                       "--input-profile)")
    if topics[topic] not in SUPPORTED_TYPES:
        raise BagError(f"bag '{path}': {topic} carries {topics[topic]}, expected one of "
                       f"{', '.join(t.rsplit('/', 1)[-1] for t in SUPPORTED_TYPES)} "
                       "(TwistStamped, TwistWithCovarianceStamped, Odometry)")


def _attach_truth(data: FlightData, raw: RawSeries, channel: str, path: Path, topic: str) -> None:
    stamps, channels, names, xs = cdr.decode_filter_state_x(
        raw.payloads, what=f"bag '{path}': {topic} message")
    pick = [i for i, c in enumerate(channels) if c == channel]
    if not pick:
        return
    first = names[pick[0]]
    for i in pick:
        if names[i] != first or xs[i].size != len(first):
            raise BagError(f"bag '{path}': {topic} message #{i} has states {list(names[i])} "
                           f"({xs[i].size} values), expected {list(first)}")
    data.t_truth = stamps[pick] * 1e-9
    data.x_truth = np.vstack([xs[i] for i in pick])
    data.truth_state_names = first


def _attach_fault(data: FlightData, raw: RawSeries, path: Path, topic: str) -> None:
    if len(raw.payloads) == 0:
        return
    try:
        doc = json.loads(cdr.decode_string(raw.payloads[0], what=f"bag '{path}': {topic}"))
    except BagError:
        raise
    except Exception as exc:
        raise BagError(f"bag '{path}': {topic} is not a JSON fault description: "
                       f"{reason(exc)}") from None
    if not isinstance(doc, dict):
        raise BagError(f"bag '{path}': {topic} is not a JSON object")
    data.fault = doc
