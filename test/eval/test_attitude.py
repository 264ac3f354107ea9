"""Attitude axis (seed 003): observability refusal, the zero-control disturbance monitor on crafted
inputs, the thruster-leak scenario end to end, its bag round trip and its Monte Carlo."""
from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from flight_fdi.core.actuator import (ActuatorConfig, ActuatorMonitor, attitude_model,
                                      monitor_record, require_observable, run_attitude,
                                      unobservable_states)
from flight_fdi.core.errors import CoreError
from flight_fdi.core.kalman import KalmanFilter
from flight_fdi.sim.attitude import (ActuatorFault, AttitudeSimConfig, parse_actuator_fault,
                                     read_attitude_bag, simulate_attitude, write_attitude_bag)
from flight_fdi.sim.errors import SimError


# --------------------------------------------------------------------------- observability

@pytest.mark.parametrize("measure, rank", [("angle", 3), ("angle+rate", 3), ("rate", 2)])
def test_rank_test_matches_the_hand_built_observability_matrix(measure, rank):
    model = attitude_model(measure)
    A = np.array([[0, 1, 0], [0, 0, 1], [0, 0, 0]], dtype=float)
    H = {"angle": [[1, 0, 0]], "angle+rate": [[1, 0, 0], [0, 1, 0]], "rate": [[0, 1, 0]]}[measure]
    H = np.array(H, dtype=float)
    O = np.vstack([H, H @ A, H @ A @ A])
    assert np.linalg.matrix_rank(O) == rank
    if rank == 3:
        assert require_observable(model, 100.0).observable
        assert unobservable_states(model) == []
    else:
        assert unobservable_states(model) == ["angle"]
        with pytest.raises(CoreError, match=r"not observable.*rank .* = 2 < n = 3.*angle"):
            require_observable(model, 100.0)


def test_unobservable_configuration_is_refused_everywhere():
    model = attitude_model("rate")
    with pytest.raises(CoreError, match="not observable"):
        ActuatorMonitor(model)
    t = np.arange(10) * 0.1
    with pytest.raises(CoreError, match="not observable"):
        run_attitude(model, t, np.zeros(10), np.zeros((10, 1)))
    with pytest.raises(SimError, match="not observable"):
        simulate_attitude(AttitudeSimConfig(duration_s=10.0, measure="rate"))


# --------------------------------------------------------------------------- the monitor

def feed(mon, t, u, d, sd=1e-7):
    """Feed disturbance estimates d (with std sd) and controls u at times t; the events."""
    events = []
    for ti, ui, di in zip(t, u, d):
        x = np.array([0.0, 0.0, di])
        P = np.diag([1e-8, 1e-10, sd**2])
        ev = mon.update(ti, ui, x, P)
        if ev is not None:
            events.append(ev)
    return events


def test_window_mean_above_threshold_raises_one_switch_to_reserve():
    cfg = ActuatorConfig(window_s=5.0, threshold=1e-5)
    mon = ActuatorMonitor(attitude_model(), cfg, axis="y")
    t = np.arange(200) * 0.1
    u = np.zeros(200)
    d = np.full(200, 2e-5)
    events = feed(mon, t, u, d)
    assert len(events) == 1  # latched after the switch
    ev = events[0]
    # the first window opens at t = 0 and closes at the first sample 5 s later
    assert ev.window_start_t == 0.0 and ev.t == pytest.approx(5.0)
    assert ev.samples == 51 and ev.mean == pytest.approx(2e-5)
    assert ev.axis == "y" and ev.action == "switch_to_reserve"
    assert ev.threshold == 1e-5 and "switch to reserve" in ev.message()
    assert len(mon.windows) == 3 and all(w.exceeded for w in mon.windows)
    mon.reset()
    assert feed(mon, t + 100.0, u, d)  # re-armed


