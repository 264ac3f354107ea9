"""ClockReader reads the same time as rclpy's Clock.now() -- ROS, simulated and steady time."""
from __future__ import annotations

from rclpy.clock import Clock, ClockType, ROSClock
from rclpy.time import Time

from flight_fdi.nodes.clockutil import ClockReader


def test_reads_the_clock_it_wraps():
    for clock in (ROSClock(), Clock(clock_type=ClockType.STEADY_TIME),
                  Clock(clock_type=ClockType.SYSTEM_TIME)):
        reader = ClockReader(clock)
        before = clock.now().nanoseconds
        got = reader.now_ns()
        after = clock.now().nanoseconds
        assert before <= got <= after
        assert abs(reader.now_s() - got * 1e-9) < 1.0


def test_follows_simulated_time():
    clock = ROSClock()
    reader = ClockReader(clock)
    clock._set_ros_time_is_active(True)  # what use_sim_time does through TimeSource
    clock.set_ros_time_override(Time(seconds=42, nanoseconds=7))
    assert reader.now_ns() == clock.now().nanoseconds == 42_000_000_007
    clock.set_ros_time_override(Time(seconds=43))
    assert reader.now_s() == 43.0
