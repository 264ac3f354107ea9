"""Fuzzing the filter node's input path with hypothesis.

A plausible 1-s flight (INS at 50 Hz, references at 10 Hz; one reference topic, or two redundant
ones) is mutated by hypothesis (``fuzzlib``): any field of any message -- stamps over the whole
wire range (negative seconds, nanosec >= 1e9), frame_id, linear and angular velocity, all 36
covariance entries -- set to NaN, +-Inf, huge, subnormal, negative or arbitrary values, messages
duplicated, dropped, swapped, later stamps shifted (time jumps). The stream is published into a
fresh in-process ``FilterNode`` over reliable QoS and the executor is spun until the node has
received every message. Then:

* no exception escaped a callback (``spin_once`` re-raises them, so a clean spin is the check);
* every published Innovation / FilterState holds only finite numbers (the one documented
  exception: an update that used no row -- every present row excluded -- has
  ``gate_threshold`` NaN);
* every input is accounted for in ``/diagnostics``: INS messages received = accepted + INS drop
  counts (accepted computed here by the documented rule, from the values sent), and per channel,
  reference samples received = message-level drops + samples waiting + per-sample drops + rows of
  the updates published + channel drops.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import strategies as st

from hardening import fuzzlib as fz

TWIST = "geometry_msgs/TwistStamped"
TWIST_COV = "geometry_msgs/TwistWithCovarianceStamped"
INS_TOPIC = "/ins/velocity"
#: INS message-level drop counters (every other dropped_* of the inputs status is about
#: reference samples)
INS_DROPS = ("dropped_ins_invalid_stamp", "dropped_ins_nonfinite", "dropped_ins_duplicate",
             "dropped_ins_out_of_order", "dropped_ins_core_error", "dropped_ins_stamp_outlier")
TIME_JUMP_RESET_S = 1.0  # the node's default time_jump_reset_s
TIME_JUMP_CONFIRM = 3    # the node's default time_jump_confirm
RESET_AFTER_GAP_S = 60.0  # the node's default reset_after_gap_s (the forward jump limit)
AXES = (0, 1)            # channels x and y (the default)


def skeleton(start_ns: int, seed: int, ref_topics) -> list[dict]:
    """A plausible 1-s flight: INS at 50 Hz, each reference at 10 Hz (4 ms after an INS
    sample), velocities a slow ramp plus noise, reference covariance 0.01 on the diagonal."""
    rng = np.random.default_rng(seed)
    msgs = []
    for k in range(50):
        t = start_ns + k * 20_000_000
        msgs.append((t, 0, _twist(TWIST, INS_TOPIC, t, rng)))
        if k % 5 == 0 and k < 45:
            for j, topic in enumerate(ref_topics):
                m = _twist(TWIST_COV, topic, t + 4_000_000, rng)
                m.update({f"twist.covariance[{i}]": 0.0 for i in range(36)})
                m.update({f"twist.covariance[{i}]": 0.01 for i in (0, 7, 14)})
                msgs.append((t + 4_000_000, 1 + j, m))
    return [m for *_, m in sorted(msgs, key=lambda e: e[:2])]


def _twist(msgtype: str, topic: str, t_ns: int, rng) -> dict:
    v = np.array([50.0 + 0.5 * (t_ns % 10**10) * 1e-9, -20.0, 1.0]) + rng.normal(0, 0.05, 3)
    pre = "twist.twist" if msgtype == TWIST_COV else "twist"
    m = {"type": msgtype, "topic": topic, "header.frame_id": "map"}
    fz.set_stamp_ns(m, t_ns)
    m.update({f"{pre}.linear.{c}": float(x) for c, x in zip("xyz", v)})
    m.update({f"{pre}.angular.{c}": float(x) for c, x in zip("xyz", rng.normal(0, 0.01, 3))})
    return m


def flights(ref_topics):
    """(skeleton, mutations) for a drawn start time and seed."""
    template = skeleton(0, 0, ref_topics)  # the message types do not depend on start and seed
    return st.tuples(fz.start_ns, st.integers(0, 2**16), fz.mutations(template)).map(
        lambda a: fz.apply(skeleton(a[0], a[1], ref_topics), a[2]))


class FilterFuzz:
    def __init__(self, ros, ref_topics=("/reference/velocity",), **params):
        from flight_fdi_msgs.msg import FilterState, Innovation
        from geometry_msgs.msg import TwistStamped, TwistWithCovarianceStamped

        self.ros = ros
        self.ref_topics = list(ref_topics)
        self.params = {"input_qos": "reliable", "input_queue_depth": 1000,
                       "diagnostics_period_s": 3600.0, **params}
        if len(ref_topics) > 1:
            self.params["reference_topics"] = self.ref_topics
        self.under_test = fz.NodeUnderTest(ros, "filter_fuzz_driver")
        drv = self.under_test.drv
        self.classes = {TWIST: TwistStamped, TWIST_COV: TwistWithCovarianceStamped}
        self.pubs = {INS_TOPIC: drv.create_publisher(TwistStamped, INS_TOPIC, 1000)}
        self.pubs.update({t: drv.create_publisher(TwistWithCovarianceStamped, t, 1000)
                          for t in ref_topics})
        self.innov: list = []
        self.states: list = []
        drv.create_subscription(Innovation, "fdi/innovation", self.innov.append, 1000)
        drv.create_subscription(FilterState, "fdi/state", self.states.append, 1000)
        self.total_states = 0

    def run(self, msgs: list[dict]) -> None:
        from flight_fdi.nodes.filter_node import FilterNode

        node = self.under_test.start(FilterNode, self.params, list(self.pubs.values()),
                                     lambda n: [n.pub_innovation, n.pub_state])
        self.published = [0, 0]
        self._count(node.pub_innovation, 0)
        self._count(node.pub_state, 1)
        self.innov.clear()
        self.states.clear()
        sent = {"ins": 0, "ref": 0}
        for m in msgs:
            self.pubs[m["topic"]].publish(fz.build(self.classes[m["type"]], m))
            sent["ins" if m["topic"] == INS_TOPIC else "ref"] += 1
        c = node.counters
        self.ros.spin_until(lambda: c["received_ins"] == sent["ins"]
                            and c["received_reference"] == sent["ref"], what="inputs received")
        self.values = values = self.under_test.diag.read(node)
        self.ros.spin_until(lambda: [len(self.innov), len(self.states)] == self.published,
                            what="outputs")
        self.total_states += len(self.states)
        self.check_outputs()
        self.check_accounting(values, msgs, node)

    def _count(self, pub, k: int) -> None:
        """Count what the node publishes (to know when everything has arrived)."""
        publish = pub.publish

        def counted(msg):
            publish(msg)
            self.published[k] += 1

        pub.publish = counted

    def check_outputs(self) -> None:
        for m in self.innov:
            bad = fz.nonfinite_fields(m, fz.INNOVATION_FLOATS)
            no_row_used = len(m.row_excluded) > 0 and all(m.row_excluded)
            if bad and not (no_row_used and bad == [f"gate_threshold={[m.gate_threshold]}"]):
                pytest.fail(f"Innovation with non-finite numbers: {bad}\n{m}")
        for m in self.states:
            bad = fz.nonfinite_fields(m, fz.FILTER_STATE_FLOATS)
            assert not bad, f"FilterState with non-finite numbers: {bad}\n{m}"

    def check_accounting(self, values: dict, msgs: list[dict], node) -> None:
        name = node.get_name()
        inputs = values[f"{name}: inputs"]
        ins = [m for m in msgs if m["topic"] == INS_TOPIC]
        n_ref = len(msgs) - len(ins)
        assert int(inputs["received_ins"]) == len(ins)
        assert int(inputs["received_reference"]) == n_ref
        # INS: received = accepted + counted drops + held (a stamp jump not confirmed yet)
        held = int(inputs["held_ins_samples"])
        assert len(ins) == accepted_ins(ins) + _ints(inputs, INS_DROPS) + held, inputs
        # reference samples: received = message drops + waiting + sample drops + rows stepped
        ref_drops = _ints(inputs, [k for k in inputs if k.startswith("dropped_")
                                   and k not in INS_DROPS])
        waiting = int(inputs["waiting_reference_samples"]) + \
            int(inputs["held_reference_samples"])
        for ch in node.p["channels"]:
            cv = values[f"{name}: channel {ch}"]
            rows = sum(len(m.row_names) for m in self.innov if m.channel == ch)
            core_errors = int(cv.get("dropped_core_error", 0))
            known = ref_drops + waiting + rows + int(cv.get("dropped_reference_nonfinite", 0))
            # an update the core refused had between one row and one per reference
            assert known + core_errors <= n_ref <= known + core_errors * len(self.ref_topics), \
                (ch, n_ref, known, core_errors, inputs, cv)

    def close(self) -> None:
        self.under_test.stop()


def accepted_ins(ins: list[dict]) -> int:
    """INS messages the node must accept (filter_node's module docstring): a stamp a ROS stamp
    can hold, finite on every configured axis, and on the time line (core ``StampLine``, unit
    tested on its own in test/core/test_timeline.py: later than the last accepted stamp, or a
    jump that the next samples confirm). Stamps as the node reads them (sec + nanosec * 1e-9)."""
    from flight_fdi.core.timeline import ACCEPT, NEW_LINE, StampLine

    line = StampLine(TIME_JUMP_RESET_S, TIME_JUMP_CONFIRM, RESET_AFTER_GAP_S)
    n = 0
    for m in ins:
        t = m["header.stamp.sec"] + m["header.stamp.nanosec"] * 1e-9
        if round(t * 1e9) >= 2**31 * fz.NS:
            continue
        if not all(math.isfinite(m[f"twist.linear.{'xyz'[a]}"]) for a in AXES):
            continue
        v = line.check(t, t)
        n += 1 if v.kind == ACCEPT else len(v.released) if v.kind == NEW_LINE else 0
    return n


def _ints(d: dict, keys) -> int:
    return sum(int(d.get(k, 0)) for k in keys)


# ------------------------------------------------------------------------------ the tests

@pytest.mark.parametrize("gate_action", ["flag", "reject"])
def test_fuzzed_inputs_never_crash_publish_only_finite_numbers_and_are_counted(ros, gate_action):
    fuzz = FilterFuzz(ros, gate_action=gate_action)
    fz.run_examples(fuzz, flights(fuzz.ref_topics), 40)
    assert fuzz.total_states > 40 * 10, fuzz.total_states  # the fuzzing reached the filter


@pytest.mark.parametrize("mode", ["exclude", "known_anomaly"])
def test_fuzzed_redundant_references(ros, mode):
    fuzz = FilterFuzz(ros, ref_topics=("/gnss/velocity", "/doppler/velocity"),
                      reference_mode=mode)
    fz.run_examples(fuzz, flights(fuzz.ref_topics), 25)
    assert fuzz.total_states > 25 * 10, fuzz.total_states
