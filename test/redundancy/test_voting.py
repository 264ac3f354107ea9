"""The triple-IMU voting core (seed 002): statistics, truth table, calibration, segmentation and
the threshold table file. Expected values are brute-force loops, scipy's own KS test and
hand-written tables."""
from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.stats as st

from flight_fdi.core.errors import CoreError
from flight_fdi.core.voting import (HEALTHY, MARGINAL, MULTIPLE_FAULT, PAIRS,
                                    SINGLE_FAULT, ThresholdTable, load_table, pair_differences,
                                    save_table, table_from_dict, vote, vote_array, window_means)
from flight_fdi.core.voting_calib import (bounds_from_samples, calibrate, ks_critical, ks_normal,
                                          segment_curve)

# ------------------------------------------------------------------------ truth table

# (eps1, eps2, eps3) -> (status, faulty IMU, IMU to use); SPEC section 4, written out by hand
TRUTH = {
    (1, 1, 1): (HEALTHY, 0, 1),
    (0, 1, 1): (MARGINAL, 0, 1),
    (1, 0, 1): (MARGINAL, 0, 1),
    (1, 1, 0): (MARGINAL, 0, 1),
    (1, 0, 0): (SINGLE_FAULT, 3, 1),   # only P1-P2 agree: IMU3 faulty, use IMU1
    (0, 1, 0): (SINGLE_FAULT, 1, 2),   # only P2-P3 agree: IMU1 faulty, use IMU2
    (0, 0, 1): (SINGLE_FAULT, 2, 1),   # only P1-P3 agree: IMU2 faulty, use IMU1
    (0, 0, 0): (MULTIPLE_FAULT, 0, 0),  # multiple fault: keep the selection
}


@pytest.mark.parametrize("eps, want", sorted(TRUTH.items()))
def test_truth_table_all_eight_combinations(eps, want):
    v = vote(*eps)
    assert (v.status, v.faulty_imu, v.use_imu) == want
    assert v.total == sum(eps) and v.epsilon == eps
    status, faulty, use = vote_array(np.array([eps], dtype=bool))
    assert (int(status[0]), int(faulty[0]), int(use[0])) == want


def test_vote_array_broadcasts():
    eps = np.array(list(TRUTH), dtype=bool).reshape(2, 4, 3)
    status, faulty, use = vote_array(eps)
    want = np.array(list(TRUTH.values())).reshape(2, 4, 3)
    np.testing.assert_array_equal(status, want[..., 0])
    np.testing.assert_array_equal(faulty, want[..., 1])
    np.testing.assert_array_equal(use, want[..., 2])


# ------------------------------------------------------------------------ statistics

def test_pair_differences():
    p = np.array([[1.0, 2.0, 4.0], [0.5, 0.5, 0.5]])
    np.testing.assert_array_equal(pair_differences(p), [[-1.0, -2.0, -3.0], [0.0, 0.0, 0.0]])
    with pytest.raises(CoreError, match="3 IMUs"):
        pair_differences(np.zeros((2, 2)))


