"""3-D flights as bags (the 3-D estimator's input contract), the CLI, the sample flights."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml

from flight_fdi.bagio import cdr, get_typestore, read_messages
from flight_fdi.cli.main import main
from flight_fdi.sim.bag3d import TRUTH_NAMES, truth_matrix, write_bag3d
from flight_fdi.sim.faults import FaultSpec3D, parse_fault
from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
from flight_fdi.sim.trajectory import TrajectoryConfig

SAMPLES = {"ins3d_nominal": None, "ins3d_accel_y_step": ("accel", "y"),
           "ins3d_gyro_x_step": ("gyro", "x")}


@pytest.fixture(scope="module")
def flight_and_bag(tmp_path_factory):
    faults = tuple(parse_fault(s, FaultSpec3D) for s in
                   ("accel:step:t=20,mag=2mg,axis=z", "ref:dropout:t=30,end=35"))
    fl = simulate3d(Sim3DConfig(trajectory=TrajectoryConfig(duration_s=120), grade="tactical",
                                faults=faults, seed=7))
    path = tmp_path_factory.mktemp("sim3d") / "flight"
    counts = write_bag3d(fl, str(path), velocity_rate_hz=50, imu_rate_hz=20, fix_rate_hz=10,
                         truth_rate_hz=2)
    msgs: dict[str, list] = {}
    for topic, msgtype, t_ns, msg in read_messages(path):
        msgs.setdefault(topic, []).append((msgtype, t_ns, msg))
    return fl, path, counts, msgs


def _stamp(msg) -> int:
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


def test_topics_types_counts_frames(flight_and_bag):
    fl, path, counts, msgs = flight_and_bag
    want = {"/ins/velocity": ("geometry_msgs/msg/TwistStamped", 6001, "enu"),
            "/ins/imu": ("sensor_msgs/msg/Imu", 2400, "base_link"),
            "/ins/fix": ("sensor_msgs/msg/NavSatFix", 1201, "base_link"),
            "/reference/velocity": ("geometry_msgs/msg/TwistWithCovarianceStamped", 1151, "enu"),
            "/reference/fix": ("sensor_msgs/msg/NavSatFix", 1151, "gnss"),
            "/sim/truth": ("flight_fdi_msgs/msg/FilterState", 241, "enu")}
    for topic, (msgtype, n, frame) in want.items():
        got = msgs[topic]
        assert len(got) == n == counts[topic], topic
        assert all(m[0] == msgtype and m[2].header.frame_id == frame for m in got), topic
        assert all(t == _stamp(m) for _, t, m in got), topic  # receive time = header stamp
    assert counts["/sim/fault"] == 1


def test_ins_topics_carry_the_ins_solution(flight_and_bag):
    fl, _, _, msgs = flight_and_bag
    v = np.array([[m.twist.linear.x, m.twist.linear.y, m.twist.linear.z]
                  for _, _, m in msgs["/ins/velocity"]])
    assert np.array_equal(v, fl.ins.v[::2])
    imu = [m for _, _, m in msgs["/ins/imu"]]
    q = np.array([[m.orientation.w, m.orientation.x, m.orientation.y, m.orientation.z]
                  for m in imu])
    assert np.array_equal(q, fl.ins.q[5::5])
    w = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z]
                  for m in imu])
    f = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z]
                  for m in imu])
    # the mean rate over the interval since the previous message: sums give the increments
    assert np.allclose(w.sum(0) * 0.05, fl.gyro.rate.sum(0) * fl.dt, rtol=1e-12, atol=1e-15)
    assert np.allclose(f[3], fl.accel.rate[15:20].mean(0), rtol=1e-14)
    assert f[0, 2] == pytest.approx(9.8, abs=0.05)  # gravity as an accelerometer senses it
    fix = np.array([[m.latitude, m.longitude, m.altitude] for _, _, m in msgs["/ins/fix"]])
    assert np.allclose(fix[:, 0], np.degrees(fl.ins.lat[::10]), rtol=0, atol=1e-15)
    assert np.array_equal(fix[:, 2], fl.ins.h[::10])


def test_reference_topics(flight_and_bag):
    fl, _, _, msgs = flight_and_bag
    ref = [m for _, _, m in msgs["/reference/velocity"]]
    v = np.array([[m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.linear.z]
                  for m in ref])
    assert np.array_equal(v, fl.gnss.v)
    cov = np.asarray(ref[0].twist.covariance).reshape(6, 6)
    assert np.allclose(np.diag(cov)[:3], fl.gnss.vel_var) and np.diag(cov)[3:].min() == 1e6
    t = np.array([_stamp(m) for m in ref]) / 1e9 - 1_700_000_000
    assert not np.any((t >= 30) & (t < 35)) and np.allclose(t, fl.gnss.t, atol=1e-9)
    fixes = [m for _, _, m in msgs["/reference/fix"]]
    assert fixes[0].position_covariance_type == 2 and fixes[0].status.service == 1
    assert np.allclose(np.diag(np.reshape(fixes[0].position_covariance, (3, 3))),
                       fl.gnss.pos_var)


def test_truth_and_description(flight_and_bag):
    fl, path, _, msgs = flight_and_bag
    truth = [m for _, _, m in msgs["/sim/truth"]]
    assert list(truth[0].state_names) == TRUTH_NAMES and truth[0].channel == "truth3d"
    x = np.array([m.x for m in truth])
    assert np.array_equal(x, truth_matrix(fl, np.arange(0, fl.t.size, 50)))
    assert truth[0].dt == 0.0 and truth[1].dt == 0.5
    i = TRUTH_NAMES.index("accel_fault_z")
    t = np.arange(241) * 0.5
    assert np.allclose(x[:, i], np.where(t >= 20, 2e-3 * 9.80665, 0.0), rtol=1e-12, atol=0)
    # the codec's message equals rosbags' own serialization of the same message
    store = get_typestore()
    raw = store.serialize_cdr(truth[7], "flight_fdi_msgs/msg/FilterState")
    assert np.array_equal(x[7], np.asarray(store.deserialize_cdr(
        bytes(raw), "flight_fdi_msgs/msg/FilterState").x))
    (_, _, s), = msgs["/sim/fault"]
    doc = json.loads(s.data)
    assert doc["format"] == "flight_fdi.sim3d/1" and doc["imu"]["name"] == "tactical"
    assert [f["type"] for f in doc["faults"]] == ["step", "dropout"]
    assert doc["faults"][0]["axis"] == "z" and doc["topics"]["imu_rate_hz"] == 20
    meta = yaml.safe_load((path / "metadata.yaml").read_text())
    assert json.loads(meta["rosbag2_bagfile_information"]["custom_data"]["flight_fdi.sim3d"]) \
        == doc


def test_fast_encoders_equal_rosbags():
    store = get_typestore()
    stamp = np.array([1_700_000_000_123_456_789, 42])
    rng = np.random.default_rng(0)
    for frame in ("", "a", "enu", "base_link", "gnss_antenna"):
        vals = rng.normal(size=(2, 37))
        p = cdr.encode_doubles(cdr.IMU, stamp, frame, vals)
        m = store.deserialize_cdr(p[0], cdr.IMU)
        assert bytes(store.serialize_cdr(m, cdr.IMU)) == p[0]
        assert m.header.frame_id == frame and m.orientation.w == vals[0, 3]
        llh = rng.normal(size=(2, 3))
        p = cdr.encode_navsatfix(stamp, frame, -1, 1, llh, np.arange(9.0), 2)
        m = store.deserialize_cdr(p[1], cdr.NAVSATFIX)
        assert bytes(store.serialize_cdr(m, cdr.NAVSATFIX)) == p[1]
        assert (m.status.status, m.status.service, m.position_covariance_type) == (-1, 1, 2)
        assert m.altitude == llh[1, 2]


def test_cli_ins3d(tmp_path, capsys):
    out = tmp_path / "b"
    rc = main(["simulate", str(out), "--model", "ins3d", "--duration", "60", "--profile",
               "straight", "--grade", "mems", "--imu-rate", "10", "--velocity-rate", "10",
               "--fault", "gyro:step:t=30,mag=10deg/h,axis=z", "--gnss", "latency_s=0.05",
               "--ref-rate", "5"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "60 s at 100 Hz" in text and "gyro step on z at 30 s" in text
    doc = json.loads(yaml.safe_load((out / "metadata.yaml").read_text())[
        "rosbag2_bagfile_information"]["custom_data"]["flight_fdi.sim3d"])
    assert doc["gnss"]["latency_s"] == 0.05 and doc["gnss"]["rate_hz"] == 5
    assert doc["trajectory"]["profile"] == "straight" and doc["imu"]["name"] == "mems"


@pytest.mark.parametrize("args, msg", [
    (["--grade", "tactical"], "apply to --model ins3d only"),
    (["--model", "ins3d", "--channel", "y"], "single-axis model"),
    (["--model", "ins3d", "--ins-rate", "50"], ">= 100 Hz"),
    (["--model", "ins3d", "--speed", "20"], "50..250"),
    (["--model", "ins3d", "--gnss", "latency=3"], "unknown parameter"),
    (["--model", "ins3d", "--fault", "ref:latency:t=10,mag=2"], "latency must be within"),
    (["--model", "ins3d", "--fault", "gyro:step:t=10,mag=1,axis=w"], "x, y or z"),
    (["--model", "ins3d", "--imu-rate", "30"], "must divide"),
])
def test_cli_errors_are_one_line(tmp_path, capsys, args, msg):
    rc = main(["simulate", str(tmp_path / "x"), "--duration", "20"] + args)
    err = capsys.readouterr().err
    assert rc == 1 and msg in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "x").exists()


def test_single_axis_sample_bag_is_unchanged(repo_root, tmp_path):
    """The single-axis simulator (and its defaults through the extended CLI) still writes the
    sample bag byte for byte."""
    assert main(["simulate", str(tmp_path / "nominal"), "--seed", "0"]) == 0
    for name in ("nominal.mcap", "metadata.yaml"):
        assert (tmp_path / "nominal" / name).read_bytes() == \
            (repo_root / "bags" / "nominal" / name).read_bytes()


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_sample_flights(repo_root, name):
    path = repo_root / "bags" / name
    size = sum(f.stat().st_size for f in path.rglob("*") if f.is_file())
    assert size < 10e6, f"{name} is {size / 1e6:.2f} MB"
    doc = json.loads(yaml.safe_load((path / "metadata.yaml").read_text())[
        "rosbag2_bagfile_information"]["custom_data"]["flight_fdi.sim3d"])
    assert doc["trajectory"]["profile"] == "cruise_turns" and doc["trajectory"]["rate_hz"] >= 100
    want = SAMPLES[name]
    if want is None:
        assert doc["faults"] == []
    else:
        (f,) = doc["faults"]
        assert (f["target"], f["type"], f["axis"]) == (want[0], "step", want[1])
        # a turn follows the onset: the truth heading changes by > 45 deg after it
        q = np.array([m.x[6:10] for _, _, _, m in read_messages(path, ["/sim/truth"])])
        t = np.arange(len(q)) / doc["topics"]["truth_rate_hz"]
        yaw = np.unwrap(np.arctan2(2 * (q[:, 0] * q[:, 3] + q[:, 1] * q[:, 2]),
                                   1 - 2 * (q[:, 2] ** 2 + q[:, 3] ** 2)))
        after = yaw[t > f["start_s"]]
        assert math.degrees(np.ptp(after)) > 45
    assert "bags/" + name in (repo_root / "bags" / "README.md").read_text()
