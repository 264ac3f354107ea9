"""Parameters survive ``ros2 param dump`` -> ``--params-file``, and the natural spellings work.

The files are written the way ros2cli's ``ros2 param dump`` writes them (ros2param 0.32:
``yaml.dump({node: {"ros__parameters": values}}, default_flow_style=False)``, PyYAML, which leaves
``y`` unquoted), and read by rcl itself: ``rclpy.init(args=[... "--ros-args", "--params-file",
F])`` in a private context, then the node is built in that context. rcl reads a plain ``y`` as a
boolean (YAML 1.1); ``runner`` re-types the values of the node's own parameters first
(``param_args.normalize_ros_args``), which is what these tests exercise.
"""
from __future__ import annotations

import os
from pathlib import Path

import harness  # noqa: F401  (private ROS domain)
import pytest
import rclpy
import yaml
from rclpy.context import Context

from flight_fdi.nodes.param_args import fix_params_file, fix_value_text, normalize_ros_args


def _dump(node) -> str:
    """What ``ros2 param dump <node>`` prints for ``node`` (its code, on the node's values)."""
    values = {name: p.value if not isinstance(p.value, (list, tuple)) or isinstance(p.value, str)
              else list(p.value) for name, p in node._parameters.items()}
    return yaml.dump({node.get_fully_qualified_name(): {"ros__parameters": values}},
                     default_flow_style=False)


def _build(factory, argv: list[str], **kwargs):
    """``factory`` built in a fresh context initialised with ``argv`` (after the runner's
    normalisation, as the executables do); returns (node, {name: value})."""
    from flight_fdi.nodes.runner import node_table

    args, temps = normalize_ros_args(["prog", *argv], node_table(factory))
    ctx = Context()
    try:
        rclpy.init(args=args, context=ctx)
    finally:
        for t in temps:
            os.unlink(t)
    node = factory(context=ctx, **kwargs)
    values = {n: (list(p.value) if isinstance(p.value, (list, tuple)) else p.value)
              for n, p in node._parameters.items()}
    return node, ctx, values


def _close(node, ctx):
    node.destroy_node()
    rclpy.shutdown(context=ctx)


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    from flight_fdi.sim import SimConfig, simulate_to_bag

    path = tmp_path_factory.mktemp("rt") / "flight"
    simulate_to_bag(SimConfig(duration_s=5.0, seed=1), str(path))
    return path


def _cases(tmp: Path, bag: Path):
    from flight_fdi.nodes.bag_player import BagPlayer
    from flight_fdi.nodes.filter_node import FilterNode
    from flight_fdi.nodes.recorder_node import RecorderNode
    from flight_fdi.nodes.smoother_node import SmootherNode

    return [
        (FilterNode, ["-p", "channels:=[y]", "-p", "tau_a:=1800", "-p", "frame_id:=n",
                      "-p", "reference_topics:=[/gnss, /doppler]", "-p", "gate_rule:=seed"]),
        (SmootherNode, ["-p", "channel:=y", "-p", "analyze_on_start:=false",
                        "-p", "output_json:=yes"]),
        (RecorderNode, ["-p", f"output:={tmp / 'rec'}", "-p", "storage:=sqlite3",
                        "-p", "topics:=[fdi/state, fdi/model, y]",
                        "-p", "transient_local_topics:=[fdi/model]"]),
        (BagPlayer, ["-p", f"bag:={bag}", "-p", "rate:=2", "-p", "wait_for_subscribers:=false",
                     "-p", "exit_when_done:=false", "-p", "ack_topic:=n"]),
    ]


def test_natural_spellings_and_the_dump_round_trip(tmp_path, bag):
    for factory, argv in _cases(tmp_path, bag):
        node, ctx, first = _build(factory, ["--ros-args", *argv])
        dumped = _dump(node)
        _close(node, ctx)
        path = tmp_path / f"{factory.__name__}.yaml"
        path.write_text(dumped)
        if factory.__name__ == "RecorderNode":  # a new bag each time
            (tmp_path / "rec").rename(tmp_path / "rec_first")
        node, ctx, second = _build(factory, ["--ros-args", "--params-file", str(path)])
        _close(node, ctx)
        assert second == first, factory.__name__
    # the natural spellings gave the values a user means
    node, ctx, v = _build(_cases(tmp_path, bag)[0][0],
                          ["--ros-args", "-p", "channels:=[x, y]", "-p", "tau_a:=1800"])
    _close(node, ctx)
    assert v["channels"] == ["x", "y"] and v["tau_a"] == 1800.0


