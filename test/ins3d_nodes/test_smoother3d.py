"""smoother_node with ``channel: ins3d`` on a bag it cannot analyse: a schema-valid
insufficient_data result with the error, published and logged, never a crash."""
from __future__ import annotations

import pytest

import harness  # noqa: F401  (private ROS domain)

from flight_fdi.nodes.smoother_node import SmootherNode
from flight_fdi.schema import validate_result


@pytest.mark.parametrize("bag,needle", [("does/not/exist", "does not exist"),
                                        ("bags/nominal", "no topic /fdi/model")])
def test_unusable_bag_gives_an_error_result(ros, bag, needle):
    node = ros.node(SmootherNode, {"bag": bag, "channel": "ins3d",
                                       "publish_smoothed": False})
    ros.spin_until(node.done, timeout=20, what="the analysis")
    res = node.last.result
    validate_result(res)
    assert res["model"] == "ins3d" and res["post_flight"]["verdict"] == "insufficient_data"
    assert needle in node.last.error and needle in res["error"]
    status = node._statuses()[0]
    assert status.level == b"\x02" and needle in status.message
