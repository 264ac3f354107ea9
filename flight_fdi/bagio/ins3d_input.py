"""The 3-D estimator's input: the contract topics (/ins/velocity, /ins/imu, /ins/fix,
/reference/velocity; docs/sim3d.md) decoded into ``core.ins3d.data`` arrays -- from a bag
(``read_ins3d``) or from a simulated flight in memory (``from_flight``, same decimation as the
bag writer), plus the simulator's truth on the step grid (``truth_from_flight``) for tests and
evaluation.

The propagation grid is the /ins/imu stamps: step k runs from IMU message k to k+1 with the mean
specific force and rate of message k+1 (the mean over the interval that ends at its stamp). The
INS velocity, latitude and height at the boundaries are interpolated from their own topics.

The bag's description (metadata ``flight_fdi.sim3d``, JSON) may say how to model this INS and
its reference, in a block ``error_model`` (``error_model_options``; docs/ins3d.md, "The contract
description"): ``vertical`` (the error model's vertical channel: free, damped or loop),
``latency`` (estimate a reference latency state), ``reference_markov`` (null, or [sigma_h,
sigma_v m/s, tau s] of the reference's Markov noise) and ``initial_attitude`` (``levelled``: the
INS levelled itself on its accelerometers -- the aligned prior; ``independent``: its attitude
came from elsewhere -- independent states). Without the block (the simulator's bags) the
analysis options are those of before (``Ins3dInput.vertical``). The command line's options
(``--vertical`` ...) give a block of their own that wins key by key (``model_options_with``,
``with_error_model``); a result records the block it was analysed with (``error_model_used``).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.ins3d.data import NavSteps, RefRows, nav_steps, ref_rows
from .cdr import FILTER_STATE
from .errors import BagError

TOPICS = {"ins_velocity": "/ins/velocity", "ins_imu": "/ins/imu", "ins_fix": "/ins/fix",
          "ref_velocity": "/reference/velocity"}
#: the message type each contract topic must carry
TYPES = {"ins_velocity": "geometry_msgs/msg/TwistStamped", "ins_imu": "sensor_msgs/msg/Imu",
         "ins_fix": "sensor_msgs/msg/NavSatFix",
         "ref_velocity": "geometry_msgs/msg/TwistWithCovarianceStamped"}
TRUTH_TOPIC = "/sim/truth"
#: the description's block of error-model options and its keys
ERROR_MODEL = "error_model"
ERROR_MODEL_KEYS = ("vertical", "latency", "reference_markov", "initial_attitude")
INITIAL_ATTITUDE = {"levelled": True, "independent": False}   # -> analyze_ins3d aligned_prior


@dataclass
class Ins3dInput:
    """Decoded inputs: the steps, the reference rows, and the INS attitude at the boundaries."""

    steps: NavSteps
    refs: RefRows
    q: np.ndarray          # (K+1, 4) INS q_b^n (w, x, y, z) at the step boundaries
    t0_ns: int = 0         # the stamp times are relative to (a bag: the earliest first stamp)
    #: the simulator's description of the flight (bag metadata ``flight_fdi.sim3d``), if any
    description: dict | None = None
    #: read from a bag: the contract topics ({role: topic}) and the messages read per topic
    topics: dict | None = None
    messages: dict | None = None
    #: the height reference row, when one was asked for (``bagio.height_input.HeightInput``)
    height: Any = None

    def vertical(self) -> dict:
        """``description_vertical`` of this input's description."""
        return description_vertical(self.description)

    def model_options(self, where: str = "bag") -> dict:
        """The ``analyze_ins3d`` options of this input (``description_options``)."""
        return description_options(self.description, {}, where)


def description_vertical(description: dict | None) -> dict:
    """The ``analyze_ins3d`` options of the INS's vertical channel: its baro loop from the
    description (``vertical="loop"``), ``damped`` when the description says the INS has
    another vertical channel, nothing (the analysis defaults) without a description."""
    from ..core.ins3d.vertical import VerticalLoop
    if description is None:
        return {}
    loop = VerticalLoop.from_description(description)
    return {"vertical": "damped"} if loop is None else {"vertical": "loop", "loop": loop}


