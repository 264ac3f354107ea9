"""The text result's observability line (``observability.bias_line``): from when the flight
knew each initial sensor bias to half its prior sigma, and which it never did (on a flight
without turns, the vertical gyro)."""
from __future__ import annotations

from flight_fdi.bagio.ins3d_input import from_flight
from flight_fdi.core.ins3d.analysis import analyze_ins3d
from flight_fdi.core.ins3d.observability import bias_line
from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
from flight_fdi.sim.trajectory import TrajectoryConfig


def test_the_line_names_sensors_and_what_was_never_known():
    line = bias_line({"dv_e": 10.0, "ba_x": 80.0, "ba_y": None, "bg_x": 310.4, "bg_z": None,
                      "ref_m_e": None})
    assert line == ("sensor bias known to half its prior sigma: accelerometer x from 80 s, "
                    "accelerometer y never, gyro x from 310 s, gyro z never")
    assert bias_line({"dv_e": 1.0}) is None
    assert bias_line({}) is None


def test_a_straight_flight_never_learns_the_vertical_gyro():
    """300 s of straight flight, no turn: the vertical gyro's bias is never learnt (heading is
    seen only through turns), the vertical accelerometer's is (the height loop)."""
    flight = simulate3d(Sim3DConfig(trajectory=TrajectoryConfig(profile="straight",
                                                                duration_s=300.0, seed=3),
                                    seed=5))
    inp = from_flight(flight)
    an = analyze_ins3d(inp.steps, inp.refs, post=False, **inp.vertical())
    line = bias_line(an.observability.excited_at)
    assert "gyro z never" in line
    assert "accelerometer z from" in line
