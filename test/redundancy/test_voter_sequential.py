"""The voter's sequential detector (CUSUM on the pair residuals, core/voter_sequential.py) and
the robust learnt offset (median of block means): known answers, batch invariance, validation,
and on the real excerpt (test/redundancy/data/mimu, CC BY 4.0): the nominal excerpt is not
faulted, an injected accelerometer step is isolated on the right IMU where the window bounds
alone miss it, a start-up transient does not shift the learnt offset."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from flight_fdi.cli.errors import CliError
from flight_fdi.cli.voter_calibrate import parse_drift
from flight_fdi.core.errors import CoreError
from flight_fdi.core.voter_core import VoterCore, VoterModel, block_median
from flight_fdi.core.voter_kernel import cusum
from flight_fdi.core.voter_sequential import Cusum, check, thresholds
from flight_fdi.core.voting import QUANTITIES, load_table, table_from_dict

SEQ_TABLE = Path(__file__).parent / "data" / "mimu" / "thresholds_seq_without_vertical_path_9.json"
DPH = math.pi / 180 / 3600
CONFIRM = 60   # 0.5 s


@pytest.fixture(scope="module")
def table():
    """Calibrated on the 17 other recordings with the defaults (robust offset, CUSUM)."""
    return load_table(SEQ_TABLE)


def without_sequential(table, **model):
    d = table.to_dict()
    d["model"] = {**d["model"], "sequential": None, **model}
    return table_from_dict(d)


def run(table, ns, P, batch=None):
    core = VoterCore(table, confirm=CONFIRM)
    step = batch or len(ns)
    parts = [core.push(ns[a:a + step], P[a:a + step]) for a in range(0, len(ns), step)]
    parts.append(core.finish())
    cat = lambda name: np.concatenate([getattr(d, name) for d in parts])  # noqa: E731
    return core, cat, [e for d in parts for e in d.events if e[3]]


# ------------------------------------------------------------------------ known answers

def test_cusum_known_answer_constant_shift():
    """e = delta > nu: g+ rises by (delta - nu) dt per sample; the alarm comes at the first
    sample where it exceeds h: n = ceil(h / ((delta - nu) dt))."""
    dt, nu, delta, h = 1 / 120, 0.025, 0.075, 0.5
    e = np.full((600, 2), delta)
    e[:, 1] = -delta                                     # the other sign: g-
    z = np.zeros(2)
    g, inside = cusum(e, np.full(2, nu), np.full(2, h), dt, z.copy(), z.copy(), z.copy())
    n = np.arange(1, 601)
    np.testing.assert_allclose(g[:, 0], n * (delta - nu) * dt)
    np.testing.assert_allclose(g[:, 1], -n * (delta - nu) * dt)
    first = int(math.ceil(h / ((delta - nu) * dt) - 1e-9))
    assert np.all(inside[:first - 1]) and not np.any(inside[first:])


def test_cusum_equals_a_reference_loop_and_is_batch_invariant():
    rng = np.random.default_rng(16)
    e = rng.normal(0.0, 1.0, (500, 3)) + np.r_[np.zeros(250), np.full(250, 0.8)][:, None]
    nu, h, dt = np.array([0.3, 0.5, 0.0]), np.array([0.4, 0.3, 2.0]), 0.01
    gp, gn = np.zeros(3), np.zeros(3)
    ref = np.empty_like(e)
    for j in range(e.shape[0]):
        gp = np.maximum(0, gp + (e[j] - nu) * dt)
        gn = np.maximum(0, gn + (-e[j] - nu) * dt)
        ref[j] = np.where(gp >= gn, gp, -gn)
    state = [np.zeros(3) for _ in range(3)]
    parts = [cusum(e[a:a + 37], nu, h, dt, *state) for a in range(0, 500, 37)]
    g = np.concatenate([p[0] for p in parts])
    inside = np.concatenate([p[1] for p in parts])
    np.testing.assert_allclose(g, ref, atol=1e-12)
    np.testing.assert_array_equal(inside, np.abs(ref) <= h)
    np.testing.assert_allclose(state[2], np.abs(ref).max(axis=0))     # the running peak


def test_thresholds_and_the_cusum_of_a_table():
    peaks = [np.full((2, 3), 0.1), np.array([[0.2, 0.05, 0.1], [1.0, 1.0, 1.0]])]
    sec = thresholds(peaks, ("accel_x", "gyro_z"), {"accel_x": 0.02}, 3.0, 0.05)
    assert sec["threshold"] == {"accel_x": pytest.approx([0.6, 0.3, 0.3])}
    assert sec["drift"] == {"accel_x": 0.02} and sec["calibration_hours"] == 0.05
    c = Cusum(check(sec, "t"), ("accel_x", "gyro_z"), 100.0)
    g, inside = c.step(np.full((1000, 2, 3), 10.0))          # gyro z has no CUSUM: never out
    assert not inside[-1, 0].any() and inside[:, 1].all()
    with pytest.raises(CoreError, match="margin"):
        thresholds(peaks, ("accel_x",), {"accel_x": 0.02}, 0.5, 0.05)


def test_block_median_ignores_a_transient_block():
    rows = np.full((600, 2), 1.0)
    rows[:120] = 5.0                                         # the first of five blocks
    np.testing.assert_allclose(block_median(rows, 5), 1.0)
    np.testing.assert_allclose(block_median(rows, 1), rows.mean(axis=0))   # 1: the mean
    np.testing.assert_allclose(block_median(rows[:3], 5), rows[:3].mean(axis=0))


def test_validation():
    with pytest.raises(CoreError, match="drift"):
        check({"threshold": {}}, "t")
    with pytest.raises(CoreError, match="3 values > 0"):
        check({"drift": {"accel_x": 0.1}, "threshold": {"accel_x": [1, 0, 1]}}, "t")
    with pytest.raises(CoreError, match="no drift"):
        check({"drift": {}, "threshold": {"accel_x": [1, 1, 1]}}, "t")
    with pytest.raises(CoreError, match="fixed offset"):
        VoterModel.from_dict({"learn_s": 5, "baseline": "grow",
                              "sequential": {"drift": {"accel_x": 0.1}}})
    with pytest.raises(CoreError, match="offset_blocks"):
        VoterModel.from_dict({"offset_blocks": 0})
    assert parse_drift("off,0.025") == {q: 0.025 for q in QUANTITIES if q.startswith("accel")}
    assert parse_drift("50,off")["gyro_z"] == pytest.approx(50 * DPH)
    for bad in ("off,off", "1", "a,b", "-1,0.1"):
        with pytest.raises(CliError):
            parse_drift(bad)


# ------------------------------------------------------------------------ the real excerpt

def test_nominal_excerpt_is_not_faulted(mimu_excerpt, table):
    ns, P = mimu_excerpt
    core, cat, iso = run(table, ns, P)
    assert iso == [] and np.mean(cat("status") > 0) <= 0.01
    assert core.model.sequential and set(core.model.sequential["threshold"]) == {
        "accel_x", "accel_y", "accel_z"}
    # the statistic stays below its thresholds with room to spare on this held-out recording
    h = np.array([core.model.sequential["threshold"][q] for q in ("accel_x", "accel_y",
                                                                   "accel_z")])
    assert np.all(np.abs(cat("cusum")[:, 3:]).max(axis=0) < 0.7 * h)


@pytest.mark.parametrize("imu", [2, 3])
def test_accel_step_isolated_by_the_sequential_detector(mimu_excerpt, table, imu):
    """0.07 m/s^2 on accel x from 6 s (9 s of post-fault data): the CUSUM isolates the right IMU
    within the excerpt; the window bounds alone (same table without it) see nothing."""
    ns, P = mimu_excerpt
    t = (ns - ns[0]) * 1e-9
    Pf = P.copy()
    Pf[t >= 6.0, 3, imu - 1] += 0.07
    _, _, iso = run(table, ns, Pf)
    assert iso, "not isolated"
    t_iso, q, _, k = iso[0]
    assert (QUANTITIES[q], k) == ("accel_x", imu) and 6.0 < t_iso < 15.0
    _, _, iso = run(without_sequential(table), ns, Pf)
    assert iso == []


def test_sequential_detector_is_batch_invariant(mimu_excerpt, table):
    ns, P = mimu_excerpt
    Pf = P.copy()
    Pf[(ns - ns[0]) * 1e-9 >= 6.0, 3, 1] += 0.07
    _, whole, ev1 = run(table, ns, Pf)
    _, parts, ev2 = run(table, ns, Pf, batch=89)
    np.testing.assert_array_equal(parts("status"), whole("status"))
    np.testing.assert_allclose(parts("cusum"), whole("cusum"), rtol=1e-9, atol=1e-12)
    assert ev1 == ev2


def test_startup_transient_does_not_shift_the_offset(mimu_excerpt, table):
    """vertical/path_9 starts with IMU3's gyro z ~400 deg/h off for about a second: the mean of
    the first 5 s carries a fifth of it into the offset and every later decision; the median of
    the five 1-s block means does not."""
    ns, P = mimu_excerpt
    dev = {}
    for blocks in (1, 5):
        _, cat, _ = run(without_sequential(table, offset_blocks=blocks), ns, P)
        dev[blocks] = np.median(cat("deviation")[:, 2, 1]) / DPH      # gyro z, x2 = P2 - P3
    assert dev[1] < -60 and abs(dev[5]) < 0.5 * abs(dev[1])
