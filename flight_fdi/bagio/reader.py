"""Reading rosbag2 bags (mcap or sqlite3) with rosbags, no rclpy.

``read_flight`` extracts one INS channel and its reference from a recorded or simulated flight,
fast (the velocity messages are decoded straight from their CDR bytes, see ``cdr``), and reports
every message it had to drop and why. ``read_messages`` iterates any bag with the project's
message types registered.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator, Sequence

import numpy as np

from . import cdr
from .errors import BagError
from .inputs import (SUPPORTED_TYPES, InputSpec, Series, clean_series, decode_topic,
                     merge_references)
from .typestore import get_typestore

INS_TOPIC = "/ins/velocity"
REF_TOPIC = "/reference/velocity"
TRUTH_TOPIC = "/sim/truth"
FAULT_TOPIC = "/sim/fault"
FILTER_STATE = "flight_fdi_msgs/msg/FilterState"
STRING = "std_msgs/msg/String"

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


# --------------------------------------------------------------------------- opening a bag

def _open_reader(path: str | Path):
    from rosbags.rosbag2 import Reader

    p = Path(path)
    if not p.exists():
        raise BagError(f"bag '{p}' does not exist")
    if p.is_dir() and not (p / "metadata.yaml").exists():
        raise BagError(f"bag '{p}': not a rosbag2 bag (no metadata.yaml in the directory)")
    if p.is_file() and p.suffix not in (".mcap", ".db3"):
        raise BagError(f"bag '{p}': not a rosbag2 bag (expected a bag directory, .mcap or .db3)")
    try:
        reader = Reader(p)
        reader.open()
    except BagError:
        raise
    except Exception as exc:
        raise BagError(f"bag '{p}' cannot be opened: {_reason(exc)}") from None
    return reader


def _reason(exc: BaseException) -> str:
    text = str(exc).strip().rstrip(".") or type(exc).__name__
    return text.splitlines()[0]


def bag_topics(path: str | Path) -> dict[str, str]:
    """{topic: message type} of a bag."""
    reader = _open_reader(path)
    try:
        return {c.topic: c.msgtype for c in reader.connections}
    finally:
        reader.close()


def _topic_list(topics: dict[str, str]) -> str:
    return ", ".join(sorted(topics)) or "none"


# --------------------------------------------------------------------------- raw messages

@dataclass
class _Raw:
    log_ns: np.ndarray
    payloads: cdr.Payloads


def _read_raw(reader: Any, path: Path, topics: set[str]) -> dict[str, _Raw]:
    """Raw payloads of ``topics`` in receive-time order (fast path for mcap)."""
    from . import mcapscan

    files: list[Path] | None = None
    try:  # which mcap files back the bag (rosbags internals; any surprise: generic path)
        from rosbags.rosbag2.reader import DirectoryReader
        from rosbags.rosbag2.storage_mcap import McapReader

        storage = reader.storage
        if isinstance(storage, DirectoryReader):
            if not storage.metadata.compression_mode and all(
                    isinstance(s, McapReader) for s in storage.storages):
                files = [Path(s.path) for s in storage.storages]
        elif isinstance(storage, McapReader):
            files = [Path(storage.path)]
    except (ImportError, AttributeError):
        files = None
    if files:
        try:
            parts = [mcapscan.scan(str(f), topics, str(path)) for f in files]
            return _merge_files(parts, topics)
        except mcapscan.Unsupported:
            pass
    return _read_raw_generic(reader, path, topics)


def _merge_files(parts: list[dict], topics: set[str]) -> dict[str, _Raw]:
    if len(parts) == 1:
        return {t: _Raw(m.log_ns, m.payloads) for t, m in parts[0].items()}
    out: dict[str, _Raw] = {}
    for t in topics:
        bufs, starts, lens, logs, base = [], [], [], [], 0
        for k, part in enumerate(parts):
            m = part[t]
            bufs.append(m.payloads.buf)
            starts.append(m.payloads.starts + base)
            lens.append(m.payloads.lengths)
            logs.append(m.log_ns)
            base += m.payloads.buf.size
        log = np.concatenate(logs)
        order = np.argsort(log, kind="stable")
        out[t] = _Raw(log[order], cdr.Payloads(np.concatenate(bufs), np.concatenate(starts)[order],
                                               np.concatenate(lens)[order]))
    return out


def _read_raw_generic(reader: Any, path: Path, topics: set[str]) -> dict[str, _Raw]:
    conns = [c for c in reader.connections if c.topic in topics]
    logs: dict[str, list[int]] = {t: [] for t in topics}
    datas: dict[str, list[bytes]] = {t: [] for t in topics}
    try:
        for conn, t_ns, data in reader.messages(connections=conns):
            logs[conn.topic].append(t_ns)
            datas[conn.topic].append(data)
        # (a damaged sqlite3 record can hold a receive time or data of the wrong type)
        return {t: _Raw(np.array(logs[t], dtype=np.int64), cdr.Payloads.from_list(datas[t]))
                for t in topics}
    except BagError:
        raise
    except Exception as exc:
        raise BagError(f"bag '{path}' is corrupt: {_reason(exc)}") from None


# --------------------------------------------------------------------------- read_flight

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
    reader = _open_reader(p)
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
        raw = _read_raw(reader, p, wanted)
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
        raise BagError(f"bag '{path}': no messages on {topic} (topics: {_topic_list(topics)}; "
                       "name the inputs with --ins-topic / --reference-topic or an "
                       "--input-profile)")
    if topics[topic] not in SUPPORTED_TYPES:
        raise BagError(f"bag '{path}': {topic} carries {topics[topic]}, expected one of "
                       f"{', '.join(t.rsplit('/', 1)[-1] for t in SUPPORTED_TYPES)} "
                       "(TwistStamped, TwistWithCovarianceStamped, Odometry)")


def _attach_truth(data: FlightData, raw: _Raw, channel: str, path: Path, topic: str) -> None:
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


def _attach_fault(data: FlightData, raw: _Raw, path: Path, topic: str) -> None:
    if len(raw.payloads) == 0:
        return
    try:
        doc = json.loads(cdr.decode_string(raw.payloads[0], what=f"bag '{path}': {topic}"))
    except BagError:
        raise
    except Exception as exc:
        raise BagError(f"bag '{path}': {topic} is not a JSON fault description: "
                       f"{_reason(exc)}") from None
    if not isinstance(doc, dict):
        raise BagError(f"bag '{path}': {topic} is not a JSON object")
    data.fault = doc


# --------------------------------------------------------------------------- generic iteration

def read_messages(path: str | Path, topics: Iterable[str] | None = None
                  ) -> Iterator[tuple[str, str, int, Any]]:
    """Yield (topic, msgtype, receive time ns, decoded message) in receive-time order.

    The project's messages (flight_fdi_msgs) and ROS 2 Jazzy's standard messages are known;
    other types are registered from the definitions stored in the bag.
    """
    p = Path(path)
    reader = _open_reader(p)
    try:
        available = {c.topic: c.msgtype for c in reader.connections}
        if topics is None:
            conns = list(reader.connections)
        else:
            wanted = list(topics)
            missing = [t for t in wanted if t not in available]
            if missing:
                raise BagError(f"bag '{p}': no topic {', '.join(missing)} "
                               f"(topics: {_topic_list(available)})")
            conns = [c for c in reader.connections if c.topic in wanted]
        store = get_typestore()
        _register_bag_types(store, conns, p)
        try:
            it = reader.messages(connections=conns)
            for conn, t_ns, data in it:
                if not isinstance(t_ns, int):  # a damaged sqlite3 record
                    raise BagError(f"bag '{p}' is corrupt: a message on {conn.topic} has the "
                                   f"receive time {t_ns!r}, not an integer")
                try:
                    msg = store.deserialize_cdr(data, conn.msgtype)
                except Exception as exc:
                    raise BagError(f"bag '{p}': a {conn.msgtype} message on {conn.topic} cannot "
                                   f"be decoded: {_reason(exc)}") from None
                yield conn.topic, conn.msgtype, t_ns, msg
        except BagError:
            raise
        except Exception as exc:
            raise BagError(f"bag '{p}' is corrupt: {_reason(exc)}") from None
    finally:
        reader.close()


def _register_bag_types(store: Any, conns: list, path: Path) -> None:
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.typesys import get_types_from_idl, get_types_from_msg

    for conn in conns:
        if conn.msgtype in store.fielddefs:
            continue
        fmt, text = conn.msgdef.format, conn.msgdef.data
        try:
            if fmt == MessageDefinitionFormat.MSG:
                types = get_types_from_msg(text, conn.msgtype)
            elif fmt == MessageDefinitionFormat.IDL:
                types = get_types_from_idl(text)
            else:
                raise BagError(f"bag '{path}': {conn.topic} has the unknown type {conn.msgtype} "
                               "and the bag stores no definition for it")
            store.register({k: v for k, v in types.items() if k not in store.fielddefs})
        except BagError:
            raise
        except Exception as exc:
            raise BagError(f"bag '{path}': the definition of {conn.msgtype} stored in the bag "
                           f"cannot be used: {_reason(exc)}") from None
