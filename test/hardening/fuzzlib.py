"""Structured fuzzing of ROS message streams with hypothesis (shared by the hardening tests).

A test builds a plausible **skeleton** stream (a short flight whose messages the node processes
normally, values from a seeded generator), and hypothesis draws a list of **mutations** applied
to it: any field of any message set to a drawn value, or a message duplicated, dropped, swapped
with the next one, or every later stamp shifted (a time jump back or forward). So bad values
arrive in the middle of a flight, with the node's state built up around them, and shrinking
leads to the one mutation that matters.

Messages are plain dicts ``{"topic": ..., field path: value}`` until they are published
(``build``), so the test can also compute what it expects from the exact values sent.

Wire ranges (checked on rclpy Jazzy): ``builtin_interfaces/Time`` is ``int32 sec`` and
``uint32 nanosec``. With ``ROS_PYTHON_CHECK_FIELDS`` off (the default) rclpy's setters accept any
int, but only the wire range reaches a subscriber, so stamps are drawn from exactly that range:
negative seconds and ``nanosec >= 1e9`` (up to 4.29 s extra) included.
"""
from __future__ import annotations

import math
import os
from typing import Any, Callable, Iterable, Sequence

from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

#: common hypothesis settings: reproducible (derandomized, no example database), no deadline
#: (spinning ROS is slow); FUZZ_NO_SHRINK=1 skips shrinking (for a quick look at a failure)
SETTINGS = dict(deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
                phases=(Phase.explicit, Phase.generate)
                if os.environ.get("FUZZ_NO_SHRINK") else tuple(Phase))

INT32 = (-(2**31), 2**31 - 1)
UINT32 = (0, 2**32 - 1)
NS = 1_000_000_000

# ------------------------------------------------------------------------------ field values

#: values a float field can carry that commonly break numerical code
SPECIAL_FLOATS = (math.nan, math.inf, -math.inf, 0.0, -0.0, 5e-324, -5e-324,
                  2.2250738585072014e-308, 1e-300, 1e154, -1e154, 1e200,
                  1.7976931348623157e308, -1.7976931348623157e308)

special = st.sampled_from(SPECIAL_FLOATS)
any_float = st.floats(allow_nan=True, allow_infinity=True)
#: a float field's bad value: special, any float64 at all, or plausible-looking
wild_float = st.one_of(special, any_float, st.floats(-1e3, 1e3))
sec = st.one_of(st.sampled_from([INT32[0], -1, 0, 1, INT32[1]]), st.integers(*INT32))
nanosec = st.one_of(st.sampled_from([0, NS - 1, NS, UINT32[1]]), st.integers(*UINT32))
#: strings (frame_id): any text without NUL (a CDR string ends at its NUL) -- control and
#: non-BMP characters, long strings
text = st.one_of(st.just(""), st.text(st.characters(blacklist_characters="\x00",
                                                    blacklist_categories=("Cs",)), max_size=300))

HEADER_FIELDS = [("header.stamp.sec", sec), ("header.stamp.nanosec", nanosec),
                 ("header.frame_id", text)]


def vector_fields(prefix: str, names: str = "xyz") -> list[tuple[str, st.SearchStrategy]]:
    return [(f"{prefix}.{c}", wild_float) for c in names]


def array_fields(prefix: str, n: int) -> list[tuple[str, st.SearchStrategy]]:
    return [(f"{prefix}[{i}]", wild_float) for i in range(n)]


#: every field of the subscribed message types, with the strategy of its bad values
FIELDS = {
    "geometry_msgs/TwistStamped": HEADER_FIELDS + vector_fields("twist.linear")
    + vector_fields("twist.angular"),
    "geometry_msgs/TwistWithCovarianceStamped": HEADER_FIELDS
    + vector_fields("twist.twist.linear") + vector_fields("twist.twist.angular")
    + array_fields("twist.covariance", 36),
    "sensor_msgs/Imu": HEADER_FIELDS + vector_fields("orientation", "xyzw")
    + array_fields("orientation_covariance", 9) + vector_fields("angular_velocity")
    + array_fields("angular_velocity_covariance", 9) + vector_fields("linear_acceleration")
    + array_fields("linear_acceleration_covariance", 9),
}


# ------------------------------------------------------------------------------ mutations

def mutations(skeleton: Sequence[dict], max_size: int = 8) -> st.SearchStrategy:
    """A list of mutations of ``skeleton`` (each message a dict with a ``type`` key)."""
    n = len(skeleton)

    @st.composite
    def set_field(draw):
        """A field of one message -- or of a run of consecutive messages of its type (a sensor
        stuck at a bad value) -- set to a drawn value."""
        i = draw(st.integers(0, n - 1))
        msgtype = skeleton[i]["type"]
        path, values = draw(st.sampled_from(FIELDS[msgtype]))
        run = draw(st.one_of(st.just(1), st.just(1), st.integers(2, 30)))
        return ("set", i, path, draw(values), msgtype, run)

    index = st.integers(0, n - 1)
    shift = st.one_of(st.integers(-5 * NS, -1), st.integers(1, 3 * NS),
                      st.integers(-10**15, 10**15))
    one = st.one_of(set_field(), set_field(), set_field(), set_field(),
                    st.tuples(st.just("dup"), index), st.tuples(st.just("drop"), index),
                    st.tuples(st.just("swap"), index),
                    st.tuples(st.just("shift"), index, shift))
    return st.lists(one, min_size=1, max_size=max_size)


def stamp_ns(msg: dict) -> int:
    return msg["header.stamp.sec"] * NS + msg["header.stamp.nanosec"]


