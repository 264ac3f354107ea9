"""Every custom message survives an rclpy publish -> subscribe round trip with every field set."""
from __future__ import annotations

import importlib

import pytest
from msg_contract import REQUIRED_FIELDS, msg_file_fields

MESSAGES = sorted(REQUIRED_FIELDS)


def _value(ftype: str, seed: int):
    """A non-default value for an rclpy field type string."""
    import builtin_interfaces.msg
    import std_msgs.msg

    if ftype.startswith("sequence<"):
        inner = ftype[len("sequence<"):-1]
        return [_value(inner, seed + k) for k in range(3)]
    if ftype == "std_msgs/Header":
        return std_msgs.msg.Header(stamp=builtin_interfaces.msg.Time(sec=1_700_000_000 + seed,
                                                                     nanosec=123_456 + seed),
                                   frame_id=f"frame{seed}")
    if ftype == "builtin_interfaces/Time":
        return builtin_interfaces.msg.Time(sec=1_700_000_100 + seed, nanosec=789 + seed)
    if ftype == "string":
        return f"s{seed}"
    if ftype == "boolean":
        return True
    if ftype in ("double", "float"):
        return 1.5 + seed
    if ftype.startswith(("uint", "int", "octet")):
        return 1 + seed % 3
    raise AssertionError(f"no test value for field type {ftype}")


def _fill(cls):
    msg = cls()
    for k, (name, ftype) in enumerate(cls.get_fields_and_field_types().items()):
        setattr(msg, name, _value(ftype, k))
    return msg


@pytest.mark.parametrize("name", MESSAGES)
def test_built_message_has_the_required_fields(name, repo_root):
    cls = getattr(importlib.import_module("flight_fdi_msgs.msg"), name)
    built = list(cls.get_fields_and_field_types())
    assert built == msg_file_fields(repo_root / "msg_defs" / "msg" / f"{name}.msg"), \
        "the built message differs from msg_defs: run make setup"
    missing = [f for f in REQUIRED_FIELDS[name] if f not in built]
    assert not missing, f"{name} lacks {missing}"


@pytest.mark.parametrize("name", MESSAGES)
def test_round_trip_through_rclpy(ros, name):
    cls = getattr(importlib.import_module("flight_fdi_msgs.msg"), name)
    sent = _fill(cls)
    node = ros.node("msg_round_trip")
    received: list = []
    node.create_subscription(cls, "round_trip", received.append, 10)
    pub = node.create_publisher(cls, "round_trip", 10)
    ros.wait_for_subscribers([pub])
    pub.publish(sent)
    ros.spin_until(lambda: received, what=f"{name} delivery")
    got = received[0]
    assert got == sent
    for field in cls.get_fields_and_field_types():
        assert getattr(got, field) == getattr(sent, field), field