def error_model_options(description: dict | None, where: str = "bag") -> dict:
    """The ``analyze_ins3d`` options (vertical, latency, ref_markov, aligned_prior) that a
    description's ``error_model`` block gives (module docstring), {} without one; BagError, one
    line, for a key or value it does not know."""
    from ..core.ins3d.model import VERTICAL
    block = (description or {}).get(ERROR_MODEL)
    if block is None:
        return {}
    head = f"{where}: metadata flight_fdi.sim3d {ERROR_MODEL}"
    if not isinstance(block, dict):
        raise BagError(f"{head}: expected a mapping of {', '.join(ERROR_MODEL_KEYS)}")
    bad = sorted(set(block) - set(ERROR_MODEL_KEYS), key=str)
    if bad:
        raise BagError(f"{head}: unknown key {bad[0]!r} (allowed: {', '.join(ERROR_MODEL_KEYS)})")
    out: dict = {}
    if "vertical" in block:
        if block["vertical"] not in VERTICAL:
            raise BagError(f"{head}.vertical must be one of {', '.join(VERTICAL)}, got "
                           f"{block['vertical']!r}")
        out["vertical"] = block["vertical"]
    if "latency" in block:
        if not isinstance(block["latency"], bool):
            raise BagError(f"{head}.latency must be true or false, got {block['latency']!r}")
        out["latency"] = block["latency"]
    if "reference_markov" in block:
        out["ref_markov"] = _markov(head, block["reference_markov"])
    if "initial_attitude" in block:
        if block["initial_attitude"] not in INITIAL_ATTITUDE:
            raise BagError(f"{head}.initial_attitude must be one of "
                           f"{', '.join(INITIAL_ATTITUDE)}, got {block['initial_attitude']!r}")
        out["aligned_prior"] = INITIAL_ATTITUDE[block["initial_attitude"]]
    return out


def with_error_model(description: dict | None, block: dict) -> dict | None:
    """A copy of ``description`` whose ``error_model`` block has the keys of ``block`` (a block
    given elsewhere: the command line's options) in place of its own; ``description`` itself
    when ``block`` is empty. Checks nothing: ``error_model_options`` reads the result."""
    if not block:
        return description
    own = (description or {}).get(ERROR_MODEL)
    return {**(description or {}), ERROR_MODEL: {**(own if isinstance(own, dict) else {}),
                                                 **block}}


def description_options(description: dict | None, block: dict, where: str = "bag") -> dict:
    """The ``analyze_ins3d`` options of a bag's description: its vertical channel
    (``description_vertical``), overridden by its ``error_model`` block, whose keys ``block``
    (a block given elsewhere, e.g. on the command line) overrides in turn -- the one
    ``error_model_options`` check for both (BagError, one line). A ``loop`` vertical channel
    takes the description's baro loop when it has one. Without a description: the analysis
    defaults for the keys ``block`` does not give."""
    error_model_options(description, where)               # the bag's own block, as it is
    if description is None:
        return error_model_options({ERROR_MODEL: block}, where)
    merged = with_error_model(description, block)
    out = description_vertical(merged)
    given = error_model_options(merged, where)
    if given.get("vertical", "loop") != "loop":
        out.pop("loop", None)
    return {**out, **given}


def model_options_with(inp: Ins3dInput, block: dict, where: str = "bag") -> dict:
    """``description_options`` of the input's description and ``block``."""
    return description_options(inp.description, block, where)


def error_model_used(options: dict) -> dict:
    """The complete ``error_model`` block (all of ERROR_MODEL_KEYS) of ``analyze_ins3d`` model
    options: the inverse of ``error_model_options``, the options not given at
    ``analyze_ins3d``'s defaults (which are also filter_node's parameter defaults) -- what a
    result records as the options it was analysed with."""
    import inspect

    from ..core.ins3d.analysis import analyze_ins3d
    sig = inspect.signature(analyze_ins3d).parameters
    o = {k: options.get(k, sig[k].default)
         for k in ("vertical", "latency", "ref_markov", "aligned_prior")}
    mk = o["ref_markov"]
    attitude = {v: k for k, v in INITIAL_ATTITUDE.items()}[bool(o["aligned_prior"])]
    return {"vertical": o["vertical"], "latency": bool(o["latency"]),
            "reference_markov": None if mk is None else [float(v) for v in mk],
            "initial_attitude": attitude}


def _markov(head: str, value) -> tuple[float, float, float] | None:
    if value is None:
        return None
    ok = isinstance(value, list) and len(value) == 3 and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) and v > 0
        for v in value)
    if not ok:
        raise BagError(f"{head}.reference_markov must be null or [sigma_h, sigma_v, tau], all "
                       f"> 0, got {value!r}")
    return (float(value[0]), float(value[1]), float(value[2]))


