"""Reading a recording of the filter node (a bag written by ``recorder_node``), no rclpy.

:func:`read_recording` returns one channel as arrays (:class:`Recording`): the model rebuilt from
its ModelInfo, and per FilterState the stamp, dt, z, R, H, u, x, P and the fused / gated flags.
The analysis of a recording is :func:`flight_fdi.core.recording.analyze_recording`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import cdr
from .errors import BagError
from .reader import reason

MODEL_INFO = "flight_fdi_msgs/msg/ModelInfo"
_NS = 1_000_000_000


@dataclass
class Recording:
    """One channel of a recording (N filter steps, n states, m measurement rows)."""

    path: str
    channel: str
    model: Any                  # LinearModel rebuilt from ModelInfo
    gate: Any                   # GateConfig from ModelInfo
    t: np.ndarray               # (N,) s, header stamps
    dt: np.ndarray              # (N,)
    z: np.ndarray               # (N, m)
    R: np.ndarray               # (N, m, m)
    H: np.ndarray               # (N, m, n)
    u: np.ndarray | None        # (N, p) or None
    x: np.ndarray               # (N, n)
    P: np.ndarray               # (N, n, n)
    fused: np.ndarray           # (N,) bool
    gated: np.ndarray           # (N,) bool
    first_stamp_s: float        # first recorded filter state of the channel (all segments)
    closed_cleanly: bool | None  # recorder's metadata flag (None: not a recorder_node bag)
    problems: dict[str, int] = field(default_factory=dict)
    gaps: list = field(default_factory=list)  # missing states: core.recording.bridge_gaps
    frame_id: str = ""          # header.frame_id of the recorded states (the navigation frame)


def _closed_cleanly(path: Path) -> bool | None:
    import yaml

    meta = path / "metadata.yaml"
    try:
        info = yaml.safe_load(meta.read_text(encoding="utf-8"))["rosbag2_bagfile_information"]
        flag = (info.get("custom_data") or {}).get("closed_cleanly")
    except Exception:  # not a directory bag, or metadata without custom data
        return None
    return None if flag is None else flag == "true"


def read_recording(path: str | Path, channel: str = "x", state_topic: str = "/fdi/state",
                   model_topic: str = "/fdi/model") -> Recording:
    """Read one channel of a recorder_node bag. BagError (bag or content) / CoreError (model).

    FilterStates are taken in bag order; one whose stamp does not increase is dropped
    (``problems['out_of_order_state']``), one without a measurement too
    (``problems['no_measurement']``). Where the filter was reset, the longest segment is kept
    (``problems['segments']`` = how many there were).
    """
    from ..core.recording import bridge_gaps, model_from_info

    p = Path(path)
    info_msg, rows = _load(p, channel, state_topic, model_topic)
    model, gate = model_from_info(info_msg)
    n, m = model.n, model.m
    seg, meas, problems = _longest_segment(p, channel, rows, model)
    N = len(seg)
    stamps = np.array([s.stamp_ns for s in seg], dtype=np.int64)
    sec, nsec = np.divmod(stamps, _NS)
    t = sec + nsec * 1e-9  # as sec + nanosec * 1e-9 of the header (the filter's own time)
    dt = np.array([s.dt for s in seg])
    dt[0] = 0.0  # the first step of a segment is an update on the prior
    try:
        dt, gaps = bridge_gaps(dt, np.diff(stamps) * 1e-9, t, f"bag '{p}': channel {channel!r}")
    except ValueError as exc:
        raise BagError(str(exc)) from None
    pdim = model.B.shape[1] if model.B is not None else 0
    u = None
    if pdim:
        u = np.zeros((N, pdim))
        for i, s in enumerate(seg):
            if s.u.size == pdim:
                u[i] = s.u
    return Recording(
        path=str(p), channel=channel, model=model, gate=gate, t=t, dt=dt,
        z=np.array([mz[0] for mz in meas]).reshape(N, m),
        R=np.array([mz[1] for mz in meas]).reshape(N, m, m),
        H=np.array([mz[2] for mz in meas]).reshape(N, m, n),
        u=u,
        x=np.array([s.x for s in seg]).reshape(N, n),
        P=np.array([s.p for s in seg]).reshape(N, n, n),
        fused=np.array([s.fused and s.z.size > 0 for s in seg]),
        gated=np.array([s.gated for s in seg]),
        first_stamp_s=float(rows[0].stamp_ns // _NS + (rows[0].stamp_ns % _NS) * 1e-9),
        closed_cleanly=_closed_cleanly(p), problems=problems, gaps=gaps,
        frame_id=seg[0].frame_id)


def _load(p: Path, channel: str, state_topic: str, model_topic: str
          ) -> tuple[Any, list[cdr.FilterStateRecord]]:
    """(the channel's last ModelInfo, its FilterStates in bag order) of a recording, read raw
    as :func:`~flight_fdi.bagio.recording3d.read_recording3d` reads (``read_topics_raw``: an
    mcap bag without rosbags' Reader; a damaged one is one BagError line naming the file)."""
    from .reader import read_topics_raw

    raw = read_topics_raw(p, [model_topic, state_topic])
    info_msg = last_model_info(raw[model_topic].payloads, channel, f"bag '{p}': {model_topic}")
    if info_msg is None:
        raise BagError(f"bag '{p}': no ModelInfo for channel {channel!r} on {model_topic}")
    rows = [s for s in cdr.decode_filter_states(raw[state_topic].payloads,
                                                what=f"bag '{p}': {state_topic} message")
            if s.channel == channel]
    if not rows:
        raise BagError(f"bag '{p}': no FilterState for channel {channel!r} on {state_topic}")
    return info_msg, rows


def last_model_info(payloads: cdr.Payloads, channel: str, what: str) -> Any:
    """The last ModelInfo of ``channel`` among raw ModelInfo messages (None: there is none);
    BagError naming ``what`` (bag and topic) for one that cannot be decoded."""
    from .typestore import get_typestore

    store = get_typestore()
    info_msg = None
    for i in range(len(payloads)):
        try:
            msg = store.deserialize_cdr(payloads[i], MODEL_INFO)
        except Exception as exc:
            raise BagError(f"{what} message #{i} is not a valid {MODEL_INFO}: "
                           f"{reason(exc)}") from None
        if msg.channel == channel:
            info_msg = msg  # the last description of the channel wins
    return info_msg


def _longest_segment(p: Path, channel: str, rows: list[cdr.FilterStateRecord], model: Any
                     ) -> tuple[list[cdr.FilterStateRecord], list[tuple], dict[str, int]]:
    """The longest run of usable states between filter resets, their (z, R, H) and the counts
    of what was left out (read_recording)."""
    from ..core.recording import measurement_of

    n, m = model.n, model.m
    problems = {"out_of_order_state": 0, "no_measurement": 0, "segments": 0}
    segments: list[list[tuple]] = []
    last_ns = None
    for msg in rows:
        stamp_ns = msg.stamp_ns
        if msg.x.size != n or msg.p.size != n * n:
            raise BagError(f"bag '{p}': a FilterState of channel {channel!r} has {msg.x.size} "
                           f"states; the model has {n}")
        if msg.reset or not segments:
            segments.append([])
            last_ns = None
        if last_ns is not None and stamp_ns <= last_ns:
            problems["out_of_order_state"] += 1
            continue
        try:
            meas = measurement_of(msg, model)
        except ValueError as exc:
            raise BagError(f"bag '{p}': FilterState at {stamp_ns * 1e-9:.3f} s of channel "
                           f"{channel!r}: {exc}") from None
        if meas is None:
            problems["no_measurement"] += 1
            continue
        if not msg.z.size:
            problems["prediction_only"] = problems.get("prediction_only", 0) + 1
        elif msg.z.size != m:
            problems["merged_rows"] = problems.get("merged_rows", 0) + 1
        segments[-1].append((msg, meas))
        last_ns = stamp_ns
    problems["segments"] = len(segments)
    seg = max(segments, key=len)
    if not seg:
        raise BagError(f"bag '{p}': no usable FilterState for channel {channel!r}")
    return [msg for msg, _ in seg], [mz for _, mz in seg], problems