def test_control_resets_the_window_and_small_or_uncertain_means_do_not_decide():
    cfg = ActuatorConfig(window_s=5.0, threshold=1e-5)
    t = np.arange(200) * 0.1
    # the mean is below the threshold: windows close, nothing is decided
    mon = ActuatorMonitor(attitude_model(), cfg)
    assert feed(mon, t, np.zeros(200), np.full(200, 0.9e-5)) == []
    assert mon.windows and not any(w.exceeded for w in mon.windows)
    # control fired at t = 3.0 s: the window restarts at the next zero-control sample (3.1 s)
    u = np.zeros(200)
    u[30] = 1.0
    mon = ActuatorMonitor(attitude_model(), cfg)
    (ev,) = feed(mon, t, u, np.full(200, -3e-5))
    assert ev.window_start_t == pytest.approx(3.1) and ev.t == pytest.approx(8.1)
    assert ev.mean == pytest.approx(-3e-5)
    # settle time after the firing delays the window by 2 s more
    mon = ActuatorMonitor(attitude_model(), ActuatorConfig(window_s=5.0, settle_s=2.0))
    (ev,) = feed(mon, t, u, np.full(200, -3e-5))
    assert ev.window_start_t == pytest.approx(5.0) and ev.t == pytest.approx(10.0)
    # an estimate whose std exceeds threshold / k_sigma is not evaluated
    mon = ActuatorMonitor(attitude_model(), cfg)
    assert feed(mon, t, np.zeros(200), np.full(200, 5e-5), sd=4e-6) == []
    assert mon.windows and not any(w.evaluated for w in mon.windows)


def test_monitor_rejects_bad_input():
    with pytest.raises(CoreError, match="threshold"):
        ActuatorConfig(threshold=0.0)
    mon = ActuatorMonitor(attitude_model())
    mon.update(1.0, 0.0, np.zeros(3), np.eye(3) * 1e-12)
    with pytest.raises(CoreError, match="increase"):
        mon.update(1.0, 0.0, np.zeros(3), np.eye(3) * 1e-12)
    with pytest.raises(CoreError, match="u must be"):
        mon.update(2.0, [0.0, 1.0], np.zeros(3), np.eye(3) * 1e-12)
    with pytest.raises(CoreError, match="3 values"):
        mon.update(3.0, 0.0, np.zeros(2), np.eye(3))


# --------------------------------------------------------------------------- the scenario

@pytest.fixture(scope="module")
def flights():
    nominal = simulate_attitude(AttitudeSimConfig(duration_s=600.0, seed=3))
    leak = simulate_attitude(AttitudeSimConfig(duration_s=600.0, seed=3,
                                               fault=ActuatorFault(300.0, 5e-5, "x")))
    return nominal, leak


def test_simulated_leak_is_a_torque_while_commanded_off(flights):
    nominal, leak = flights
    k0 = 3000  # 300 s at 10 Hz
    # truth disturbance on x jumps by the leak at the onset; y and z are untouched
    jump = leak.x_true[0, k0, 2] - leak.x_true[0, k0 - 1, 2]
    walk = np.abs(np.diff(nominal.x_true[0, :, 2])).max()
    assert jump == pytest.approx(5e-5, abs=5 * walk)
    assert np.array_equal(leak.x_true[1:], nominal.x_true[1:])
    # the controller keeps the attitude in its dead band, with and without the leak, and
    # fires more on the leaking axis (against the leak: u < 0)
    for f in flights:
        assert np.abs(f.x_true[:, :, 0]).max() < 0.05
        assert set(np.unique(f.u)) <= {-1.0, 0.0, 1.0}
        assert np.mean(f.u == 0) > 0.9
    assert np.sum(leak.u[k0:, 0] < 0) > 3 * max(1, np.sum(nominal.u[k0:, 0] < 0))