def _interp(t_out: np.ndarray, t: np.ndarray, y: np.ndarray) -> np.ndarray:
    y = np.asarray(y, dtype=float)
    if y.ndim == 1:
        return np.interp(t_out, t, y)
    return np.stack([np.interp(t_out, t, y[:, i]) for i in range(y.shape[1])], axis=1)


def build_input(t_imu: np.ndarray, q: np.ndarray, f_b: np.ndarray, w_b: np.ndarray,
                t_vel: np.ndarray, v: np.ndarray, t_fix: np.ndarray, lat: np.ndarray,
                h: np.ndarray, t_ref: np.ndarray, v_ref: np.ndarray, r_ref: np.ndarray
                ) -> Ins3dInput:
    """Arrays per topic (IMU: stamps, (w, x, y, z) quaternions, mean f and w over the interval
    ending at the stamp; velocity ENU; fix lat rad, h m; reference velocity and variances)."""
    if np.size(t_imu) < 2:
        raise BagError("ins3d input: need at least two /ins/imu messages")
    t_imu = np.asarray(t_imu, dtype=float)
    v_b = _interp(t_imu, t_vel, v)
    steps = nav_steps(t_imu, q, np.asarray(f_b)[1:], np.asarray(w_b)[1:], v_b,
                      _interp(t_imu, t_fix, lat), _interp(t_imu, t_fix, h))
    refs = ref_rows(steps, np.asarray(t_vel, dtype=float), v, t_ref, v_ref, r_ref)
    return Ins3dInput(steps, refs, np.asarray(q, dtype=float))


def from_flight(flight, imu_rate_hz: float = 20.0, velocity_rate_hz: float = 20.0,
                fix_rate_hz: float = 5.0) -> Ins3dInput:
    """The inputs a bag of ``flight`` (sim.ins3d.Flight3D) would give, without the bag."""
    rate = flight.config.trajectory.rate_hz
    every = int(round(rate / imu_rate_hz))
    n_int = flight.gyro.rate.shape[0]
    m = n_int // every
    idx = every * np.arange(1, m + 1)       # as the bag: the first message ends interval 1
    w = flight.gyro.rate[:m * every].reshape(m, every, 3).mean(axis=1)
    f = flight.accel.rate[:m * every].reshape(m, every, 3).mean(axis=1)
    ins, t = flight.ins, flight.t
    iv = np.arange(0, t.size, int(round(rate / velocity_rate_hz)))
    ifx = np.arange(0, t.size, int(round(rate / fix_rate_hz)))
    g = flight.gnss
    out = build_input(t[idx], ins.q[idx], f, w, t[iv], ins.v[iv], t[ifx], ins.lat[ifx],
                      ins.h[ifx], g.t, g.v, np.broadcast_to(g.vel_var, g.v.shape))
    out.description = flight.description()
    return out


def truth_from_flight(flight, inp: Ins3dInput) -> dict[str, np.ndarray]:
    """The true error states on the step grid: ``x`` (K+1, 15) [dv, phi, b_a, b_g, dp] (biases:
    the total systematic error (S+M) r + b + fault, mean over the next step; the last repeats)
    and ``u_a``, ``u_g`` (K, 3) the same per step."""
    t = flight.t
    rate = flight.config.trajectory.rate_hz
    idx = np.rint((inp.steps.t - t[0]) * rate).astype(int)
    every = int(idx[1] - idx[0])
    from ..core.earth import radii
    dv = flight.velocity_error()[idx]
    phi = flight.attitude_error()[idx]
    tr, ins = flight.truth.nav, flight.ins
    r_n, r_m = radii(tr.lat[idx])
    dp = np.stack([(r_n + tr.h[idx]) * np.cos(tr.lat[idx]) * (ins.lon[idx] - tr.lon[idx]),
                   (r_m + tr.h[idx]) * (ins.lat[idx] - tr.lat[idx]),
                   ins.h[idx] - tr.h[idx]], axis=1)
    dt = flight.dt
    ea = flight.accel.systematic(flight.ideal_dv / dt)
    eg = flight.gyro.systematic(flight.ideal_dtheta / dt)
    k = idx.size - 1
    u_a = ea[idx[0]:idx[0] + k * every].reshape(k, every, 3).mean(axis=1)
    u_g = eg[idx[0]:idx[0] + k * every].reshape(k, every, 3).mean(axis=1)
    x = np.hstack([dv, phi, np.vstack([u_a, u_a[-1:]]), np.vstack([u_g, u_g[-1:]]), dp])
    return {"x": x, "u_a": u_a, "u_g": u_g}


