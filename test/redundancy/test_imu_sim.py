"""The three-IMU simulator: true inputs, pulse quantization, the seed-002 fault catalogue, seeding,
and the bag it writes."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from flight_fdi.sim import SimError
from flight_fdi.sim.faults import DEG_PER_HOUR, G0
from flight_fdi.sim.imu import (ARCSEC, IMU_MSG, IMU_TOPICS, ImuBatch, ImuErrorModel, ImuFault,
                                ImuSimConfig, maneuver_profile, output_variance, parse_imu_fault,
                                simulate_imus, simulate_quantity, true_inputs, write_imu_bag)
from flight_fdi.sim.profile import EARTH_RATE

Q = {q: j for j, q in enumerate(("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y",
                                 "accel_z"))}


def cfg(*faults, seed=1, duration=10.0, rate=100.0, **kw):
    return ImuSimConfig(duration_s=duration, rate_hz=rate, seed=seed,
                        faults=tuple(parse_imu_fault(f) for f in faults), **kw)


def test_true_inputs_follow_the_profile():
    prof = maneuver_profile(60.0)
    t = np.arange(0.0, 60.0, 0.01)
    u = true_inputs(prof, t)
    motion = prof.evaluate(t)
    np.testing.assert_array_equal(u[:, 0:2], motion.angular_rate)
    np.testing.assert_array_equal(u[:, 3:5], motion.specific_force)
    assert np.all(u[:, 5] == prof.g)
    # yaw rate = d(heading)/dt of the velocity vector (+ the vertical earth rate)
    heading = np.unwrap(np.arctan2(motion.velocity[:, 1], motion.velocity[:, 0]))
    moving = np.hypot(*motion.velocity.T) > 1.0
    dpsi = np.gradient(heading, t)
    wz = u[:, 2] - EARTH_RATE * math.sin(math.radians(prof.latitude_deg))
    np.testing.assert_allclose(wz[moving][5:-5], dpsi[moving][5:-5], atol=1e-4)
    assert np.abs(wz).max() > math.radians(5)  # the profile does turn


def test_pulse_output_keeps_the_integral_within_a_pulse():
    c = cfg(duration=5.0)
    batch = ImuBatch(c, 2)
    for q, j in Q.items():
        y, phase, _, _ = batch.continuous(j)
        counts = batch.quantize(y, phase, j)
        assert counts.dtype == np.int64
        integral = phase[..., None] + np.cumsum(y * c.dt / batch.pulse[j], axis=-1)
        total = np.cumsum(counts, axis=-1)
        err = integral - total  # in pulses
        assert np.all(err >= -1e-9) and np.all(err < 1 + 1e-9), q
    fl = simulate_imus(c)
    np.testing.assert_allclose(fl.output, fl.pulses * (ImuErrorModel().pulse() / c.dt))


def test_runs_are_reproducible_and_independent_of_the_batch():
    c = cfg(duration=2.0)
    b = ImuBatch(c, 3)
    three = simulate_quantity(b, "gyro_z")
    one = simulate_imus(c, run=2)
    np.testing.assert_array_equal(three[2], one.pulses[:, :, Q["gyro_z"]])
    again = simulate_imus(c, run=2)
    np.testing.assert_array_equal(one.pulses, again.pulses)
    assert not np.array_equal(three[0], three[1])
    # the three IMUs draw different errors
    assert len(set(one.bias[:, 0])) == 3


def test_error_statistics_match_the_parameters():
    e = ImuErrorModel()
    c = ImuSimConfig(duration_s=1.0, rate_hz=100.0, seed=3)
    b = ImuBatch(c, 2000)
    _, bias, scale, noise = b.draws(Q["accel_y"])
    assert np.std(bias) == pytest.approx(e.accel_bias_ug * 1e-6 * G0, rel=0.05)
    assert np.std(scale) == pytest.approx(e.accel_scale_ppm * 1e-6, rel=0.05)
    assert np.std(noise) == pytest.approx(e.accel_vrw_ug_rthz * 1e-6 * G0 / math.sqrt(0.01),
                                          rel=0.01)


def _pair(*faults, seed=4):
    nominal = simulate_imus(cfg(seed=seed))
    faulty = simulate_imus(cfg(*faults, seed=seed))
    return nominal, faulty


def test_output_faults():
    nom, fl = _pair("imu2:gyro_x:zero:t=3,end=6", "imu1:accel_z:doubled:t=5",
                    "imu3:gyro_y:full_scale:t=2,end=2.5,mag=-1")
    t = fl.t
    on = (t >= 3) & (t < 6)
    assert np.all(fl.output[1, on, Q["gyro_x"]] == 0.0)
    np.testing.assert_array_equal(fl.pulses[1, ~on, Q["gyro_x"]], nom.pulses[1, ~on, Q["gyro_x"]])
    on = t >= 5
    np.testing.assert_array_equal(fl.pulses[0, on, Q["accel_z"]],
                                  2 * nom.pulses[0, on, Q["accel_z"]])
    on = (t >= 2) & (t < 2.5)
    fs = math.radians(ImuErrorModel().gyro_full_scale_dps)
    np.testing.assert_allclose(fl.output[2, on, Q["gyro_y"]], -fs, rtol=1e-3)
    # nothing else changed
    untouched = np.ones((3, 6), dtype=bool)
    untouched[1, Q["gyro_x"]] = untouched[0, Q["accel_z"]] = untouched[2, Q["gyro_y"]] = False
    for k, j in zip(*np.nonzero(untouched)):
        np.testing.assert_array_equal(fl.pulses[k, :, j], nom.pulses[k, :, j])


@pytest.mark.parametrize("spec, shape", [
    ("imu3:gyro_z:step:t=4,mag=50deg/h", lambda tau: np.full_like(tau, 50 * DEG_PER_HOUR)),
    ("imu3:gyro_z:ramp:t=4,mag=10deg/h", lambda tau: 10 * DEG_PER_HOUR * tau),
    ("imu3:gyro_z:sine:t=4,mag=50deg/h,freq=1",
     lambda tau: 50 * DEG_PER_HOUR * np.sin(2 * np.pi * tau)),
    ("imu3:gyro_z:square:t=4,mag=50deg/h,freq=1",
     lambda tau: np.where(np.mod(tau, 1.0) < 0.5, 1, -1) * 50 * DEG_PER_HOUR),
    ("imu3:gyro_z:square_onoff:t=4,mag=50deg/h,freq=1",
     lambda tau: np.where(np.mod(tau, 1.0) < 0.5, 50 * DEG_PER_HOUR, 0.0)),
])
def test_parameter_faults_add_their_shape(spec, shape):
    """The fault's integral (faulty minus nominal pulses, same noise) follows the shape's
    integral within two pulses."""
    nom, fl = _pair(spec)
    j = Q["gyro_z"]
    q = ImuErrorModel().pulse()[j]
    dt = fl.config.dt
    extra = np.cumsum((fl.pulses[2, :, j] - nom.pulses[2, :, j])) * q   # rad
    tau = fl.t - 4.0
    e = np.where(tau >= 0, shape(tau), 0.0)
    want = np.cumsum(e) * dt
    assert np.max(np.abs(extra - want)) <= 2 * q
    np.testing.assert_array_equal(fl.pulses[:2], nom.pulses[:2])  # IMU1 and IMU2 untouched


def test_scale_factor_fault_scales_the_true_input():
    nom, fl = _pair("imu1:accel_x:scale:t=0,mag=0.01")
    j = Q["accel_x"]
    q = ImuErrorModel().pulse()[j]
    extra = np.cumsum(fl.pulses[0, :, j] - nom.pulses[0, :, j]) * q
    want = np.cumsum(0.01 * fl.truth[:, j]) * fl.config.dt
    assert np.max(np.abs(extra - want)) <= 2 * q


@pytest.mark.parametrize("text, want", [
    ("imu3:gyro_z:square:t=20,mag=20deg/h,freq=1",
     dict(imu=3, quantity="gyro_z", type="square", start_s=20.0, magnitude=20 * DEG_PER_HOUR,
          freq_hz=1.0)),
    ("IMU1:accel_y:step:t=5,end=9,mag=100ug",
     dict(imu=1, quantity="accel_y", end_s=9.0, magnitude=100e-6 * G0)),
    ("imu2:gyro_x:zero:t=5", dict(type="zero", magnitude=0.0)),
    ("imu2:gyro_x:full_scale:t=5", dict(type="full_scale", magnitude=1.0)),
    ("imu2:gyro_x:full_scale:t=5,mag=-1", dict(magnitude=-1.0)),
    ("imu1:accel_z:scale:t=1,mag=1000ppm", dict(type="scale", magnitude=1e-3)),
    ("imu1:gyro_y:square_onoff:t=1,mag=5deg/h,freq=5", dict(type="square_onoff", freq_hz=5.0)),
])
def test_parse_imu_fault(text, want):
    f = parse_imu_fault(text)
    for k, v in want.items():
        got = getattr(f, k)
        assert (math.isclose(got, v, rel_tol=1e-12) if isinstance(v, float) else got == v), k
    assert ImuFault.from_dict(f.to_dict()) == f


@pytest.mark.parametrize("text, match", [
    ("imu4:gyro_z:step:t=1,mag=1", "imu1, imu2 or imu3"),
    ("imu1:gyro_w:step:t=1,mag=1", "unknown quantity"),
    ("imu1:gyro_z:jump:t=1,mag=1", "unknown fault type"),
    ("imu1:gyro_z:step:mag=1", "start time t=... is required"),
    ("imu1:gyro_z:step:t=1,mag=3mg", "unknown unit 'mg'"),
    ("imu1:gyro_z:square:t=1,mag=1", "positive frequency"),
    ("imu1:gyro_z:zero:t=1,mag=2", "no magnitude"),
    ("imu1:gyro_z:step:t=1,mag=1,axis=x", "no axis= key"),
    ("imu1:gyro_z", "expected IMU:QUANTITY:TYPE"),
])
def test_parse_errors(text, match):
    with pytest.raises(SimError, match=match):
        parse_imu_fault(text)


def test_config_checks_faults_against_the_flight():
    with pytest.raises(SimError, match="after the end"):
        cfg("imu1:gyro_z:step:t=20,mag=1deg/h", duration=10.0)
    with pytest.raises(SimError, match="below half"):
        cfg("imu1:gyro_z:square:t=1,mag=1deg/h,freq=60", rate=100.0)
    with pytest.raises(SimError, match="whole number"):
        ImuSimConfig(duration_s=1.005, rate_hz=100.0)
    with pytest.raises(SimError, match="gyro_pulse_arcsec"):
        ImuErrorModel(gyro_pulse_arcsec=0.0)
    with pytest.raises(SimError, match="unknown parameters"):
        ImuErrorModel.from_dict({"gyro_bias": 1.0})


def test_bag_round_trip(tmp_path):
    from flight_fdi.bagio import read_messages

    fl = simulate_imus(cfg("imu3:gyro_z:step:t=1,mag=10deg/h", duration=2.0))
    counts = write_imu_bag(fl, str(tmp_path / "bag"))
    assert counts == {"/sim/fault": 1, **{t: fl.t.size for t in IMU_TOPICS}}
    got = {t: [] for t in IMU_TOPICS}
    stamps = {t: [] for t in IMU_TOPICS}
    doc = None
    for topic, msgtype, t_ns, m in read_messages(tmp_path / "bag"):
        if topic == "/sim/fault":
            doc = json.loads(m.data)
            continue
        assert msgtype == IMU_MSG
        stamp = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
        assert t_ns == stamp and m.header.frame_id == f"imu{topic[4]}"
        assert m.orientation_covariance[0] == -1.0
        stamps[topic].append(stamp)
        got[topic].append([m.angular_velocity.x, m.angular_velocity.y,
                           m.angular_velocity.z, m.linear_acceleration.x,
                           m.linear_acceleration.y, m.linear_acceleration.z,
                           m.angular_velocity_covariance[4], m.linear_acceleration_covariance[8]])
    var = output_variance(fl.config)
    for k, topic in enumerate(IMU_TOPICS):
        a = np.array(got[topic])
        np.testing.assert_array_equal(np.array(stamps[topic], dtype=np.int64), fl.stamp_ns)
        np.testing.assert_array_equal(a[:, 0:6], fl.output[k])
        assert a[0, 6] == var[1] and a[0, 7] == var[5]
    assert doc["format"] == "flight_fdi.sim.imu/1" and doc["faults"][0]["type"] == "step"
    # the quantization variance is part of the reported covariance: (q / dt)^2 / 6 for the gyro
    assert var[0] >= (ARCSEC / fl.config.dt) ** 2 / 6
