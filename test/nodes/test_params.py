"""The parameter mechanism (flight_fdi/nodes/params.py) and the documented params files.

Generic over every node module in flight_fdi/nodes that has a ``NODE_NAME`` and a ``*_PARAMS``
table of ParamSpec: its ``config/<NODE_NAME without _node>.yaml`` must document exactly the
declared parameters, each with a comment, at the default, typed as ROS reads it.
"""
from __future__ import annotations

import importlib
import math
import pathlib
import re

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from flight_fdi.nodes.errors import ParameterError
from flight_fdi.nodes.params import (ParamSpec, check_value, declare_parameters, fail,
                                     format_yaml_value, render_yaml)

REPO = pathlib.Path(__file__).resolve().parents[2]
NODE_DIR = REPO / "flight_fdi" / "nodes"
ROS_OWN = {"use_sim_time"}  # parameters every rclpy node declares itself


def _node_tables():
    """(module name, NODE_NAME or import error, specs) for every node module with a table."""
    out = []
    for path in sorted(NODE_DIR.glob("*.py")):
        name = f"flight_fdi.nodes.{path.stem}"
        text = path.read_text(encoding="utf-8")
        if not re.search(r"^[A-Z_]+_PARAMS\s*=", text, re.M):
            continue
        try:
            mod = importlib.import_module(name)
        except Exception as exc:  # reported by the test, not at collection
            out.append(pytest.param(name, None, exc, id=path.stem))
            continue
        tables = [v for k, v in vars(mod).items() if k.endswith("_PARAMS") and isinstance(v, tuple)
                  and v and all(isinstance(s, ParamSpec) for s in v)]
        specs = tables[0] if len(tables) == 1 else ValueError(
            f"{name}: expected exactly one *_PARAMS table of ParamSpec, found {len(tables)}")
        out.append(pytest.param(name, getattr(mod, "NODE_NAME", None), specs, id=path.stem))
    return out


NODE_TABLES = _node_tables()


def _config_path(node_name: str) -> pathlib.Path:
    stem = node_name[: -len("_node")] if node_name.endswith("_node") else node_name
    return REPO / "config" / f"{stem}.yaml"


def _ros_value(pvalue):
    from rclpy.parameter import parameter_value_to_python

    v = parameter_value_to_python(pvalue)
    return list(v) if isinstance(v, (list, tuple)) or hasattr(v, "tolist") else v


def test_the_filter_node_table_is_found():
    assert any(p.id == "filter_node" for p in NODE_TABLES)


@pytest.mark.parametrize("module, node_name, specs", NODE_TABLES)
def test_config_file_documents_exactly_the_declared_parameters(module, node_name, specs):
    if isinstance(specs, Exception):
        raise AssertionError(f"{module} cannot be checked: {specs!r}")
    assert node_name, f"{module} has a *_PARAMS table but no NODE_NAME"
    path = _config_path(node_name)
    assert path.is_file(), f"{module}: missing {path.relative_to(REPO)}"
    text = path.read_text(encoding="utf-8")
    data = yaml.safe_load(text)
    assert list(data) == [node_name], f"{path.name}: top-level key must be {node_name}"
    documented = data[node_name]["ros__parameters"]
    declared = {s.name: s for s in specs}
    assert set(documented) - ROS_OWN == set(declared), (
        f"{path.name}: undocumented {sorted(set(declared) - set(documented))}, "
        f"unknown {sorted(set(documented) - set(declared) - ROS_OWN)}")

    # as ROS's own Python loader reads it: same values and types as the defaults
    from rclpy.parameter import parameter_dict_from_yaml_file

    loaded = parameter_dict_from_yaml_file(str(path))
    for name, spec in declared.items():
        got = _ros_value(loaded[name].value)
        assert type(got) is type(spec.default), f"{name}: {got!r} is not a {spec.type}"
        assert got == spec.default, f"{path.name}: {name} = {got!r}, default {spec.default!r}"

    # every parameter is preceded by a comment
    lines = text.splitlines()
    for name in declared:
        idx = next(i for i, ln in enumerate(lines) if re.match(rf"\s+{name}:", ln))
        assert lines[idx - 1].strip().startswith("#"), f"{path.name}: {name} has no comment"


@pytest.mark.parametrize("module, node_name, specs", NODE_TABLES)
def test_config_file_parses_with_rcl(ros, module, node_name, specs):
    """The C parser of --params-file (what ros2 run uses) reads every value with its type."""
    if isinstance(specs, Exception):
        raise AssertionError(f"{module} cannot be checked: {specs!r}")
    from rclpy.node import Node

    node = Node(node_name, context=ros.context,
                cli_args=["--ros-args", "--params-file", str(_config_path(node_name))],
                automatically_declare_parameters_from_overrides=True)
    try:
        for spec in specs:
            got = node.get_parameter(spec.name).value
            got = list(got) if spec.type.endswith("_array") else got
            assert type(got) is type(spec.default) and got == spec.default, spec.name
    finally:
        node.destroy_node()


# --- the mechanism on a test table ---------------------------------------------------------------

SPECS = (
    ParamSpec("gain", "double", 0.5, "a gain", "1/s", min=0.0, max=10.0, min_exclusive=True),
    ParamSpec("count", "int", 3, "a count", min=1, max=10),
    ParamSpec("axes", "string_array", ["x", "y"], "axes", choices=("x", "y"), non_empty=True),
    ParamSpec("rule", "string", "chi2", "a rule", choices=("chi2", "seed")),
    ParamSpec("tiny", "double", 1e-6, "a small number", min=0.0),
    ParamSpec("flag", "bool", True, "a switch"),
    ParamSpec("live", "double", 2.0, "changeable at run time", min=0.0, read_only=False),
)


