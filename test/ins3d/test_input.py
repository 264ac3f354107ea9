"""Decoding the 3-D contract topics from a bag equals the in-memory path; analyze_ins3d on the
bundled samples; bad input is a clear error."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from flight_fdi.bagio.errors import BagError
from flight_fdi.bagio.ins3d_input import from_flight, read_ins3d
from flight_fdi.core.errors import CoreError
from flight_fdi.core.ins3d.analysis import analyze_ins3d
from flight_fdi.core.ins3d.data import nav_steps

from .conftest import flight, sample_input

BAGS = Path(__file__).resolve().parents[2] / "bags"


@pytest.fixture(scope="module")
def nominal_bag():
    return sample_input("ins3d_nominal")       # read_ins3d of the bag, decoded once


@pytest.mark.slow
def test_bag_decoding_equals_the_in_memory_flight(nominal_bag):
    """bags/ins3d_nominal is `simulate --model ins3d --duration 1800 --seed 0` (bags/README.md)."""
    mem = from_flight(flight("cruise_turns", 1800.0, "navigation", "baro", 0))
    b, m = nominal_bag, mem
    assert len(b.steps) == len(m.steps) == 35999       # IMU messages at 0.05 .. 1800 s
    np.testing.assert_allclose(b.steps.t, m.steps.t, atol=1e-6)
    np.testing.assert_allclose(b.steps.C, m.steps.C, atol=1e-12)
    np.testing.assert_allclose(b.steps.f_n, m.steps.f_n, atol=1e-9)
    np.testing.assert_allclose(b.steps.v, m.steps.v, atol=1e-9)
    np.testing.assert_allclose(b.steps.lat, m.steps.lat, atol=1e-12)
    np.testing.assert_allclose(b.refs.z, m.refs.z, atol=1e-6)
    np.testing.assert_array_equal(b.refs.step, m.refs.step)


@pytest.mark.slow
def test_analyze_the_bundled_samples(nominal_bag):
    nom = analyze_ins3d(nominal_bag.steps, nominal_bag.refs).summary()
    assert nom["alarms_raised_s"] == []
    rows = len(nom["beta2_row_mean"])                                # 3 by default
    assert 0.25 * rows < nom["beta2_mean"] < 1.25 * rows             # E beta2 = rows
    assert nom["final_state"]["latency"] == pytest.approx(0.02, abs=2e-3)
    assert nom["observability"]["phi_u"] == pytest.approx(310.0, abs=20.0)   # the first turn
    json.dumps(nom)
    fault = sample_input("ins3d_accel_y_step")                     # 0.5 mg on body y at 480 s
    acc = analyze_ins3d(fault.steps, fault.refs).summary()
    # absorbed by the bias state (no forward alarm): the post-flight isolator's job
    assert acc["final_state"]["ba_y"] / 9.80665e-6 == pytest.approx(500.0, abs=100.0)
    assert abs(acc["final_state"]["ba_x"]) / 9.80665e-6 < 100.0
    fault = sample_input("ins3d_gyro_x_step")                      # 1 deg/h on body x at 480 s
    gyr = analyze_ins3d(fault.steps, fault.refs).summary()
    assert gyr["alarms_raised_s"] and gyr["alarms_raised_s"][0] > 480.0
    assert np.degrees(gyr["final_state"]["bg_x"]) * 3600 > 0.3


def test_missing_topic_is_a_clear_error(tmp_path):
    with pytest.raises(BagError, match="/ins/imu_missing"):
        read_ins3d(BAGS / "ins3d_nominal", topics={"ins_imu": "/ins/imu_missing"})


def test_bad_steps_are_refused():
    q = np.tile([1.0, 0, 0, 0], (3, 1))
    with pytest.raises(CoreError, match="increase"):
        nav_steps(np.array([0.0, 0.1, 0.1]), q, np.zeros((2, 3)), np.zeros((2, 3)),
                  np.zeros((3, 3)), np.zeros(3), np.zeros(3))
    with pytest.raises(CoreError):
        nav_steps(np.array([0.0, 0.1]), q, np.zeros((2, 3)), np.zeros((2, 3)),
                  np.zeros((3, 3)), np.zeros(3), np.zeros(3))