def test_the_ins3d_height_parameters_round_trip_through_the_dump(tmp_path):
    """filter_node in its ins3d mode with a height reference (``ins3d_height_*``): the natural
    spellings (an integer in the Markov pair) give the values meant, and the dump loads back to
    the same values and the same model."""
    from flight_fdi.nodes.filter_node import FilterNode

    argv = ["-p", "model:=ins3d", "-p", "ins3d_height_topic:=/baro", "-p",
            "ins3d_height_type:=sensor_msgs/msg/NavSatFix", "-p", "ins3d_height_markov:=[0.5, 8]",
            "-p", "ins3d_height_datum:=absolute", "-p", "ins3d_height_sigma:=0.1",
            "-p", "ins3d_v0_sigma_up:=2"]
    node, ctx, first = _build(FilterNode, ["--ros-args", *argv])
    model, dumped = node.model, _dump(node)
    _close(node, ctx)
    assert (first["ins3d_height_markov"], first["ins3d_v0_sigma_up"]) == ([0.5, 8.0], 2.0)
    assert model.height_row and model.ref_markov == (0.02, 0.5, 30.0, 8.0) \
        and model.v0_sigma_up == 2
    path = tmp_path / "f.yaml"
    path.write_text(dumped)
    node, ctx, second = _build(FilterNode, ["--ros-args", "--params-file", str(path)])
    again = node.model
    _close(node, ctx)
    assert second == first and again == model


def test_the_dump_of_y_is_what_rcl_alone_cannot_read(tmp_path):
    """The root of the problem, shown with rcl alone: ros2 param dump writes ``- y`` plainly,
    rcl reads it as a boolean, a mixed list does not load; after the re-typing it does."""
    from rclpy._rclpy_pybind11 import RCLError

    text = yaml.dump({"/filter_node": {"ros__parameters": {"channels": ["x", "y"]}}},
                     default_flow_style=False)
    assert "- y\n" in text
    path = tmp_path / "p.yaml"
    path.write_text(text)
    ctx = Context()
    with pytest.raises(RCLError, match="Sequence should be of same type"):
        rclpy.init(args=["prog", "--ros-args", "--params-file", str(path)], context=ctx)
    fixed = fix_params_file(text, {"channels": "string_array"})
    assert yaml.safe_load(fixed) == yaml.safe_load(text) and '["x", "y"]' in fixed


@pytest.mark.parametrize("text,ptype,want", [
    ("y", "string", '"y"'), ("n", "string", '"n"'), ("yes", "string", '"yes"'),
    ("'y'", "string", "'y'"), ("[x, y]", "string_array", '["x", "y"]'),
    ("2", "double", "2.0"), ("-3", "double", "-3.0"), ("1e-3", "double", "1e-3"),
    ("[1, 2.5]", "double_array", "[1.0, 2.5]"), ("true", "bool", "true"), ("7", "int", "7"),
    ("[1, [", "string_array", "[1, ["),  # not YAML: left to rcl's error message
])
def test_value_retyping(text, ptype, want):
    assert fix_value_text(text, ptype) == want


def test_only_the_nodes_parameters_and_plain_values_are_touched(tmp_path):
    argv = ["prog", "--executor", "single", "--ros-args", "-p", "other:=y", "-p",
            "filter_node:channels:=[y]", "-r", "__node:=f", "--params-file",
            str(tmp_path / "missing.yaml"), "--", "-p", "channels:=[y]"]
    from flight_fdi.nodes.filter_node import FILTER_PARAMS

    out, temps = normalize_ros_args(argv, FILTER_PARAMS)
    assert temps == []
    assert out == argv[:7] + ['filter_node:channels:=["y"]'] + argv[8:]


def test_unknown_parameter_names_are_warned_about(tmp_path):
    from flight_fdi.nodes.filter_node import FilterNode
    from flight_fdi.nodes.params import warn_unknown

    node, ctx, _ = _build(FilterNode, ["--ros-args", "-p", "gate_probabilty:=0.01",
                                       "-p", "chanels:=[x]"])
    try:
        assert warn_unknown(node) == ["chanels", "gate_probabilty"]
    finally:
        _close(node, ctx)


def test_help_prints_the_parameters_and_does_not_start_the_node(capsys):
    from flight_fdi.nodes import bag_player, filter_node, recorder_node, smoother_node

    for mod, table in ((filter_node, filter_node.FILTER_PARAMS),
                       (bag_player, bag_player.PLAYER_PARAMS),
                       (recorder_node, recorder_node.RECORDER_PARAMS),
                       (smoother_node, smoother_node.SMOOTHER_PARAMS)):
        assert mod.main(["prog", "--help"]) == 0
        out = capsys.readouterr().out
        assert out.startswith(f"usage: ros2 run flight_fdi {mod.NODE_NAME}")
        for spec in table:
            assert f"\n  {spec.name} ({spec.type}, default " in out
    assert not rclpy.ok()  # no context was initialised