def _cross(values):
    if values["count"] > 5 and values["rule"] == "seed":
        fail("count", values["count"], "<= 5 with rule seed")


def _make(ros, overrides=None, **kw):
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    node = Node("params_test", context=ros.context,
                parameter_overrides=[Parameter(k, value=v) for k, v in (overrides or {}).items()])
    ros.add(node)
    return node, declare_parameters(node, SPECS, **kw)


def test_defaults_and_descriptors(ros):
    from rcl_interfaces.msg import ParameterType

    node, values = _make(ros)
    assert values == {s.name: s.default for s in SPECS}
    d = node.describe_parameter("gain")
    assert d.type == ParameterType.PARAMETER_DOUBLE
    assert (d.floating_point_range[0].from_value, d.floating_point_range[0].to_value) == (0.0, 10.0)
    assert d.read_only and "1/s" in d.description and "(0, 10]" in d.additional_constraints
    d = node.describe_parameter("count")
    assert (d.integer_range[0].from_value, d.integer_range[0].to_value) == (1, 10)
    assert "chi2, seed" in node.describe_parameter("rule").additional_constraints
    assert not node.describe_parameter("live").read_only


@pytest.mark.parametrize("name, value, expect", [
    ("gain", 20.0, "(0, 10]"),          # rclpy's own range check, converted
    ("gain", 0.0, "(0, 10]"),           # exclusive bound: ours
    ("gain", 1, "decimal point"),       # an int for a double: rclpy's type check, converted
    ("gain", math.nan, "(0, 10]"),
    ("tiny", math.inf, "finite"),
    ("count", 0, "[1, 10]"),
    ("count", 2.5, "an integer"),
    ("axes", ["z"], "'z' is not one of x, y"),
    ("axes", ["x", "x"], "duplicate"),
    ("rule", "bogus", "one of: chi2, seed"),
    ("flag", "yes", "true or false"),
])
def test_invalid_values_raise_parameter_error_naming_them(ros, name, value, expect):
    with pytest.raises(ParameterError) as err:
        _make(ros, {name: value})
    msg = str(err.value)
    assert f"'{name}'" in msg and repr(value) in msg and expect in msg, msg


def test_cross_field_validator(ros):
    _make(ros, {"count": 7, "rule": "chi2"}, validator=_cross)  # fine
    with pytest.raises(ParameterError, match=r"'count': got 7; allowed: <= 5 with rule seed"):
        _make(ros, {"count": 7, "rule": "seed"}, validator=_cross)


def test_run_time_changes_are_validated_and_reported(ros):
    from rclpy.parameter import Parameter

    seen = []
    node, values = _make(ros, on_change=seen.append)
    ok = node.set_parameters([Parameter("live", value=3.0)])[0]
    assert ok.successful and seen[-1]["live"] == 3.0 and values["live"] == 3.0
    bad = node.set_parameters([Parameter("live", value=-1.0)])[0]
    assert not bad.successful and "live" in bad.reason
    assert node.get_parameter("live").value == 3.0 and len(seen) == 1
    ro = node.set_parameters([Parameter("gain", value=1.0)])[0]
    assert not ro.successful  # read-only: a restart is needed


def test_spec_rejects_an_invalid_default():
    with pytest.raises(ValueError, match="default"):
        ParamSpec("x", "double", -1.0, "neg", min=0.0)
    with pytest.raises(ValueError, match="empty"):
        ParamSpec("x", "string_array", [], "empty array cannot be typed by rcl")


def test_check_value_bounds():
    s = ParamSpec("p", "double", 0.5, "", min=0.0, max=1.0, min_exclusive=True)
    assert check_value(s, 1.0) is None and check_value(s, 1e-300) is None
    assert check_value(s, 0.0) and check_value(s, 1.0000001) and check_value(s, 1)
    even = ParamSpec("e", "int", 4, "", min=0, max=10, step=2)
    assert check_value(even, 6) is None and "step" in check_value(even, 5)
    arr = ParamSpec("a", "double_array", [1.0], "", min=0.0)
    assert check_value(arr, [0.0, 2.0]) is None and check_value(arr, [1.0, -1.0])


def test_filter_yaml_is_the_generated_file(repo_root):
    """config/filter.yaml is regenerated from FILTER_PARAMS (python -m flight_fdi.nodes.params)."""
    from flight_fdi.nodes.params import render_module

    text = (repo_root / "config" / "filter.yaml").read_text(encoding="utf-8")
    assert text == render_module("flight_fdi.nodes.filter_node")


def test_render_yaml_round_trip(tmp_path, ros):
    path = tmp_path / "p.yaml"
    path.write_text(render_yaml("params_test", SPECS, header="test header\nsecond line"))
    text = path.read_text()
    assert text.startswith("# test header\n# second line\nparams_test:\n  ros__parameters:\n")
    from rclpy.node import Node

    node = Node("params_test", context=ros.context,
                cli_args=["--ros-args", "--params-file", str(path)])
    ros.add(node)
    assert declare_parameters(node, SPECS) == {s.name: s.default for s in SPECS}


@settings(max_examples=300, deadline=None)
@given(st.floats(allow_nan=False, allow_infinity=False))
def test_format_yaml_value_keeps_floats_floats(x):
    """YAML 1.1 (PyYAML, rclpy) reads '1e-06' as a string; the renderer must not write that."""
    got = yaml.safe_load(format_yaml_value(x))
    assert isinstance(got, float) and got == x


@given(st.text(max_size=20), st.integers(-2**63, 2**63 - 1), st.booleans())
def test_format_yaml_value_other_scalars(s, i, b):
    assert yaml.safe_load(format_yaml_value(s)) == s
    assert yaml.safe_load(format_yaml_value(i)) == i
    assert yaml.safe_load(format_yaml_value(b)) is b
