"""The turn-on biases of an ins3d result (post_flight.turn_on_bias) travel on the smoother's
FaultLocalization as structured fields (``ros2 topic echo`` shows the sensor, axis and size, not
only the headline), and come back from the message."""
from __future__ import annotations

import math

import pytest

from flight_fdi.nodes.result_msgs import fault_localization_msg, post_flight_from_msg
from ins3d.test_turn_on import IN_FLIGHT, TURN_ON, analysis


def _message(*faults: str):
    from builtin_interfaces.msg import Time

    a = analysis(*faults)
    res = {"channel": "ins3d", "duration_s": 420.0,
           "samples": 42000, "post_flight": a.post_flight_dict()}
    return res["post_flight"], fault_localization_msg(res, Time(), 0.0)


def test_turn_on_bias_and_the_in_flight_fault_both_on_the_message():
    pf, msg = _message(TURN_ON, IN_FLIGHT)
    (r,) = pf["turn_on_bias"]
    assert (msg.sensor, msg.axis, msg.kind) == ("accelerometer", "x", "step")  # the in-flight one
    assert list(msg.turn_on_sensor) == ["accelerometer"] and list(msg.turn_on_axis) == ["y"]
    assert list(msg.turn_on_unit_eng) == ["mg"]
    assert msg.turn_on_magnitude_eng[0] == pytest.approx(0.3, abs=0.05)
    assert msg.turn_on_magnitude[0] == r["magnitude"]
    assert msg.turn_on_magnitude_std[0] == r["magnitude_std"]
    assert msg.turn_on_prior_sigmas[0] == pytest.approx(10.0, rel=0.1)
    back = post_flight_from_msg(msg)["turn_on_bias"]
    assert back == [{k: r[k] for k in back[0]}]


def test_no_turn_on_bias_gives_empty_fields():
    pf, msg = _message(IN_FLIGHT)
    assert pf.get("turn_on_bias", []) == []
    assert list(msg.turn_on_sensor) == [] and list(msg.turn_on_prior_sigmas) == []
    assert post_flight_from_msg(msg)["turn_on_bias"] == []


def test_a_reference_offset_has_no_prior_sigmas():
    """NaN on the message for the reference's prior sigmas, None back (as the .msg says)."""
    from builtin_interfaces.msg import Time

    pf, _ = _message(TURN_ON)
    r = dict(pf["turn_on_bias"][0], sensor="reference", axis="east", unit_eng="m/s",
             prior_sigmas=None)
    msg = fault_localization_msg({"channel": "ins3d", "duration_s": 1.0, "samples": 1,
                                  "post_flight": dict(pf, turn_on_bias=[r])}, Time(), 0.0)
    assert math.isnan(msg.turn_on_prior_sigmas[0])
    assert post_flight_from_msg(msg)["turn_on_bias"][0]["prior_sigmas"] is None
