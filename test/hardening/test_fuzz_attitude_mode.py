"""Fuzzing the filter node's attitude mode (seed 003) input path with hypothesis.

A plausible 1-s attitude flight at 20 Hz (angle, rate and control per tick, the command stamped
at the sample it follows) is mutated by hypothesis (``fuzzlib``): any field of any
geometry_msgs/Vector3Stamped -- stamps over the wire range, frame_id, x/y/z -- set to NaN,
+-Inf, huge, subnormal or arbitrary values, messages duplicated, dropped, swapped, later stamps
shifted. After every example:

* no exception escaped a callback;
* every Innovation / FilterState holds only finite numbers, every ``fdi/actuator_event`` is
  strict JSON (no NaN);
* every angle sample is accounted for in ``/diagnostics``: received = message-level drops +
  waiting + sample-level drops + per channel (channel drops + states published).
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import strategies as st

from hardening import fuzzlib as fz

VEC = "geometry_msgs/Vector3Stamped"
fz.FIELDS[VEC] = fz.HEADER_FIELDS + fz.vector_fields("vector")
TOPICS = {k: f"/attitude/{k}" for k in ("angle", "rate", "control")}
#: drops (inputs status) that remove an angle sample before the channels see it
ANGLE_DROPS = ("dropped_angle_invalid_stamp", "dropped_angle_duplicate",
               "dropped_angle_out_of_order", "dropped_time_jump", "dropped_control_expired",
               "dropped_no_control")


def skeleton(start_ns: int, seed: int) -> list[dict]:
    """20 ticks at 20 Hz: angle, rate, then the command for the next interval (stamped now)."""
    rng = np.random.default_rng(seed)
    msgs = []
    for k in range(20):
        t = start_ns + k * 50_000_000
        for kind, v in (("angle", rng.normal(0, 1e-4, 3)), ("rate", rng.normal(0, 1e-5, 3)),
                        ("control", rng.choice([-1.0, 0.0, 0.0, 0.0, 1.0], 3))):
            m = {"type": VEC, "topic": TOPICS[kind], "header.frame_id": "body"}
            fz.set_stamp_ns(m, t)
            m.update({f"vector.{c}": float(x) for c, x in zip("xyz", v)})
            msgs.append(m)
    return msgs


flights = st.tuples(fz.start_ns, st.integers(0, 2**16), fz.mutations(skeleton(0, 0))).map(
    lambda a: fz.apply(skeleton(a[0], a[1]), a[2]))


class AttitudeFuzz:
    """A driver for the attitude inputs; ``run(msgs)`` publishes a stream into a fresh
    FilterNode in attitude mode and checks it (outputs in ``states``, ``innov``, ``events``,
    the diagnostics key values in ``values``)."""

    PARAMS = {"model": "attitude_axis", "attitude_measure": "angle+rate",
              "channels": ["x", "y", "z"], "input_qos": "reliable",
              "input_queue_depth": 1000, "diagnostics_period_s": 3600.0}

    def __init__(self, ros):
        from flight_fdi_msgs.msg import FilterState, Innovation
        from geometry_msgs.msg import Vector3Stamped
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import String

        self.ros = ros
        self.under_test = fz.NodeUnderTest(ros, "attitude_fuzz_driver")
        drv = self.under_test.drv
        self.pubs = {t: drv.create_publisher(Vector3Stamped, t, 1000) for t in TOPICS.values()}
        self.innov: list = []
        self.states: list = []
        self.events: list = []
        drv.create_subscription(Innovation, "fdi/innovation", self.innov.append, 1000)
        drv.create_subscription(FilterState, "fdi/state", self.states.append, 1000)
        drv.create_subscription(String, "fdi/actuator_event", self.events.append, QoSProfile(
            depth=100, reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.total = 0

    def run(self, msgs: list[dict]) -> None:
        from geometry_msgs.msg import Vector3Stamped

        from flight_fdi.nodes.filter_node import FilterNode

        ros = self.ros
        node = self.under_test.start(FilterNode, self.PARAMS, list(self.pubs.values()),
                                     lambda n: [n.pub_innovation, n.pub_state])
        published = [0]
        publish = node.pub_state.publish

        def counted(msg):
            publish(msg)
            published[0] += 1

        node.pub_state.publish = counted
        self.innov.clear()
        self.states.clear()
        self.events.clear()
        sent = dict.fromkeys(TOPICS, 0)
        for m in msgs:
            self.pubs[m["topic"]].publish(fz.build(Vector3Stamped, m))
            sent[m["topic"].rsplit("/", 1)[1]] += 1
        c = node.counters
        ros.spin_until(lambda: all(c[f"received_{k}"] == n for k, n in sent.items()),
                       what="inputs received")
        self.values = values = self.under_test.diag.read(node)
        ros.spin_until(lambda: len(self.states) == published[0]
                       and len(self.innov) == len(self.states), what="outputs")
        self.total += len(self.states)
        for m in self.innov:
            bad = fz.nonfinite_fields(m, fz.INNOVATION_FLOATS)
            assert not bad, f"Innovation with non-finite numbers: {bad}\n{m}"
        for m in self.states:
            bad = fz.nonfinite_fields(m, fz.FILTER_STATE_FLOATS)
            assert not bad, f"FilterState with non-finite numbers: {bad}\n{m}"
        for m in self.events:
            json.loads(m.data, parse_constant=lambda c: pytest.fail(f"{c} in event {m.data}"))
        name = node.get_name()
        inputs = values[f"{name}: inputs"]
        dropped = sum(int(inputs.get(k, 0)) for k in ANGLE_DROPS)
        for ch in self.PARAMS["channels"]:
            cv = values[f"{name}: channel {ch}"]
            ch_drops = sum(int(cv.get(k, 0)) for k in ("dropped_angle_nonfinite",
                                                       "dropped_no_control",
                                                       "dropped_core_error"))
            stepped = sum(1 for m in self.states if m.channel == ch)
            assert sent["angle"] == dropped + int(inputs["waiting_samples"]) + ch_drops + stepped, \
                (ch, sent, inputs, cv)

    def close(self) -> None:
        self.under_test.stop()


def test_fuzzed_attitude_inputs_never_crash_publish_only_finite_numbers_and_are_counted(ros):
    fuzz = AttitudeFuzz(ros)
    fz.run_examples(fuzz, flights, 30)
    assert fuzz.total > 30 * 20, fuzz.total  # the fuzzing reached the filters
