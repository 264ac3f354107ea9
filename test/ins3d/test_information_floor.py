"""The onset search's information floor (``glr3d.curves(floor=)``, docs/ins3d_eval.md, "Sixth
evaluation"; off by default, ``glr3d.INFORMATION_FLOOR`` = 0): a step / ramp / jump is searched
only at onsets where its information is above the floor times its largest on the flight.
Known answers: the rule itself on constructed information (brute force), and on a flight with
data drawn from the filter's own model (floor 1e-4, the value measured) the onsets it drops are
those after the last turn for the vertical gyro, where its GLR is chi^2 noise with (almost) no
information behind it."""
from __future__ import annotations

from unittest import mock

import numpy as np
import pytest

from flight_fdi.core.ins3d import glr3d
from flight_fdi.core.ins3d.backward import GROUP_START, REF
from flight_fdi.core.ins3d.glr3d import curves, hypotheses
from flight_fdi.eval.onset_bound import Signatures
from flight_fdi.eval.power_bound import PowerFlight

from .test_backward import short_analysis

#: the floor measured in docs/ins3d_eval.md ("Sixth evaluation")
FLOOR = 1e-4


def _constructed(U: int = 6, rows: int = 3):
    """eta, I3 over U onsets: the gyro z step's information falls by 10^1.5 per onset, every
    onset's GLR e^2 / d = 9 (a 3-sigma excursion) except the last, 25."""
    rng = np.random.default_rng(0)
    I3 = np.zeros((U, 3, 6, 6))
    for k in range(U):
        for g in range(3):
            A = rng.standard_normal((6, 6))
            I3[k, g] = A @ A.T + 6 * np.eye(6)
    info = 10.0 ** (-1.5 * np.arange(U))
    I3[:, 1, 2, 2] = info                       # gyro group, column a_z
    eta = rng.standard_normal((U, REF + rows))
    stat = np.full(U, 9.0)
    stat[-1] = 25.0
    eta[:, GROUP_START[1] + 2] = np.sqrt(stat * info)
    t = np.arange(U, dtype=float)
    M = 4
    return (t, 0.0, float(U), eta, I3, np.ones(REF + rows), np.arange(M, dtype=float),
            np.ones((M, rows)), np.tile(np.eye(rows), (M, 1, 1))), info, stat


def test_the_floor_drops_exactly_the_onsets_below_it_and_keeps_the_others():
    args, info, stat = _constructed()
    hyps = hypotheses(3)
    for floor in (0.0, 1e-4, 1e-2):
        cv = curves(hyps, *args, floor=floor)["gyro_z_step"]
        keep = info > floor * info.max()
        np.testing.assert_allclose(cv.stat, np.where(keep, stat, 0.0), rtol=1e-12)
        np.testing.assert_allclose(cv.sd[keep], 1.0 / np.sqrt(info[keep]), rtol=1e-12)
        assert np.all(np.isnan(cv.sd[~keep]))
    # no floor: the 25 at the onset with 10^-7.5 of the information is the maximum; 1e-4: 9
    assert curves(hyps, *args, floor=0.0)["gyro_z_step"].statistic == pytest.approx(25.0)
    assert curves(hyps, *args, floor=1e-4)["gyro_z_step"].statistic == pytest.approx(9.0)
    # the outliers' per-update statistic has no floor; the default is the module's constant
    # (0: off -- every onset with information, the isolator as calibrated)
    assert glr3d.INFORMATION_FLOOR == 0.0
    out0 = curves(hyps, *args, floor=0.5)["reference_east_outliers"]
    np.testing.assert_array_equal(out0.stat, curves(hyps, *args, floor=0.0)
                                  ["reference_east_outliers"].stat)
    np.testing.assert_array_equal(
        curves(hyps, *args)["gyro_z_step"].stat,
        curves(hyps, *args, floor=glr3d.INFORMATION_FLOOR)["gyro_z_step"].stat)


@pytest.fixture(scope="module")
def model_draws():
    """The 420-s cruise_turns flight (one turn, 303-372 s), 12 sets of innovations drawn from
    the filter's own no-fault model: the GLR curves without (the default) and with the floor."""
    a = short_analysis()
    pf = PowerFlight(Signatures(a))
    rng = np.random.default_rng(3)
    out = []
    for _ in range(12):
        bwd = pf.noise(rng)
        free = pf.curves(bwd)
        with mock.patch.object(glr3d, "INFORMATION_FLOOR", FLOOR):
            out.append((free, pf.curves(bwd)))
    return a, out


def test_on_model_drawn_data_the_floor_drops_only_the_vertical_gyro_onsets_after_the_turn(
        model_draws):
    a, draws = model_draws
    turn_end = max(b for _, b in a.turns())
    moved = 0
    for free, floored in draws:
        for name, c0 in free.items():
            if c0.hypothesis.kind == "outliers":
                continue
            info = 1.0 / c0.sd ** 2
            keep = info > FLOOR * np.nanmax(info)
            np.testing.assert_array_equal(floored[name].stat[keep], c0.stat[keep])
            assert np.all(floored[name].stat[~keep] == 0.0)
            # dropped: onsets in the flight's last 20 % only (a ramp's information falls
            # fastest: some inside the turn's end; a step's or jump's: after the turn)
            assert np.all(c0.t[~keep] > 0.8 * c0.t[-1]), name
            if c0.hypothesis.kind != "ramp":
                assert np.all(c0.t[~keep] > turn_end), name
        c0 = free["gyro_z_step"]
        info = 1.0 / c0.sd ** 2
        keep = info > FLOOR * np.nanmax(info)
        assert 0.8 * keep.size < keep.sum() < keep.size
        moved += c0.best >= 0 and not keep[c0.best]
    # without the floor the vertical gyro's noise maximum often sits after the turn, where a
    # fault of 100x the size it can show elsewhere would be needed to move the data
    assert moved >= 3