def test_monitor_detects_the_leak_and_stays_quiet_on_the_nominal_flight(flights):
    nominal, leak = flights
    cfg = ActuatorConfig()
    for axis in ("x", "y"):
        t, z, u = nominal.axis_data(axis)
        fwd, mon = run_attitude(nominal.model, t, z, u, config=cfg, axis=axis)
        assert not mon.fault
        assert mon.summary()["windows_evaluated"] > 50
        # the filter with the control input is consistent: gate rate near its 1e-3
        assert fwd.exceeded.mean() < 5e-3
        err = fwd.x[:, 2] - nominal.x_true["xyz".index(axis), :, 2]
        sd = np.sqrt(fwd.P[:, 2, 2])
        assert np.mean(np.abs(err[100:]) < 3 * sd[100:]) > 0.95
    t, z, u = leak.axis_data("x")
    fwd, mon = run_attitude(leak.model, t, z, u, config=cfg, axis="x")
    (ev,) = mon.events
    assert 300.0 < ev.t < 360.0
    assert ev.axis == "x" and abs(ev.mean) > cfg.threshold
    assert ev.window_start_t >= 300.0
    assert np.all(u[(t >= ev.window_start_t) & (t <= ev.t)] == 0)  # a zero-control window
    # the healthy y axis of the same flight stays quiet
    t, z, u = leak.axis_data("y")
    assert not run_attitude(leak.model, t, z, u, config=cfg, axis="y")[1].fault
    t, z, u = leak.axis_data("x")
    # the streaming use of a filter node: KalmanFilter one sample at a time, the monitor after
    # each step -- the same decision at the same time
    kf = KalmanFilter(leak.model)
    stream = ActuatorMonitor(leak.model, cfg, axis="x", keep_windows=False)
    events = []
    for k in range(len(t)):
        if k:
            kf.predict(t[k] - t[k - 1], u[k])
        kf.update(z[k])
        ev = stream.update(t[k], u[k], kf.x, kf.P)
        if ev is not None:
            events.append(ev)
    assert len(events) == 1 and events[0].t == ev_t_of(mon)
    assert events[0].mean == pytest.approx(mon.events[0].mean, rel=1e-6)
    assert stream.windows == [] and stream.last_window is not None
    # and the batch monitor over the recorded pass
    again = monitor_record(leak.model, fwd.t, fwd.u, fwd.x, fwd.P, cfg, axis="x")
    assert again.events == mon.events


def ev_t_of(mon):
    return mon.events[0].t


def test_bag_round_trip_and_the_attitude_command(tmp_path, capsys):
    cfg = AttitudeSimConfig(duration_s=200.0, seed=4, measure="angle+rate",
                            fault=parse_actuator_fault("leak:t=100,mag=-6e-5,axis=z"))
    flight = simulate_attitude(cfg)
    bag = tmp_path / "att"
    counts = write_attitude_bag(flight, bag)
    assert counts["/attitude/angle"] == 2000 and counts["/attitude/rate"] == 2000
    assert counts["/attitude/control"] == 1999
    data = read_attitude_bag(bag, "z")
    t, z, u = flight.axis_data("z")
    assert data.measure == "angle+rate"
    np.testing.assert_allclose(data.t, t, atol=1e-9)
    np.testing.assert_array_equal(data.z, z)
    np.testing.assert_array_equal(data.u, u)  # the control timing survives the bag
    np.testing.assert_array_equal(data.x_truth, flight.x_true[2])
    assert data.description["fault"]["axis"] == "z"

    from flight_fdi.cli import attitude

    parser = argparse.ArgumentParser(prog="flight-fdi")
    attitude.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["attitude", "analyze", str(bag), "--axis", "z", "--json"])
    assert args.func(args) == 0
    res = json.loads(capsys.readouterr().out)
    (ev,) = res["monitor"]["events"]
    assert ev["axis"] == "z" and ev["mean"] < -1e-5 and ev["t"] > 100.0
    args = parser.parse_args(["attitude", "analyze", str(bag), "--axis", "x"])
    assert args.func(args) == 0
    assert "no actuator fault" in capsys.readouterr().out


def test_attitude_study_type_errors():
    from flight_fdi.eval.attitude import AttitudeStudyConfig, run_attitude_study

    res = run_attitude_study(AttitudeStudyConfig(nominal=2, faulty=2, levels=(5e-5,),
                                                 duration_s=300.0, seed=1))
    e = res["metrics"]["errors"]
    assert (e["nominal"], e["faulty"]) == (2, 2)
    assert e["type_I"] == 0.0 and e["type_II"] == 0.0
    delays = [r["delay_s"] for r in res["flights"] if r["kind"] == "leak"]
    assert all(0.0 < d < 60.0 for d in delays)