def check_topics(path: str | Path, topics: dict[str, str] | None = None) -> dict[str, str]:
    """The contract topic names (TOPICS overridden by ``topics``) after checking that the bag
    has each of them with the right type (BagError, one line, naming what is wrong; a bag of
    the single-axis simulator is recognised and said so). The bag's topics come from its
    metadata.yaml where bagio reads mcap bags without rosbags (``reader._mcap_files``, ~1 ms),
    else from rosbags' Reader (~0.03 s; a missing or foreign bag: its one line)."""
    from .reader import _mcap_files, bag_topics
    names = topic_names(topics)
    listed = _mcap_files(Path(path))
    _check_available(path, names, listed[1] if listed is not None else bag_topics(path))
    return names


def check_messages(path: str | Path, topics: dict[str, str] | None = None
                   ) -> tuple[dict[str, str], dict[str, int]]:
    """``check_topics``, then every message of the contract topics read (raw, not decoded:
    ``reader.read_topics_raw``, the reader of ``read_ins3d``; ~0.05 s for an 1800-s flight):
    BagError, one line, for a corrupt bag. (names, messages per topic)."""
    return checked_messages(path, topics)[:2]


def checked_messages(path: str | Path, topics: dict[str, str] | None = None,
                     with_truth: bool = False, height: str | None = None
                     ) -> tuple[dict[str, str], dict[str, int], Any, str | None]:
    """``check_messages`` and, in the same pass when ``with_truth``, the simulator's truth
    (``truth_of_raw``; None when the bag has none or it is not asked for); ``height``: a height
    topic checked (``_check_height``) and counted too, and its type returned (else None)."""
    from .reader import read_topics_raw
    names = topic_names(topics)
    types: dict[str, str] = {}
    counted = list(names.values()) + ([] if height is None else [height])
    raw = read_topics_raw(path, counted + ([TRUTH_TOPIC] if with_truth else []),
                          check=_checker(path, names, height, types))
    truth = truth_of_raw(raw[TRUTH_TOPIC], path, TRUTH_TOPIC) \
        if with_truth and types.get(TRUTH_TOPIC) == FILTER_STATE else None
    return (names, {t: int(raw[t].log_ns.size) for t in counted}, truth,
            None if height is None else types[height])


def topic_names(topics: dict[str, str] | None) -> dict[str, str]:
    """The contract topic names: TOPICS overridden by ``topics`` (BagError unless distinct);
    not checked against a bag (``check_topics``, ``check_messages``, ``read_ins3d`` do)."""
    names = {**TOPICS, **(topics or {})}
    if len(set(names.values())) != len(names):
        raise BagError(f"the ins3d input topics must be distinct, got {sorted(names.values())}")
    return names


def _check_available(path: str | Path, names: dict[str, str], have: dict[str, str]) -> None:
    """``check_topics`` of a bag's {topic: type} ``have``."""
    from .reader import topic_list
    missing = [v for v in names.values() if v not in have]
    if missing:
        hint = (" -- a single-axis bag? --model ins3d needs the 3-D contract (docs/sim3d.md)"
                if names["ins_imu"] in missing and names["ins_velocity"] in have else "")
        raise BagError(f"bag '{path}': no topic {', '.join(missing)} (topics: "
                       f"{topic_list(have)}){hint}")
    for k, v in names.items():
        if have[v] != TYPES[k]:
            raise BagError(f"bag '{path}': {v} carries {have[v]}, expected {TYPES[k]}")


