"""QoS of the filter node's inputs (``input_qos``, ``input_queue_depth``) and outputs.

* ``reliable``: DDS repairs what the transport dropped (shared memory drops samples when the
  reading process is descheduled), so nothing is lost as long as the queue holds the backlog;
  but it cannot match a best-effort publisher (a driver publishing with SensorDataQoS).
* ``sensor_data``: best effort; matches every publisher, loses what the transport drops.
* ``auto`` (default): per input topic, reliable unless a publisher of the topic offers only best
  effort; publishers that appear later are checked every second and the subscription is re-created
  best effort (with a warning) when one would not match.

The queue depth must hold the backlog of a stalled node: at 10x real time the INS topic alone
brings 500 messages/s, so the default 2000 covers 4 s (the old default 100 lost samples at 10x
across processes whenever the node was descheduled for ~0.2 s).
"""
from __future__ import annotations

from typing import Any, Callable

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

INPUT_QOS_CHOICES = ("auto", "reliable", "sensor_data")


def output_qos() -> QoSProfile:
    """fdi/innovation and fdi/state: reliable, KEEP_ALL. A KEEP_LAST writer history is the only
    copy DDS retransmits from: a reader that falls more than ``depth`` samples behind (a recorder
    process descheduled for tens of ms on a loaded machine, at replay speed) silently loses the
    overwritten samples. KEEP_ALL keeps every unacknowledged sample (docs/hardening.md)."""
    return QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=1,
                      reliability=ReliabilityPolicy.RELIABLE)


def wait_for_all_acked(publishers: dict[str, Any], timeout_s: float) -> list[str]:
    """Wait, up to ``timeout_s`` in all, until every reliable subscriber acknowledged every
    sample of ``publishers`` (topic -> Publisher); the topics still unacknowledged. For a
    process about to exit: a reader that fell behind gets lost samples retransmitted only while
    the writer lives (as ``ros2 bag play --wait-for-all-acked``)."""
    import time

    from rclpy.duration import Duration

    deadline = time.monotonic() + timeout_s
    unacked = []
    for topic, pub in publishers.items():
        left = max(0.0, deadline - time.monotonic())
        if not pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))):
            unacked.append(topic)
    return unacked


def input_profile(kind: str, depth: int, best_effort: bool | None = None) -> QoSProfile:
    """The subscription profile for ``kind`` (``auto``: reliable unless ``best_effort``)."""
    if best_effort is None:
        best_effort = kind == "sensor_data"
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.BEST_EFFORT if best_effort
                      else ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)


def _best_effort_only(node: Any, topic: str) -> bool:
    pubs = node.get_publishers_info_by_topic(topic)
    return any(p.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for p in pubs)


class InputSubscriptions:
    """The node's input subscriptions with the ``input_qos`` policy (module docstring)."""

    def __init__(self, node: Any, kind: str, depth: int) -> None:
        self.node, self.kind, self.depth = node, kind, depth
        self._subs: dict[str, list] = {}  # topic -> [subscription, msg type, callback, best]
        self._timer = None
        if kind == "auto":
            from rclpy.clock import Clock, ClockType

            self._timer = node.create_timer(1.0, self.check,
                                            clock=Clock(clock_type=ClockType.STEADY_TIME))

    def subscribe(self, msg_type: Any, topic: str, callback: Callable[[bytes], None]) -> None:
        best = self.kind == "sensor_data" or (self.kind == "auto"
                                              and _best_effort_only(self.node, topic))
        sub = self.node.create_subscription(msg_type, topic, callback,
                                            input_profile(self.kind, self.depth, best), raw=True)
        self._subs[topic] = [sub, msg_type, callback, best]

    def reliability(self, topic: str) -> str:
        return "best_effort" if self._subs[topic][3] else "reliable"

    def check(self) -> None:
        """auto: re-subscribe best effort where a best-effort publisher appeared."""
        for topic, entry in self._subs.items():
            sub, msg_type, callback, best = entry
            if best or not _best_effort_only(self.node, topic):
                continue
            self.node.get_logger().warning(
                f"input_qos auto: {topic} has a best-effort publisher, which a reliable "
                "subscription cannot match: subscribing best effort (samples the transport "
                "drops are lost)")
            self.node.destroy_subscription(sub)
            entry[0] = self.node.create_subscription(msg_type, topic, callback,
                                                     input_profile(self.kind, self.depth, True),
                                                     raw=True)
            entry[3] = True
