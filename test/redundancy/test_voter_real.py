"""The voter on real IMUs (Xsens DOT excerpt, test/redundancy/data/mimu): offsets are not faults,
an injected stuck gyro is isolated, time offsets are recovered, persistence holds the output;
the alignment functions on known answers; the vote / imu-csv commands."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from flight_fdi.core.errors import CoreError
from flight_fdi.core.voter_align import (align_times, correct_mounting, delay,
                                         estimate_mounting, estimate_time_offsets)
from flight_fdi.core.voter_core import Persistence, VoterCore, VoterModel, select
from flight_fdi.core.voting import (HEALTHY, PAIRS, QUANTITIES, SINGLE_FAULT, ThresholdTable,
                                    load_table, pair_differences, window_means)

DATA = Path(__file__).parent / "data" / "mimu"
TABLE = DATA / "thresholds_without_vertical_path_9.json"
RATE = 120.0
DPH = math.pi / 180 / 3600
CONFIRM = 60   # 0.5 s


@pytest.fixture(scope="module")
def rec(mimu_excerpt):
    """(stamp_ns (T,), P (T, 6, 3)) of the 15-s excerpt."""
    return mimu_excerpt


@pytest.fixture(scope="module")
def table():
    return load_table(TABLE)


def run(table, ns, P, confirm=CONFIRM, **kw):
    core = VoterCore(table, confirm=confirm, **kw)
    parts = [core.push(ns, P), core.finish()]
    status = np.concatenate([d.status for d in parts])
    t = np.concatenate([d.t_flight for d in parts])
    events = [e for d in parts for e in d.events]
    return core, t, status, events


# ------------------------------------------------------------------------ real recording

def test_the_units_disagree_by_large_constant_offsets(rec):
    _, P = rec
    mean = pair_differences(P).mean(axis=0)          # (6, 3)
    assert np.all(np.abs(mean[2, :2]) > 500 * DPH)   # gyro z x1, x2: ~ -1000 / +1350 deg/h
    assert np.abs(mean[0, 0]) > 2000 * DPH           # gyro x x1: ~ 3900 deg/h
    assert np.abs(mean[3:, 0]).max() > 0.1           # accelerometers: 0.1 - 0.5 m/s^2


def test_offsets_are_not_faults(rec, table):
    ns, P = rec
    core, t, status, events = run(table, ns, P)
    assert events == []
    assert len(status) > 1000 and np.mean(status > HEALTHY) <= 0.01
    assert t[0] >= core.model.learn_s - 1e-6               # no decision while learning
    # the learnt offsets are the units' real disagreement (hundreds of deg/h on gyro z)
    assert np.abs(core.offset[2, 1]) > 500 * DPH


def test_the_seed_statistic_faults_the_offsets(rec, table):
    """Without the offset model (the seed's plain window means) the same bounds see faults."""
    ns, P = rec
    plain = ThresholdTable(table.quantities, table.window, table.rate_hz, table.alpha,
                           table.duration_s, table.entries)
    _, _, status, events = run(plain, ns, P)
    assert np.mean(status > HEALTHY) > 0.9 and events


@pytest.mark.parametrize("imu", [2, 3])
def test_injected_stuck_gyro_is_isolated(rec, table, imu):
    ns, P = rec
    t = (ns - ns[0]) * 1e-9
    Pf = P.copy()
    Pf[t >= 10.0, 2, imu - 1] = 0.0
    _, _, _, events = run(table, ns, Pf)
    iso = [e for e in events if e[3]]
    assert iso, "not isolated"
    t_iso, q, _, k = iso[0]
    assert (QUANTITIES[q], k) == ("gyro_z", imu)
    assert 10.0 <= t_iso < 13.0


def test_time_offset_recovered(rec):
    """Delaying IMU3 by 4 whole samples (exact) moves its estimated offset by 4 / 120 s."""
    _, P = rec
    n = 600
    tau0, peak = estimate_time_offsets(P[:n + 10], RATE)
    late = P.copy()
    late[4:, :, 2] = P[:-4, :, 2]
    tau1, _ = estimate_time_offsets(late[:n + 10], RATE)
    assert tau1[2] - tau0[2] == pytest.approx(4 / RATE, abs=0.5e-3)
    assert tau1[1] == pytest.approx(tau0[1], abs=1e-9)
    assert peak[1] > 0.9 and peak[2] > 0.9


def test_time_offset_known_answer_and_alignment():
    """A band-limited random signal and its copy 2.5 samples late: offset 2.5 / rate; aligning
    undoes it (to the linear interpolation's accuracy)."""
    rng = np.random.default_rng(5)
    T = 3000
    g = window_means(window_means(rng.normal(size=(T, 3)), 30), 30)   # smooth rates
    P = np.zeros((T, 6, 3))
    P[:, :3, 0] = P[:, :3, 1] = g
    P[:, :3, 2] = delay(g, -2.5)                             # IMU3 sees it 2.5 samples later
    tau, _ = estimate_time_offsets(P, 100.0, max_lag_s=0.1, smooth=1)
    assert tau[1] == pytest.approx(0.0, abs=2e-4)          # the 0.01-sample grid
    assert tau[2] == pytest.approx(0.025, abs=1e-3)
    A = align_times(P, tau, 100.0)
    err = np.abs(A[20:-20, :3, 2] - g[20:-20]).max()
    assert err < 0.03 * np.abs(g).max()


def test_mounting_estimate_known_rotation():
    rng = np.random.default_rng(6)
    theta = np.radians([0.8, -1.2, 1.5])
    K = np.array([[0, -theta[2], theta[1]], [theta[2], 0, -theta[0]], [-theta[1], theta[0], 0]])
    R = np.eye(3) + K
    recs = []
    for _ in range(3):
        g = window_means(rng.normal(size=(4000, 6)), 40)
        P = np.zeros((4000, 6, 3))
        P[:, :, 0] = g
        for k in (1, 2):
            P[:, :3, k] = g[:, :3] @ R.T + 0.01 * k          # rotated + an offset
            P[:, 3:, k] = g[:, 3:]
        recs.append(P)
    m = estimate_mounting(recs, 100.0)
    np.testing.assert_allclose(m["gyro"][0], R, atol=1e-6)
    np.testing.assert_allclose(m["accel"][1], np.eye(3), atol=1e-6)
    back = correct_mounting(recs[0], m)          # IMU2 in IMU1's axes: IMU1 + a constant
    np.testing.assert_allclose(back[:, :3, 1] - back[:, :3, 1].mean(0),
                               recs[0][:, :3, 0] - recs[0][:, :3, 0].mean(0), atol=1e-9)


# ------------------------------------------------------------------------ persistence

def test_persistence_stops_a_single_window_excursion():
    """A single fault shorter than the confirmation does not isolate or switch the output;
    confirm = 1 (the old default) would switch it on the first decision."""
    seq = [SINGLE_FAULT] * 40 + [HEALTHY] * 100
    for confirm, want in ((60, []), (1, [(0, 0, 1)])):
        p = Persistence(1, confirm, release=0)
        changes = [c for s in seq for c in p.update([s], [1])]
        assert changes == want
        assert select(p.isolated, 1) == (1 if confirm == 60 else 2)


def test_persistence_latches_and_releases_after_healthy_windows():
    p = Persistence(1, 3, release=5)
    assert [p.update([SINGLE_FAULT], [3]) for _ in range(3)][-1] == [(0, 0, 3)]
    assert [p.update([HEALTHY], [0]) for _ in range(4)] == [[]] * 4   # latched
    assert p.update([HEALTHY], [0]) == [(0, 3, 0)]


def test_single_window_excursion_on_real_data_does_not_switch(rec, table):
    """A one-sample spike on IMU3's gyro z stays in the window mean for exactly one window
    (N decisions): a confirmation of one window + 1 decision does not isolate it and the output
    stays on IMU1; confirm = 1 (the old default) isolates IMU3 at once."""
    ns, P = rec
    t = (ns - ns[0]) * 1e-9
    Pf = P.copy()
    Pf[np.argmax(t >= 10.0), 2, 2] += 3000 * DPH * table.window    # +3000 deg/h in the mean
    N = table.window
    core, _, status, events = run(table, ns, Pf, confirm=N + 1)
    out = np.flatnonzero(status[:, 2] == SINGLE_FAULT)
    assert N - 30 <= out.size <= N            # the excursion is seen for one window ...
    assert events == []                       # ... and does not isolate or switch the output
    _, _, _, ev1 = run(table, ns, Pf, confirm=1)
    assert ev1 and (QUANTITIES[ev1[0][1]], ev1[0][3]) == ("gyro_z", 3)


# ------------------------------------------------------------------------ engine details

def test_batches_give_the_same_decisions(rec, table):
    ns, P = rec
    _, t_all, s_all, _ = run(table, ns, P)
    core = VoterCore(table, confirm=CONFIRM)
    parts = []
    for a in range(0, len(ns), 97):
        parts.append(core.push(ns[a:a + 97], P[a:a + 97]))
    parts.append(core.finish())
    np.testing.assert_array_equal(np.concatenate([d.status for d in parts]), s_all)
    np.testing.assert_allclose(np.concatenate([d.t_flight for d in parts]), t_all)


def test_model_validation():
    with pytest.raises(CoreError, match="prefilter"):
        VoterModel.from_dict({"prefilter": 0})
    with pytest.raises(CoreError, match="learning phase"):
        VoterModel.from_dict({"time_offsets_s": None})
    with pytest.raises(CoreError, match="mounting"):
        VoterModel.from_dict({"mounting": {"gyro": [[1, 0], [0, 1]]}})


# ------------------------------------------------------------------------ commands

def _cli(*args):
    return subprocess.run([sys.executable, "-m", "flight_fdi.cli.main", *map(str, args)],
                          capture_output=True, text=True, timeout=120)


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    out = tmp_path_factory.mktemp("mimu") / "bag"
    r = _cli("imu-csv", out, DATA)
    assert r.returncode == 0, r.stderr
    return out


def test_vote_json(bag):
    r = _cli("vote", bag, "--thresholds", TABLE, "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert set(doc["fraction_by_status"]) == {"healthy", "marginal", "single_fault",
                                              "multiple_fault"}
    assert sum(doc["fraction_by_status"].values()) == pytest.approx(1.0)
    assert doc["decisions"] > 1000 and doc["isolations"] == []
    assert doc["selected"][0]["imu"] == 1
    assert doc["first_decision_s"] == pytest.approx(5.0, abs=0.02)   # from the bag's start
    r = _cli("vote", bag, "--thresholds", TABLE)
    assert r.returncode == 0 and "isolations: 0" in r.stdout


def test_vote_errors_are_one_line(tmp_path, bag):
    for args in (("vote", tmp_path / "nothing"), ("vote", bag, "--thresholds",
                                                  tmp_path / "no.json"),
                 ("vote", bag, "--time-offsets", "x"), ("imu-csv", tmp_path / "o", tmp_path)):
        r = _cli(*args)
        assert r.returncode == 1 and r.stderr.count("\n") == 1 and "Traceback" not in r.stderr


def test_imu_csv_reports_non_increasing_times(tmp_path):
    rows = ["time,Acc_X,Acc_Y,Acc_Z,Gyr_X,Gyr_Y,Gyr_Z,Extra"]
    for i, t in enumerate([0.0, 0.01, 0.02, 0.02, 0.04]):
        rows.append(f"{t},{i},0,9.8,{i * 10},0,0,7")
    paths = []
    for k in range(3):
        p = tmp_path / f"u{k}.csv"
        p.write_text("\n".join(rows) + "\n")
        paths.append(p)
    r = _cli("imu-csv", tmp_path / "bag", *paths, "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["topics"]["/imu1/data"]["messages"] == 5
    assert doc["topics"]["/imu1/data"]["non_increasing_times"] == 1
    from flight_fdi.bagio.imu_reader import read_imu_triples

    d = read_imu_triples(tmp_path / "bag")
    assert d.P.shape == (4, 6, 3) and d.dropped["imu1_duplicate"] == 1
    np.testing.assert_allclose(d.P[1, :, 0], [math.radians(10), 0, 0, 1, 0, 9.8])


@pytest.mark.slow
def test_voter_calibrate_from_bags_cli(tmp_path, bag):
    """The command's plumbing (the same recording five times: a smoke test, not a judgement):
    a table with the model section that vote accepts."""
    out = tmp_path / "t.json"
    r = _cli("voter-calibrate", out, "--alpha", "0.002", "--json", "--from-bags", *[bag] * 5)
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert info["recordings"] == 5 and set(info["mounting"]) == {
        "imu2_gyro", "imu3_gyro", "imu2_accel", "imu3_accel"}
    table = load_table(out)
    model = VoterModel.from_table(table)
    assert model.learn_s == 5.0 and model.time_offsets_s is None and model.prefilter == 12
    assert table.window == 600 and table.alpha == 0.002
    assert model.baseline == "learn" and model.linear is None or "coef" in model.linear
    r = _cli("vote", bag, "--thresholds", out, "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["isolations"] == []
    r = _cli("voter-calibrate", out, "--force", "--baseline", "grow", "--no-linear",
             "--from-bags", *[bag] * 5)
    assert r.returncode == 0, r.stderr
    model = VoterModel.from_table(load_table(out))
    assert model.baseline == "grow" and model.linear is None
    r = _cli("vote", bag, "--thresholds", out)
    assert r.returncode == 0 and "offset baseline: grow; linear model on: -" in r.stdout


def test_grade_presets_change_the_simulated_errors():
    import argparse

    from flight_fdi.cli.voter_calibrate import add_imu_options, imu_config

    p = argparse.ArgumentParser()
    add_imu_options(p)
    nav = imu_config(p.parse_args([]))
    mems = imu_config(p.parse_args(["--grade", "mems", "--param", "gyro_bias_dph=100"]))
    tac = imu_config(p.parse_args(["--grade", "tactical"]))
    assert nav.errors.gyro_bias_dph == 0.05                      # the seed-002 defaults
    assert mems.errors.gyro_bias_dph == 100.0                    # --param wins
    assert mems.errors.accel_bias_ug == pytest.approx(5000.0)    # sim.imu3d's mems grade
    assert tac.errors.gyro_bias_dph == pytest.approx(1.0)
    assert tac.errors.gyro_arw_dph_rthz == pytest.approx(0.05)