def read_ins3d(path: str | Path, topics: dict[str, str] | None = None,
               height: Any = None) -> Ins3dInput:
    """Decode a bag's contract topics (names configurable) into the estimator's input, with its
    description (BagError for a bad ``error_model`` block). Each topic is decoded as a whole
    (``ins3d_series``: the one CDR codec, ~0.1 s for an 1800-s flight). ``height``: a
    ``bagio.height_input.HeightSpec``: its topic, read in the same pass, becomes the third
    reference row (``height_input.attach_height``; ``inp.height`` says what it did)."""
    from .height_input import attach_height
    from .ins3d_series import arrays, decode_series
    from .reader import read_topics_raw
    names = topic_names(topics)
    extra = [] if height is None else [height.topic]
    types: dict[str, str] = {}
    raw = read_topics_raw(path, list(names.values()) + extra,
                          check=_checker(path, names, extra[0] if extra else None, types))
    series = decode_series(raw, names, path)
    *values, t0 = arrays(series, names, path)
    inp = build_input(*values)
    inp.t0_ns = t0
    inp.description = sim_description(path)
    error_model_options(inp.description, f"bag '{path}'")     # a bad block: said here, once
    inp.topics = dict(names)
    inp.messages = {v: int(series[k][0].size) for k, v in names.items()}
    if height is not None:
        t_vel, v, t_fix, _, h = values[4:9]
        attach_height(inp, raw[height.topic], types[height.topic], height, t_fix, h, t_vel,
                      v[:, 2], path)
    return inp


def _checker(path: str | Path, names: dict[str, str], height: str | None,
             types: dict[str, str]):
    """The ``check`` of ``reader.read_topics_raw``: the contract topics (``_check_available``)
    and a height topic (``_check_height``), the bag's types kept in ``types``."""
    if height is not None and height in names.values():
        raise BagError(f"the height topic {height} is also a contract topic")

    def check(have: dict[str, str]) -> None:
        _check_available(path, names, have)
        if height is not None:
            _check_height(path, height, have)
        types.update(have)
    return check


def _check_height(path: str | Path, topic: str, have: dict[str, str]) -> None:
    """BagError, one line, unless the bag has the height topic with a height type."""
    from .height_input import HEIGHT_TYPES
    from .reader import topic_list
    if topic not in have:
        raise BagError(f"bag '{path}': no height topic {topic} (topics: {topic_list(have)})")
    if have[topic] not in HEIGHT_TYPES:
        raise BagError(f"bag '{path}': {topic} carries {have[topic]}, expected a height: "
                       f"{', '.join(HEIGHT_TYPES)}")


#: why the 3-D input leaves a message out (``input_section3d``): the first; the others only the
#: node pipeline's filter (``flight-fdi run --model ins3d``: nodes/ins3d_mode.py, its
#: ``Ins3dAssembler``), which takes the messages one by one -- a reference whose step was taken
#: before it came (``late``: it waited longer than ``ins3d_wait_s``), a variance not > 0, a
#: value the filter refused (``core_error``); and as the single-axis input (DROP_REASONS)
#: non_finite, duplicate_stamp, out_of_order
DROP_REASONS3D = ("outside_imu_record", "late", "invalid_covariance", "core_error")
#: the words of the input warnings (``bagio.inputs.warnings``) for the 3-D model's reasons
REASON_TEXT3D = {
    "outside_imu_record": "outside the IMU record (no step for it; not used)",
    "late": "came after its step was taken (waited longer than ins3d_wait_s; not used)",
    "invalid_covariance": "a variance not > 0 (dropped)",
    "core_error": "refused by the filter (dropped)",
    "non_finite": "non-finite value (dropped)",
    "out_of_order": "header stamp older than the previous one (dropped)",
    "no_height": "no height sample within the height reference's max gap (not used: the "
                 "height row needs one)",
    "no_fix": "NavSatFix status NO_FIX (dropped)"}


def input_section3d(inp: Ins3dInput) -> dict | None:
    """The ``input`` section of a 3-D result, in the form of the single-axis one
    (``bagio.inputs.input_section``): per contract topic its role, type, messages read, samples
    used and the messages dropped per reason (``DROP_REASONS3D``). The 3-D input drops one kind
    only: reference rows outside the IMU record (no step for them: ``core.ins3d.data.ref_rows``;
    a simulated bag's first reference, at 0 s, before the first IMU message). It refuses nothing
    else -- messages are sorted by stamp, a non-finite value or a repeated IMU stamp is not
    dropped (the latter fails the analysis). With a height reference, reference rows without a
    height sample (``no_height``) and the height topic's own entry (``HeightInput.section``:
    its drops, where its variances came from, the datum offset). None for an input not read
    from a bag."""
    if inp.topics is None or inp.messages is None:
        return None
    n_ref = int(inp.messages[inp.topics["ref_velocity"]])
    no_height = 0 if inp.height is None else inp.height.ref_no_height
    out = section3d(inp.topics, inp.messages, {"ref_velocity": {
        "outside_imu_record": n_ref - int(inp.refs.t.size) - no_height,
        **({"no_height": no_height} if inp.height is not None else {})}})
    if inp.height is not None:
        out[inp.height.spec.topic] = inp.height.section()
    return out


