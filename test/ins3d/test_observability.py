"""The observability report: a flight with turns excites heading, the vertical sensors and
separates tilt from accelerometer bias; a straight flight does not."""
from __future__ import annotations

import numpy as np
import pytest

from flight_fdi.bagio.ins3d_input import from_flight
from flight_fdi.core.errors import CoreError
from flight_fdi.core.ins3d.model import Ins3dModel
from flight_fdi.core.ins3d.observability import manoeuvres, observability

from .conftest import flight


def _report(profile):
    fl = flight(profile, 1800.0, "navigation", "baro", 4, ideal_gnss=True, scale=False)
    inp = from_flight(fl)
    return inp, observability(Ins3dModel.from_grade("navigation"), inp.steps, inp.refs)


def test_turns_excite_heading_vertical_sensors_and_separate_tilt_from_bias():
    inp, rep = _report("cruise_turns")
    turns = [(a, b) for a, b, k in manoeuvres(inp.steps) if k == "turn"]
    assert len(turns) == 3 and turns[0][0] == pytest.approx(302.0, abs=3.0)
    first = turns[0]
    for nm in ("phi_u", "phi_e", "phi_n", "ba_x", "ba_y", "ba_z", "bg_x", "bg_y"):
        at = rep.excited_at[nm]
        assert at is not None and first[0] <= at <= first[1] + 30.0, (nm, at)
    assert rep.excited_at["bg_z"] is not None and rep.excited_at["bg_z"] > first[1]
    assert rep.excited_at["dv_u"] is None              # damped vertical, 2 rows: not measured
    small = rep.eigenvalues < 1e-3                  # scaled: 1 = the prior information
    assert small.sum() == 1                            # only dv_U


def test_straight_flight_leaves_heading_vertical_and_tilt_bias_pairs_unexcited():
    inp, rep = _report("straight")
    assert manoeuvres(inp.steps) == []
    for nm in ("phi_e", "phi_n", "phi_u", "ba_x", "ba_y", "ba_z", "bg_z"):
        assert rep.excited_at[nm] is None, nm
    i = rep.names.index
    # tilt and horizontal accelerometer bias: only their combination is learnt -> 1/sqrt(2)
    for nm in ("phi_e", "phi_n", "ba_x", "ba_y"):
        assert rep.ratio[-1, i(nm)] == pytest.approx(1 / np.sqrt(2), abs=0.02), nm
    assert rep.ratio[-1, i("ba_z")] > 0.998      # (its prior includes the 1-g scale error)
    # four unobservable directions: dv_U, ba_z and the two tilt/bias combinations
    small = rep.eigenvalues < 1e-3                  # scaled: 1 = the prior information
    assert small.sum() == 4
    null = rep.eigenvectors[:, small]
    pairs = null[[i("phi_e"), i("phi_n"), i("ba_x"), i("ba_y")]]
    assert np.linalg.matrix_rank(pairs, tol=0.1) == 2


def test_bad_arguments():
    inp, _ = _report("straight")
    with pytest.raises(CoreError):
        observability(Ins3dModel.from_grade("navigation"), inp.steps, inp.refs, every_s=0)
