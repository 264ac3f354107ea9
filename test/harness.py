"""In-process ROS 2 test harness (the pattern of rclpy's own tests).

Each test gets a private ``rclpy.Context`` and executor; nodes are built with parameter overrides;
``spin_until`` spins the executor until a future is done or a predicate holds, with a timeout, and
fails the test when the timeout is reached. No sleeps: everything waits on the executor.
"""
from __future__ import annotations

import os
import time
from typing import Any, Callable, Iterable

# A private DDS domain and localhost-only discovery, set before rclpy is imported anywhere, so that
# parallel test runs on one machine (and a developer's own nodes) never hear each other.
os.environ["ROS_DOMAIN_ID"] = str(100 + os.getpid() % 100)
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_STATIC_PEERS", None)
# Fast DDS's writers heartbeat every 3 s by default, and a reliable writer's last samples are
# acknowledged only at the next heartbeat: a replay across processes waited 2-4 s for it at its
# end (the drain), ~25 s of test_graph.py's ten replays. The tests (and their subprocesses) run
# with a 100-ms heartbeat (config/fastdds_fast_heartbeat.xml, shipped for users' own multi-process
# graphs): the same reliability and QoS, the acknowledgements sooner. A developer's own profile
# file wins.
os.environ.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE",
                      os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                   "config", "fastdds_fast_heartbeat.xml"))
#: a second private domain, for a test that runs two ROS graphs side by side (test_graph.py);
#: outside 100-199, so no test process's own domain
SECOND_DOMAIN_ID = 200 + os.getpid() % 32

import rclpy  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import Executor, SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.task import Future  # noqa: E402

DEFAULT_TIMEOUT = 10.0


class SpinTimeout(AssertionError):
    """The awaited condition did not hold within the timeout."""


class RosHarness:
    """A private context + executor, and the nodes created in it (destroyed on ``close``)."""

    def __init__(self, domain_id: int | None = None) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)   # None: ROS_DOMAIN_ID
        self.executor: Executor = SingleThreadedExecutor(context=self.context)
        self.nodes: list[Node] = []

    def add(self, node: Node) -> Node:
        self.executor.add_node(node)
        self.nodes.append(node)
        return node

    def node(self, factory: Callable[..., Node] | str, parameters: dict[str, Any] | None = None,
             **kwargs: Any) -> Node:
        """Build a node in this context with parameter overrides and add it to the executor."""
        overrides = [Parameter(k, value=v) for k, v in (parameters or {}).items()]
        if isinstance(factory, str):
            node = Node(factory, context=self.context, parameter_overrides=overrides, **kwargs)
        else:
            node = factory(context=self.context, parameter_overrides=overrides, **kwargs)
        return self.add(node)

    def spin_until(self, condition: Future | Callable[[], bool],
                   timeout: float = DEFAULT_TIMEOUT, what: str = "condition") -> None:
        """Spin until the future is done / the predicate is true; fail after ``timeout`` seconds."""
        if isinstance(condition, Future):
            self.executor.spin_until_future_complete(condition, timeout_sec=timeout)
            if not condition.done():
                raise SpinTimeout(f"{what}: future not done after {timeout} s")
            return
        deadline = time.monotonic() + timeout
        while not condition():
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise SpinTimeout(f"{what}: not true after {timeout} s")
            self.executor.spin_once(timeout_sec=min(0.05, remaining))

    def wait_for_subscribers(self, publishers: Iterable[Any], count: int = 1,
                             timeout: float = DEFAULT_TIMEOUT) -> None:
        """Discovery: wait until every publisher sees ``count`` subscriptions."""
        pubs = list(publishers)
        self.spin_until(lambda: all(p.get_subscription_count() >= count for p in pubs), timeout,
                        what="subscriber discovery")

    def close(self) -> None:
        for node in self.nodes:
            self.executor.remove_node(node)
            node.destroy_node()
        self.nodes.clear()
        self.executor.shutdown()
        if self.context.ok():
            rclpy.shutdown(context=self.context)


def collect(harness: RosHarness, node: Node, msg_type: Any, topic: str, qos: Any = 10) -> list:
    """Subscribe on ``node`` and return the list the received messages are appended to."""
    received: list = []
    node.create_subscription(msg_type, topic, received.append, qos)
    return received