@pytest.mark.parametrize("window", [1, 3, 7, 50])
def test_window_means_against_a_loop(window):
    x = np.random.default_rng(3).normal(size=(40, 2, 3))
    got = window_means(x, window, axis=0)
    for k in range(40):
        lo = max(0, k - window + 1)
        np.testing.assert_allclose(got[k], x[lo:k + 1].mean(axis=0), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(window_means(np.moveaxis(x, 0, 1), window, axis=1),
                               np.moveaxis(got, 0, 1))
    with pytest.raises(CoreError, match="integer >= 1"):
        window_means(x, 0)


def test_ks_normal_matches_scipy():
    x = np.random.default_rng(4).normal(3.0, 2.0, size=(60, 5))
    D, p, mu, sigma = ks_normal(x)
    np.testing.assert_allclose(mu, x.mean(axis=0))
    np.testing.assert_allclose(sigma, x.std(axis=0, ddof=0))
    ref = st.kstest((x - mu) / sigma, "norm", axis=0, method="exact")
    np.testing.assert_allclose(D, ref.statistic, rtol=1e-12)
    _, p_exact, _, _ = ks_normal(x, exact_p=True)
    np.testing.assert_allclose(p_exact, ref.pvalue, rtol=1e-10)
    np.testing.assert_allclose(p, ref.pvalue, atol=0.02)  # Stephens' approximation
    # a point mass is not normal
    D0, p0, _, _ = ks_normal(np.ones((20, 1)))
    assert D0[0] == 1.0 and p0[0] == 0.0


def test_bounds_normal_and_quantile_branches():
    rng = np.random.default_rng(5)
    alpha = 0.1
    normal = rng.normal(1.0, 2.0, size=(2000, 1))
    lo, up, is_n, _ = bounds_from_samples(normal, alpha)
    assert is_n[0]
    z = st.norm.isf(alpha / 2)
    assert lo[0] == pytest.approx(normal.mean() - z * normal.std(), rel=1e-12)
    assert up[0] == pytest.approx(normal.mean() + z * normal.std(), rel=1e-12)
    skewed = rng.exponential(1.0, size=(2000, 1))
    lo, up, is_n, _ = bounds_from_samples(skewed, alpha)
    assert not is_n[0]
    assert (lo[0], up[0]) == tuple(np.quantile(skewed[:, 0], [alpha / 2, 1 - alpha / 2]))
    # forcing a branch
    _, _, forced, _ = bounds_from_samples(skewed, alpha, method="normal")
    assert forced[0]
    with pytest.raises(CoreError, match="alpha"):
        bounds_from_samples(skewed, 1.5)


def test_ks_critical_value_is_exact():
    n = 100
    d = ks_critical(0.05, n)
    assert st.kstwo.sf(d, n) == pytest.approx(0.05, rel=1e-9)


# ------------------------------------------------------------------------ calibration on the sim

def test_calibration_on_a_seeded_monte_carlo(sim):
    """Per time step, the bounds contain about 1 - alpha of fresh nominal window means. The
    gyro (1-arcsec pulses: its window means sit on a lattice) takes the quantile branch, the
    accelerometer with a fine pulse (1e-6 m/s) the normal branch."""
    from dataclasses import replace

    from flight_fdi.sim.imu import ImuErrorModel, nominal_window_means

    cfg = replace(sim.config(seed=21), errors=ImuErrorModel(accel_pulse_mps=1e-6))
    qs = ("gyro_z", "accel_x")
    t, means = nominal_window_means(cfg, 1000, sim.WINDOW, qs, eval_every=4, batch_size=500)
    alpha = 0.1
    cal = calibrate(means, t, alpha, sim.WINDOW, sim.RATE_HZ, qs, n_segments=8,
                    min_segment_s=0.3)
    after = t >= sim.WINDOW / sim.RATE_HZ  # sliding windows only
    assert cal.is_normal[after][:, 0].mean() < 0.05      # gyro: quantiles
    assert cal.is_normal[after][:, 1].mean() > 0.9       # accel: normal
    # fresh flights: other runs of the same seed (runs 1000..1999). The turn-on biases make
    # the time steps of one flight correlated: ~1000 independent looks, so the coverage is
    # known to about +-1 % (and the calibration's sigma to about 2 %)
    t2, fresh = nominal_window_means(cfg, 1000, sim.WINDOW, qs, eval_every=4, batch_size=500,
                                     first_run=1000)
    np.testing.assert_array_equal(t2, t)
    inside = (fresh >= cal.lower[None]) & (fresh <= cal.upper[None])      # per-step bounds
    cover_gyro = inside[:, after][:, :, 0].mean()
    cover_accel = inside[:, after][:, :, 1].mean()
    assert abs(cover_accel - (1 - alpha)) < 0.03, cover_accel
    # quantiles of a lattice distribution include the lattice point: coverage >= 1 - alpha
    assert 1 - alpha - 0.03 < cover_gyro < 1.0, cover_gyro
    # the segmented table is wider than the per-step curves everywhere
    lo_seg, up_seg = cal.table.bounds_at(t)
    assert np.all(lo_seg <= cal.lower) and np.all(up_seg >= cal.upper)


# ------------------------------------------------------------------------ segmentation

def test_segmentation_cuts_at_the_largest_rates():
    t = np.arange(0.0, 10.0, 0.1)
    up = np.full(t.size, 1.0)
    up[t >= 3.0] = 5.0          # jump of 4 at 3.0 s
    up[t >= 6.0] = 2.0          # jump of 3 at 6.0 s
    up[t >= 8.0] = 2.5          # jump of 0.5 at 8.0 s
    up += 0.01 * np.sin(7 * t)  # small wiggle everywhere
    lo = -up
    ts, seg_lo, seg_up = segment_curve(t, lo, up, n_segments=3)
    np.testing.assert_allclose(ts, [0.0, 3.0, 6.0])  # the two largest rates, not the 0.5 jump
    np.testing.assert_allclose(seg_up, [up[t < 3].max(), up[(t >= 3) & (t < 6)].max(),
                                        up[t >= 6].max()])
    np.testing.assert_allclose(seg_lo, [lo[t < 3].min(), lo[(t >= 3) & (t < 6)].min(),
                                        lo[t >= 6].min()])
    ts4, _, _ = segment_curve(t, lo, up, n_segments=4)
    np.testing.assert_allclose(ts4, [0.0, 3.0, 6.0, 8.0])
    # a minimum segment length excludes the cut 2 s after another one
    ts_min, _, _ = segment_curve(t, lo, up, n_segments=4, min_segment_s=2.5)
    np.testing.assert_allclose(ts_min, [0.0, 3.0, 6.0])
    # a forced cut counts towards the segments
    ts_f, _, _ = segment_curve(t, lo, up, n_segments=3, forced_cuts=[1.0])
    np.testing.assert_allclose(ts_f, [0.0, 1.0, 3.0])
    ts1, l1, u1 = segment_curve(t, lo, up, n_segments=1)
    assert ts1.tolist() == [0.0] and u1[0] == up.max() and l1[0] == lo.min()


def test_smoothing_ignores_single_step_flips():
    """A quantized curve flips up and back for one step (large raw rate) while a sustained
    change happens slowly; with smoothing the cut goes to the sustained change."""
    t = np.arange(0.0, 10.0, 0.05)
    up = np.where(t < 5.0, 1.0, 1.0 + (t - 5.0))  # ramps up from 5 s
    up = np.minimum(up, 2.0)
    up[40] = 1.6                                  # one-step flip at t = 2 s
    ts_raw, _, _ = segment_curve(t, -up, up, n_segments=2)
    assert ts_raw[1] in (t[40], t[41])            # raw rates: the flip wins
    ts_s, _, _ = segment_curve(t, -up, up, n_segments=2, smooth_s=1.0)
    assert 4.0 <= ts_s[1] <= 6.5


def test_segmentation_rejects_bad_input():
    with pytest.raises(CoreError, match="increase"):
        segment_curve([0.0, 0.0], [0, 0], [1, 1], 2)
    with pytest.raises(CoreError, match="n_segments"):
        segment_curve([0.0, 1.0], [0, 0], [1, 1], 0)


# ------------------------------------------------------------------------ the table file

def _table():
    entries = {q: {p: (np.array([0.0, 2.0]), np.array([-3.0, -1.0]), np.array([3.0, 1.0]))
                   for p in PAIRS} for q in ("gyro_z", "accel_x")}
    entries["gyro_z"]["x2"] = (np.array([0.0, 1.0, 4.0]), np.array([-5.0, -2.0, -0.5]),
                               np.array([5.0, 2.0, 0.5]))
    return ThresholdTable(("gyro_z", "accel_x"), 100, 200.0, 0.01, 10.0, entries)


def test_table_lookup():
    tab = _table()
    lo, up = tab.bounds(1.5)
    assert lo.shape == (2, 3)
    assert up[0].tolist() == pytest.approx([3.0, 2.0, 3.0]) and up[1].tolist() == \
        pytest.approx([3.0, 3.0, 3.0])
    lo, up = tab.bounds_at([-1.0, 0.0, 1.0, 2.0, 3.99, 4.0, 100.0])
    np.testing.assert_allclose(up[:, 0, 1], [5, 5, 2, 2, 2, 0.5, 0.5])
    np.testing.assert_allclose(up[:, 0, 0], [3, 3, 3, 1, 1, 1, 1])
    np.testing.assert_allclose(lo[:, 1, 2], [-3, -3, -3, -1, -1, -1, -1])
    # a stamp a nanosecond-scale rounding before a segment start belongs to that segment
    assert tab.bounds(2.0 - 1e-9)[1][0, 0] == pytest.approx(1.0)


def test_table_save_load_round_trip(tmp_path):
    tab = _table()
    path = tmp_path / "t.json"
    save_table(tab, path)
    back = load_table(path)
    assert back.quantities == tab.quantities and back.window == 100
    np.testing.assert_array_equal(back.grid, tab.grid)
    np.testing.assert_array_equal(back.upper_grid, tab.upper_grid)
    doc = json.loads(path.read_text())
    assert doc["format"] == "flight_fdi.voter_thresholds/1" and doc["pairs"] == list(PAIRS)


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d.update(format="x"), "not a threshold table"),
    (lambda d: d.pop("window"), "missing key 'window'"),
    (lambda d: d["entries"]["gyro_z"].pop("x3"), "gyro_z x3 needs"),
    (lambda d: d["entries"]["gyro_z"]["x1"].update(lower=[5.0, -1.0]), "lower bound exceeds"),
    (lambda d: d["entries"]["gyro_z"]["x1"].update(t_start=[1.0, 2.0]), "start at 0"),
    (lambda d: d["entries"]["gyro_z"]["x1"].update(upper=[1.0]), "equal length"),
    (lambda d: d["entries"]["gyro_z"]["x1"].update(upper=["a", 1.0]), "non-numbers"),
    (lambda d: d.update(quantities=["gyro_w"]), "no entry for gyro_w|unknown quantity"),
    (lambda d: d.update(alpha=2.0), "alpha"),
    (lambda d: d.update(window=0), "window"),
])
def test_corrupt_tables_are_rejected(tmp_path, mutate, match):
    doc = _table().to_dict()
    mutate(doc)
    with pytest.raises(CoreError, match=match):
        table_from_dict(doc, "t.json")


def test_unreadable_table_files(tmp_path):
    with pytest.raises(CoreError, match="file not found"):
        load_table(tmp_path / "none.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    with pytest.raises(CoreError, match="not valid JSON"):
        load_table(bad)
