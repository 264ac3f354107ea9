"""Fuzzing the voter node's input path with hypothesis.

0.4 s of three plausible IMU streams at 100 Hz (matched triples) is mutated by hypothesis
(``fuzzlib``): any field of any sensor_msgs/Imu -- stamps over the wire range, frame_id,
orientation, angular velocity, linear acceleration and the three covariances -- set to NaN,
+-Inf, huge, subnormal or arbitrary values, messages duplicated, dropped, swapped, later stamps
shifted. After every example:

* no exception escaped a callback (a clean spin is the check);
* every published VoteStatus has finite pair means and bounds, and every message forwarded on
  ``imu/voted`` has finite angular velocity and linear acceleration (the fields the voter
  validates; the voter forwards the selected IMU's message unchanged, so its other fields are the
  IMU's own);
* every input is accounted for in ``/diagnostics``: per IMU, received = dropped (non-finite,
  out of range, duplicate, out of order) + matched in triples + unmatched + still waiting; every triple is
  forwarded once, and what arrived on ``imu/voted`` is what the node counts as forwarded.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import strategies as st

from flight_fdi.core.voting import PAIRS, QUANTITIES, ThresholdTable, save_table
from hardening import fuzzlib as fz

WINDOW = 5
IMU = "sensor_msgs/Imu"
TOPICS = ["/imu1/data", "/imu2/data", "/imu3/data"]


def skeleton(start_ns: int, seed: int) -> list[dict]:
    """0.4 s of three IMUs at 100 Hz (IMU1, IMU2, IMU3 per tick, same stamps): level flight,
    gyro noise 1e-3 rad/s, accelerometer 9.81 m/s^2 on z with 0.01 m/s^2 noise, orientation
    unknown (covariance[0] = -1, REP 145)."""
    rng = np.random.default_rng(seed)
    msgs = []
    for k in range(40):
        t = start_ns + k * 10_000_000
        for topic in TOPICS:
            m = {"type": IMU, "topic": topic, "header.frame_id": topic.split("/")[1]}
            fz.set_stamp_ns(m, t)
            m.update({f"angular_velocity.{c}": float(v)
                      for c, v in zip("xyz", rng.normal(0, 1e-3, 3))})
            m.update({f"linear_acceleration.{c}": float(v) for c, v in
                      zip("xyz", np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.01, 3))})
            m.update({"orientation.w": 1.0, "orientation_covariance[0]": -1.0})
            msgs.append(m)
    return msgs


flight = st.tuples(fz.start_ns, st.integers(0, 2**16), fz.mutations(skeleton(0, 0))).map(
    lambda a: fz.apply(skeleton(a[0], a[1]), a[2]))


@pytest.fixture(scope="module")
def table_file(tmp_path_factory):
    """A small hand-made table: window 5, constant bounds (two segments)."""
    entries = {q: {p: ([0.0, 1.0], [-0.01, -0.02], [0.01, 0.02]) if q.startswith("gyro")
                   else ([0.0, 1.0], [-0.1, -0.2], [0.1, 0.2]) for p in PAIRS}
               for q in QUANTITIES}
    table = ThresholdTable(QUANTITIES, WINDOW, 100.0, 0.001, 10.0, entries)
    path = tmp_path_factory.mktemp("voter_fuzz") / "thresholds.json"
    save_table(table, path)
    return path


class VoterRig:
    def __init__(self, ros, table_file, **params):
        from flight_fdi_msgs.msg import VoteStatus
        from sensor_msgs.msg import Imu

        self.ros = ros
        self.params = {"thresholds_file": str(table_file), "input_qos": "reliable",
                       "input_queue_depth": 1000, "diagnostics_period_s": 3600.0, **params}
        self.under_test = fz.NodeUnderTest(ros, "voter_fuzz_driver")
        drv = self.under_test.drv
        self.pubs = {t: drv.create_publisher(Imu, t, 1000) for t in TOPICS}
        self.votes: list = []
        self.voted: list = []
        drv.create_subscription(VoteStatus, "fdi/vote", self.votes.append, 1000)
        drv.create_subscription(Imu, "imu/voted", self.voted.append, 1000)
        self.total_votes = 0

    def run(self, msgs: list[dict]) -> None:
        from sensor_msgs.msg import Imu

        from flight_fdi.nodes.voter_node import VoterNode

        self.node = node = self.under_test.start(VoterNode, self.params, list(self.pubs.values()),
                                                 lambda n: [n.pub_vote, n.pub_voted])
        self.votes.clear()
        self.voted.clear()
        self.sent = [0, 0, 0]
        for m in msgs:
            self.pubs[m["topic"]].publish(fz.build(Imu, m))
            self.sent[TOPICS.index(m["topic"])] += 1
        c = node.counters
        self.ros.spin_until(lambda: [c[f"received_imu{k + 1}"] for k in range(3)] == self.sent,
                            what="inputs received")
        values = self.under_test.diag.read(node)
        inputs = values[f"{node.get_name()}: inputs"]
        forwarded = int(inputs["voted_published"]) + int(inputs["unvoted_published"])
        # (votes are published on every decision with status_every 1, the default)
        self.ros.spin_until(lambda: len(self.voted) == forwarded
                            and len(self.votes) == int(inputs["decisions"]), what="outputs")
        self.total_votes += len(self.votes)
        check(self, inputs)

    def close(self) -> None:
        self.under_test.stop()


def check(rig: VoterRig, inputs: dict) -> None:
    for m in rig.votes:
        bad = fz.nonfinite_fields(m, fz.VOTE_FLOATS)
        assert not bad, f"VoteStatus with non-finite numbers: {bad}\n{m}"
    for m in rig.voted:
        w, a = m.angular_velocity, m.linear_acceleration
        bad = fz.nonfinite_fields(w, ("x", "y", "z")) + fz.nonfinite_fields(a, ("x", "y", "z"))
        assert not bad, f"imu/voted message with non-finite values: {bad}\n{m}"
    matched = int(inputs["matched_triples"])
    assert int(inputs["voted_published"]) == matched
    for k in range(3):
        name = f"imu{k + 1}"
        assert int(inputs[f"received_{name}"]) == rig.sent[k]
        drops = sum(int(inputs[f"dropped_{name}_{r}"])
                    for r in ("nonfinite", "out_of_range", "duplicate", "out_of_order"))
        waiting = int(inputs[f"waiting_{name}"])
        assert rig.sent[k] == drops + matched + int(inputs[f"unmatched_{name}"]) + waiting, \
            (name, inputs)


@pytest.mark.parametrize("sticky", [True, False])
def test_fuzzed_imu_inputs_never_crash_publish_only_finite_numbers_and_are_counted(
        ros, table_file, sticky):
    rig = VoterRig(ros, table_file, sticky=sticky)
    fz.run_examples(rig, flight, 30)
    assert rig.total_votes > 30 * 20, rig.total_votes  # the fuzzing reached the vote
