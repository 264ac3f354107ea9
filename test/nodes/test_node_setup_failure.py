"""A node whose set-up fails is destroyed, and the error is one line naming the parameter.

The pipeline's five nodes (bag_player, filter_node, recorder_node, smoother_node, voter_node)
build themselves in ``nodes.setup.destroyed_on_failure``: an invalid parameter destroys the
half-built node (its publishers, timers, services; the player's open bag) before the
ParameterError propagates. Before, the player's parameters were declared outside that guard: a
player given an invalid parameter was left alive in its context.
"""
from __future__ import annotations

import pytest
from rclpy.node import Node

from flight_fdi.nodes.errors import ParameterError


@pytest.fixture
def destroyed(monkeypatch) -> list[str]:
    """The names of the nodes destroyed (``rclpy.node.Node.destroy_node``)."""
    names: list[str] = []
    real = Node.destroy_node

    def spy(self, *args, **kwargs):
        names.append(self.get_name())
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Node, "destroy_node", spy)
    return names


def _node_class(name: str):
    import importlib

    module, cls = {"bag_player": ("bag_player", "BagPlayer"),
                   "filter_node": ("filter_node", "FilterNode"),
                   "recorder_node": ("recorder_node", "RecorderNode"),
                   "smoother_node": ("smoother_node", "SmootherNode"),
                   "voter_node": ("voter_node", "VoterNode")}[name]
    return getattr(importlib.import_module(f"flight_fdi.nodes.{module}"), cls)


@pytest.mark.parametrize("node, params, parameter", [
    ("bag_player", {"rate": -1.0}, "rate"),                   # refused by the declaration
    ("bag_player", {"bag": "/no/such/bag"}, "bag"),            # the bag cannot be opened
    ("filter_node", {"gate_probability": 2.0}, "gate_probability"),
    ("recorder_node", {"storage": "csv"}, "storage"),
    ("smoother_node", {"fisher_window": 1}, "fisher_window"),
    ("voter_node", {"thresholds_file": "/no/such/table.json"}, "thresholds_file"),
])
def test_an_invalid_parameter_destroys_the_node_with_one_line(ros, destroyed, node, params,
                                                              parameter):
    with pytest.raises(ParameterError) as err:
        ros.node(_node_class(node), params)
    text = str(err.value)
    assert "\n" not in text and text.startswith(f"invalid parameter '{parameter}'"), text
    assert destroyed == [node]


def test_a_player_failing_after_opening_its_bag_closes_it(ros, destroyed, monkeypatch,
                                                          repo_root):
    """A failure once the bag is open (a message type rclpy cannot import): the node's own
    destroy_node closes the bag, once."""
    from flight_fdi.bagio.reader import BagStream
    from flight_fdi.nodes import recorder_node

    closed: list = []
    real_close = BagStream.close

    def close(self):
        closed.append(self.path)
        return real_close(self)

    def no_class(msgtype):
        raise ImportError(f"no module for {msgtype}")

    monkeypatch.setattr(BagStream, "close", close)
    monkeypatch.setattr(recorder_node, "rclpy_message_class", no_class)
    with pytest.raises(ParameterError, match=r"^invalid parameter 'topics': .*rclpy can import"):
        ros.node(_node_class("bag_player"), {"bag": str(repo_root / "bags" / "nominal")})
    assert destroyed == ["bag_player"] and len(closed) >= 1


def test_the_helper_destroys_on_any_error_and_reraises_it():
    from flight_fdi.nodes.setup import destroyed_on_failure

    class Fake:
        destroyed = 0

        def destroy_node(self):
            self.destroyed += 1

    fake = Fake()
    with destroyed_on_failure(fake):
        pass
    assert fake.destroyed == 0
    with pytest.raises(KeyError, match="boom"), destroyed_on_failure(fake):
        raise KeyError("boom")
    assert fake.destroyed == 1