def set_stamp_ns(msg: dict, ns: int) -> None:
    ns = min(max(ns, INT32[0] * NS), INT32[1] * NS + NS - 1)  # the wire range
    msg["header.stamp.sec"], msg["header.stamp.nanosec"] = divmod(ns, NS)


def apply(skeleton: Sequence[dict], muts: Iterable[tuple]) -> list[dict]:
    """The mutated stream (indices taken modulo the current length)."""
    msgs = [dict(m) for m in skeleton]
    for mut in muts:
        if not msgs:
            break
        kind, i = mut[0], mut[1] % len(msgs)
        if kind == "set":  # from the i-th message of its type (other mutations move messages)
            same = [m for m in msgs if m["type"] == mut[4]]
            if same:
                j = mut[1] % len(same)
                for m in same[j:j + mut[5]]:
                    m[mut[2]] = mut[3]
        elif kind == "dup":
            msgs.insert(i + 1, dict(msgs[i]))
        elif kind == "drop":
            del msgs[i]
        elif kind == "swap" and i + 1 < len(msgs):
            msgs[i], msgs[i + 1] = msgs[i + 1], msgs[i]
        elif kind == "shift":
            for m in msgs[i:]:
                set_stamp_ns(m, stamp_ns(m) + mut[2])
    return msgs


#: where a skeleton's time line starts [ns]: a Unix time, zero, negative, near the int32 limits
start_ns = st.one_of(st.just(1_700_000_000 * NS), st.just(1_700_000_000 * NS),
                     st.sampled_from([0, -100 * NS, (INT32[0] + 10) * NS, (INT32[1] - 100) * NS]))


# ------------------------------------------------------------------------------ building messages

def _resolve(msg: Any, path: str) -> tuple[Any, str, int | None]:
    parts = path.split(".")
    obj = msg
    for p in parts[:-1]:
        obj = getattr(obj, p)
    last = parts[-1]
    if last.endswith("]"):
        name, idx = last[:-1].split("[")
        return obj, name, int(idx)
    return obj, last, None


def build(cls: Callable[[], Any], fields: dict) -> Any:
    """An rclpy message of class ``cls`` with the field values of ``fields`` (dict paths)."""
    msg = cls()
    arrays: dict[tuple[int, str], tuple[Any, list]] = {}
    for path, value in fields.items():
        if path in ("type", "topic"):
            continue
        obj, name, idx = _resolve(msg, path)
        if idx is None:
            setattr(obj, name, value)
        else:
            key = (id(obj), name)
            if key not in arrays:
                arrays[key] = (obj, [float(v) for v in getattr(obj, name)])
            arrays[key][1][idx] = value
    for (_, name), (obj, values) in arrays.items():
        setattr(obj, name, values)
    return msg


# ------------------------------------------------------------------------------ checks

def nonfinite_fields(msg: Any, fields: Iterable[str]) -> list[str]:
    """Names of the float fields (scalars or arrays) of ``msg`` holding NaN or Inf."""
    bad = []
    for name in fields:
        value = getattr(msg, name)
        values = [value] if isinstance(value, float) else list(value)
        if not all(math.isfinite(v) for v in values):
            bad.append(f"{name}={values}")
    return bad


INNOVATION_FLOATS = ("innovation", "innovation_covariance", "beta2", "gate_threshold", "row_beta2")
FILTER_STATE_FLOATS = ("x", "p", "z", "r", "h", "u", "dt")
VOTE_FLOATS = ("pair_mean", "lower_bound", "upper_bound")


def diag_values(array_msg: Any) -> dict[str, dict[str, str]]:
    """{status name: {key: value}} of a DiagnosticArray."""
    return {s.name: {kv.key: kv.value for kv in s.values} for s in array_msg.status}


class DiagReader:
    """Makes a node publish its diagnostics now and returns the key values as received on
    ``/diagnostics`` by ``driver`` (so what is checked is what a user sees)."""

    def __init__(self, ros: Any, driver: Any) -> None:
        from diagnostic_msgs.msg import DiagnosticArray

        self.ros = ros
        self.got: list = []
        driver.create_subscription(DiagnosticArray, "/diagnostics", self.got.append, 100)

    def read(self, node: Any) -> dict[str, dict[str, str]]:
        n = len(self.got)
        node.diagnostics.publish_now()
        self.ros.spin_until(lambda: len(self.got) > n, what="diagnostics")
        return diag_values(self.got[-1])


class NodeUnderTest:
    """A driver node in the test's context, and a fresh node under test per example (created by
    ``start(factory, params)``, destroyed by ``stop()``), so that a failing example replays on its
    own."""

    def __init__(self, ros: Any, driver_name: str) -> None:
        self.ros = ros
        self.drv = ros.node(driver_name)
        self.diag = DiagReader(ros, self.drv)
        self.node = None

    def start(self, factory: Callable[..., Any], params: dict, publishers: Sequence[Any],
              outputs: Callable[[Any], Sequence[Any]]) -> Any:
        from rclpy.parameter import Parameter

        self.stop()
        self.node = factory(context=self.ros.context, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])
        self.ros.executor.add_node(self.node)
        self.ros.wait_for_subscribers(publishers)
        self.ros.wait_for_subscribers([*outputs(self.node), self.node.diagnostics.publisher])
        return self.node

    def stop(self) -> None:
        if self.node is not None:
            self.ros.executor.remove_node(self.node)
            self.node.destroy_node()
            self.node = None


def run_examples(rig: Any, strategy: st.SearchStrategy, max_examples: int) -> None:
    """Run ``rig.run(example)`` for ``max_examples`` drawn examples (``SETTINGS``), then
    ``rig.close()`` whatever happened."""

    @settings(max_examples=max_examples, **SETTINGS)
    @given(strategy)
    def run(example):
        rig.run(example)

    try:
        run()
    finally:
        rig.close()
