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

from .errors import BagError


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
    gaps: list = field(default_factory=list)  # states missing from the recording: core.recording.bridge_gaps
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
    from ..core.recording import bridge_gaps, measurement_of, model_from_info
    from .reader import read_messages

    p = Path(path)
    info_msg = None
    rows: list[Any] = []
    for topic, _, _, msg in read_messages(p, topics=[model_topic, state_topic]):
        if msg.channel != channel:
            continue
        if topic == model_topic:
            info_msg = msg  # the last description of the channel wins
        else:
            rows.append(msg)
    if info_msg is None:
        raise BagError(f"bag '{p}': no ModelInfo for channel {channel!r} on {model_topic}")
    if not rows:
        raise BagError(f"bag '{p}': no FilterState for channel {channel!r} on {state_topic}")
    model, gate = model_from_info(info_msg)
    n, m = model.n, model.m
    problems = {"out_of_order_state": 0, "no_measurement": 0, "segments": 0}
    first_stamp = rows[0].header.stamp.sec + rows[0].header.stamp.nanosec * 1e-9
    segments: list[list[Any]] = []
    last_ns = None
    for msg in rows:
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if len(msg.x) != n or len(msg.p) != n * n:
            raise BagError(f"bag '{p}': a FilterState of channel {channel!r} has {len(msg.x)} "
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
        if not len(msg.z):
            problems["prediction_only"] = problems.get("prediction_only", 0) + 1
        elif len(msg.z) != m:
            problems["merged_rows"] = problems.get("merged_rows", 0) + 1
        segments[-1].append((msg, meas))
        last_ns = stamp_ns
    problems["segments"] = len(segments)
    seg = max(segments, key=len)
    if not seg:
        raise BagError(f"bag '{p}': no usable FilterState for channel {channel!r}")
    N = len(seg)
    meas = [mz for _, mz in seg]
    seg = [msg for msg, _ in seg]
    t = np.array([s.header.stamp.sec + s.header.stamp.nanosec * 1e-9 for s in seg])
    stamps = np.array([s.header.stamp.sec * 1_000_000_000 + s.header.stamp.nanosec
                       for s in seg], dtype=np.int64)
    dt = np.array([float(s.dt) for s in seg])
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
            if len(s.u) == pdim:
                u[i] = np.asarray(s.u, dtype=float)
    return Recording(
        path=str(p), channel=channel, model=model, gate=gate, t=t, dt=dt,
        z=np.array([mz[0] for mz in meas]).reshape(N, m),
        R=np.array([mz[1] for mz in meas]).reshape(N, m, m),
        H=np.array([mz[2] for mz in meas]).reshape(N, m, n),
        u=u,
        x=np.array([np.asarray(s.x, dtype=float) for s in seg]).reshape(N, n),
        P=np.array([np.asarray(s.p, dtype=float) for s in seg]).reshape(N, n, n),
        fused=np.array([bool(s.fused) and len(s.z) > 0 for s in seg]),
        gated=np.array([bool(s.gated) for s in seg]),
        first_stamp_s=first_stamp, closed_cleanly=_closed_cleanly(p), problems=problems,
        gaps=gaps, frame_id=str(seg[0].header.frame_id))
