"""Fixtures shared by the ins3d evaluation tests."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

#: the real excerpt: Xsens DOT unit 1 of straight/path_2 (CC BY 4.0) and its calibration
EXCERPT = Path(__file__).parent / "data" / "mimu_straight_2"


@pytest.fixture(scope="module")
def rec():
    """The excerpt's recording (``real3d.Recording``)."""
    from flight_fdi.eval import real3d as R
    return R.read_recording(EXCERPT.parent, EXCERPT.name, 1)


@pytest.fixture(scope="module")
def cal():
    """(gyro bias rad/s, accelerometer bias m/s^2) learnt on the other recordings of its day."""
    doc = json.loads((EXCERPT / "calibration.json").read_text())
    return np.array(doc["gyro_bias_rad_s"]), np.array(doc["accel_bias_m_s2"])


@pytest.fixture(scope="session")
def pf():
    """``power_bound.PowerFlight`` of 600 s of cruise_turns (first turn 303-372 s), navigation
    grade, nominal (the sweeps' data are drawn from the filter's own model)."""
    from flight_fdi.eval.montecarlo3d import Case3D, Study3DConfig
    from flight_fdi.eval.onset_bound import Signatures, analyse_case
    from flight_fdi.eval.power_bound import PowerFlight

    cfg = Study3DConfig(nominal=1, per_scenario=0, duration_s=600.0, profile="cruise_turns",
                        single_axis=False)
    _, an = analyse_case(Case3D(0, "nominal", 11, 12), cfg)
    return PowerFlight(Signatures(an))