def section3d(topics: dict[str, str], messages: dict[str, int],
              dropped: dict[str, dict[str, int]]) -> dict:
    """The ``input`` section of ``input_section3d`` from counts: ``topics`` {role: topic},
    ``messages`` {topic: messages read}, ``dropped`` {role: {reason: count}} (a role left out:
    none dropped); a topic's ``used``: its messages less its drops. One form for ``analyze``
    and for the node pipeline (``nodes.ins3d_pipeline.input_section_of_run``)."""
    out = {}
    for role, topic in topics.items():
        n = int(messages[topic])
        gone = {k: int(v) for k, v in (dropped.get(role) or {}).items()}
        out[topic] = {"role": role, "type": TYPES[role], "messages": n,
                      "used": n - sum(gone.values()), "dropped": gone}
    return out


def sim_description(path: str | Path) -> dict | None:
    """The simulator's flight description in a bag's metadata.yaml (``custom_data``
    ``flight_fdi.sim3d``, JSON), or None (another bag, or unreadable metadata)."""
    import json

    import yaml
    try:
        meta = Path(path) / "metadata.yaml"
        info = yaml.safe_load(meta.read_text(encoding="utf-8"))["rosbag2_bagfile_information"]
        doc = json.loads((info.get("custom_data") or {})["flight_fdi.sim3d"])
    except Exception:  # not a directory bag, no such key, or not JSON: no description
        return None
    return doc if isinstance(doc, dict) else None


def read_truth3d(path: str | Path, t0_ns: int, topic: str = TRUTH_TOPIC
                 ) -> dict[str, np.ndarray] | None:
    """The simulator's truth (/sim/truth, FilterState channel ``truth3d``) as {"t": seconds from
    ``t0_ns``, name: values} (``truth_relative``), or None when the bag has no such topic."""
    from .reader import read_topics_raw
    types: dict[str, str] = {}
    raw = read_topics_raw(path, [topic], check=types.update)
    if types.get(topic) != FILTER_STATE:
        return None
    return truth_relative(truth_of_raw(raw[topic], path, topic), t0_ns)


def truth_of_raw(raw, path: str | Path, topic: str = TRUTH_TOPIC
                 ) -> tuple[np.ndarray, list[str], np.ndarray] | None:
    """(stamps ns, state names, x (N, n)) of the ``truth3d`` messages among the raw FilterState
    messages ``raw`` (a ``reader.RawSeries``), or None when there are none; BagError for
    messages with different state names (or a malformed one)."""
    from .cdr import decode_filter_state_x
    stamps, channels, names, xs = decode_filter_state_x(
        raw.payloads, what=f"bag '{path}': {topic} message")
    pick = [i for i, c in enumerate(channels) if c == "truth3d"]
    if not pick:
        return None
    first = list(names[pick[0]])
    for i in pick:
        if list(names[i]) != first or xs[i].size != len(first):
            raise BagError(f"bag '{path}': {topic} messages with different state names")
    return stamps[pick], first, np.vstack([np.asarray(xs[i], dtype=float) for i in pick])


def truth_relative(truth: tuple | None, t0_ns: int) -> dict[str, np.ndarray] | None:
    """``truth_of_raw``'s truth as {"t": seconds from ``t0_ns``, name: values} (None: None)."""
    if truth is None:
        return None
    stamps, names, x = truth
    return {"t": (stamps - t0_ns) * 1e-9, **{n: x[:, i] for i, n in enumerate(names)}}


__all__ = ["DROP_REASONS3D", "ERROR_MODEL", "ERROR_MODEL_KEYS", "INITIAL_ATTITUDE", "Ins3dInput",
           "REASON_TEXT3D", "TOPICS", "TRUTH_TOPIC", "TYPES", "build_input", "check_messages",
           "checked_messages", "truth_of_raw", "truth_relative",
           "check_topics", "description_options", "description_vertical",
           "error_model_options", "error_model_used", "from_flight", "input_section3d",
           "model_options_with",
           "read_ins3d", "read_truth3d", "section3d", "topic_names", "truth_from_flight", "with_error_model"]
