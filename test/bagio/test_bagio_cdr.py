"""The vectorised CDR codec agrees byte for byte / value for value with rosbags' serializer."""
from __future__ import annotations

import numpy as np
import pytest

from flight_fdi.bagio import BagError, cdr, get_typestore

FRAMES = ["", "a", "ins", "abcd", "abcdefg", "reference", "a_much_longer_frame_id_123"]


def _twist_msg(store, msgtype, sec, nsec, frame, vals, cov=None):
    T = store.types
    header = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec),
                                      frame_id=frame)
    V3 = T["geometry_msgs/msg/Vector3"]
    twist = T["geometry_msgs/msg/Twist"](linear=V3(x=vals[0], y=vals[1], z=vals[2]),
                                         angular=V3(x=vals[3], y=vals[4], z=vals[5]))
    if msgtype == cdr.TWIST_STAMPED:
        return T[msgtype](header=header, twist=twist)
    inner = T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.asarray(cov))
    return T[msgtype](header=header, twist=inner)


@pytest.mark.parametrize("msgtype", [cdr.TWIST_STAMPED, cdr.TWIST_COV_STAMPED])
@pytest.mark.parametrize("frame", FRAMES)
def test_encode_matches_rosbags(msgtype, frame):
    store = get_typestore()
    rng = np.random.default_rng(len(frame))
    n = 5
    stamp = np.array([0, 1, 1_700_000_000_123_456_789, 2**31 * 10**9 - 1, -1_500_000_000])
    twist = rng.normal(size=(n, 6))
    cov = rng.normal(size=(n, 36)) if msgtype == cdr.TWIST_COV_STAMPED else None
    got = cdr.encode(msgtype, stamp, frame, twist, cov)
    for i in range(n):
        sec, nsec = divmod(int(stamp[i]), 10**9)
        msg = _twist_msg(store, msgtype, sec, nsec, frame, twist[i],
                         None if cov is None else cov[i])
        want = bytes(store.serialize_cdr(msg, msgtype, little_endian=True))
        assert got[i] == want, (frame, i)


@pytest.mark.parametrize("little", [True, False])
@pytest.mark.parametrize("msgtype", [cdr.TWIST_STAMPED, cdr.TWIST_COV_STAMPED])
def test_decode_matches_rosbags(msgtype, little):
    store = get_typestore()
    rng = np.random.default_rng(7)
    payloads, msgs = [], []
    for i, frame in enumerate(FRAMES * 2):  # several frame_id lengths mixed in one series
        vals = rng.normal(size=6)
        cov = rng.normal(size=36)
        msg = _twist_msg(store, msgtype, int(rng.integers(-2**31, 2**31)),
                         int(rng.integers(0, 10**9)), frame, vals, cov)
        payloads.append(bytes(store.serialize_cdr(msg, msgtype, little_endian=little)))
        msgs.append(store.deserialize_cdr(payloads[-1], msgtype))
    stamp, twist, cov = cdr.decode(msgtype, payloads)
    for i, m in enumerate(msgs):
        tw = m.twist if msgtype == cdr.TWIST_STAMPED else m.twist.twist
        assert stamp[i] == m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
        want = [tw.linear.x, tw.linear.y, tw.linear.z, tw.angular.x, tw.angular.y, tw.angular.z]
        assert twist[i].tolist() == want
        if msgtype == cdr.TWIST_COV_STAMPED:
            assert np.array_equal(cov[i], m.twist.covariance)
        else:
            assert cov is None
    # picking columns gathers the same values
    s2, tw2, cov2 = cdr.decode(msgtype, payloads, twist_cols=[1],
                               cov_cols=[7] if msgtype == cdr.TWIST_COV_STAMPED else None)
    assert np.array_equal(s2, stamp) and np.array_equal(tw2[:, 0], twist[:, 1])
    if msgtype == cdr.TWIST_COV_STAMPED:
        assert np.array_equal(cov2[:, 0], cov[:, 7])


def test_decode_round_trip_of_encode_and_payloads_view():
    stamp = np.arange(4) * 20_000_000 + 1_700_000_000 * 10**9
    twist = np.arange(24, dtype=float).reshape(4, 6)
    raw = cdr.encode(cdr.TWIST_STAMPED, stamp, "ins", twist)
    pl = cdr.Payloads.from_list(raw)
    assert len(pl) == 4 and pl[2] == raw[2]
    s, tw, _ = cdr.decode(cdr.TWIST_STAMPED, pl.take(np.array([3, 1])))
    assert s.tolist() == [stamp[3], stamp[1]] and np.array_equal(tw, twist[[3, 1]])


def test_decode_rejects_malformed_messages():
    good = cdr.encode(cdr.TWIST_STAMPED, np.array([5]), "ins", np.zeros((1, 6)))[0]
    with pytest.raises(BagError, match="#1: .* too short"):
        cdr.decode(cdr.TWIST_STAMPED, [good, good[:-8]], what="msg")
    with pytest.raises(BagError, match="not a CDR message"):
        cdr.decode(cdr.TWIST_STAMPED, [b"\x07\x07" + good[2:]])
    with pytest.raises(BagError, match="too short"):
        cdr.decode(cdr.TWIST_COV_STAMPED, [good])  # a TwistStamped is no TwistWithCovariance
    with pytest.raises(BagError, match="does not support"):
        cdr.decode("std_msgs/msg/String", [good])


def test_decode_empty_series():
    s, tw, cov = cdr.decode(cdr.TWIST_COV_STAMPED, [], cov_cols=[0])
    assert s.shape == (0,) and tw.shape == (0, 6) and cov.shape == (0, 1)


@pytest.mark.parametrize("little", [True, False])
def test_filter_state_fast_decoder_matches_rosbags(little):
    store = get_typestore()
    T = store.types
    rng = np.random.default_rng(3)
    payloads, msgs = [], []
    variants = [("sim", "x", ["velocity_error", "tilt", "accel_bias", "gyro_drift"]),
                ("", "y", ["a", "bb", "ccc"]), ("frame7", "longer_channel", ["s"]),
                ("sim", "x", ["velocity_error", "tilt", "accel_bias", "gyro_drift"])]
    for i in range(12):
        frame, channel, names = variants[i % len(variants)]
        header = T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=1_700_000_000 + i, nanosec=7 * i),
            frame_id=frame)
        msg = T["flight_fdi_msgs/msg/FilterState"](
            header=header, channel=channel, state_names=names, x=rng.normal(size=len(names)),
            p=rng.normal(size=len(names) ** 2), z=np.zeros(i % 2), r=np.zeros(0), h=np.zeros(0),
            u=np.zeros(0), dt=0.1 * i, fused=True, gated=False, reset=False)
        payloads.append(bytes(store.serialize_cdr(msg, "flight_fdi_msgs/msg/FilterState",
                                                  little_endian=little)))
        msgs.append(msg)
    stamps, channels, names, xs = cdr.decode_filter_state_x(payloads)
    for i, m in enumerate(msgs):
        assert stamps[i] == m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
        assert channels[i] == m.channel and list(names[i]) == m.state_names
        assert np.array_equal(xs[i], m.x)
    with pytest.raises(BagError, match="#0: not a valid"):
        cdr.decode_filter_state_x([payloads[0][:40]])


@pytest.mark.parametrize("text", ["", "a", '{"kind": "step", "mag": 0.01}', "température ✓",
                                  "x" * 1000])
def test_decode_string_matches_rosbags(text):
    store = get_typestore()
    for little in (True, False):
        msg = store.types[cdr.STRING](data=text)
        payload = store.serialize_cdr(msg, cdr.STRING, little_endian=little)
        assert cdr.decode_string(payload) == text


@pytest.mark.parametrize("cut, message", [(3, "not a CDR message"),
                                          (-1, "not a valid std_msgs/msg/String")])
def test_decode_string_rejects_truncated_messages(cut, message):
    store = get_typestore()
    payload = bytes(store.serialize_cdr(store.types[cdr.STRING](data="hello"), cdr.STRING))
    with pytest.raises(BagError, match=message):
        cdr.decode_string(payload[:cut], what="m")
    with pytest.raises(BagError, match="not UTF-8"):
        cdr.decode_string(payload[:8] + b"\xff\xfe\xfd\xfc\x00" + payload[13:], what="m")


@pytest.mark.parametrize("little", [True, False])
def test_filter_state_full_decoder_matches_rosbags(little):
    store = get_typestore()
    T = store.types
    rng = np.random.default_rng(11)
    payloads, msgs = [], []
    for i in range(16):
        n, m, p = 1 + i % 4, i % 3, i % 2        # empty and non-empty sequences of every kind
        header = T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=1_700_000_000 - 5 * i, nanosec=11 * i),
            frame_id="enu" * (i % 3))
        msg = T["flight_fdi_msgs/msg/FilterState"](
            header=header, channel="xy"[i % 2], state_names=[f"s{k}" for k in range(n)],
            x=rng.normal(size=n), p=rng.normal(size=n * n), z=rng.normal(size=m),
            r=rng.normal(size=m * m), h=rng.normal(size=m * n), u=rng.normal(size=p),
            dt=0.01 * i, fused=bool(i & 1), gated=bool(i & 2), reset=bool(i & 4))
        payloads.append(bytes(store.serialize_cdr(msg, "flight_fdi_msgs/msg/FilterState",
                                                  little_endian=little)))
        msgs.append(msg)
    records = cdr.decode_filter_states(payloads)
    for r, m in zip(records, msgs):
        assert r.stamp_ns == m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
        assert (r.frame_id, r.channel, list(r.state_names)) == (m.header.frame_id, m.channel,
                                                                 m.state_names)
        for name in ("x", "p", "z", "r", "h", "u"):
            np.testing.assert_array_equal(getattr(r, name), getattr(m, name))
        assert (r.dt, r.fused, r.gated, r.reset) == (m.dt, m.fused, m.gated, m.reset)
    for cut in (10, 30, len(payloads[3]) - 1):
        with pytest.raises(BagError, match="#0: not a valid flight_fdi_msgs/msg/FilterState"):
            cdr.decode_filter_states([payloads[3][:cut]])


@pytest.mark.parametrize("little", [True, False])
def test_header_stamp_and_header_bytes(little):
    store = get_typestore()
    T = store.types
    header = T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=-3, nanosec=999_999_999), frame_id="base")
    twist = T["geometry_msgs/msg/Twist"](
        linear=T["geometry_msgs/msg/Vector3"](x=1.0, y=2.0, z=3.0),
        angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0))
    data = bytes(store.serialize_cdr(T[cdr.TWIST_STAMPED](header=header, twist=twist),
                                     cdr.TWIST_STAMPED, little_endian=little))
    assert cdr.header_stamp_ns(data) == -3 * 10**9 + 999_999_999
    alone = bytes(store.serialize_cdr(header, "std_msgs/msg/Header", little_endian=little))
    assert cdr.header_bytes(data) == alone
    assert cdr.header_stamp_ns(data[:11]) is None and cdr.header_bytes(data[:20]) is None


def test_simulated_imu_messages_equal_rosbags_serialization():
    """sim.imu.encode_imu (cdr.encode_doubles) writes what rosbags' serializer writes for the
    same sensor_msgs/Imu, byte for byte (the IMU bags stayed identical when it replaced the
    serialized template)."""
    from flight_fdi.sim.imu import encode_imu

    store = get_typestore()
    T = store.types
    rng = np.random.default_rng(2)
    stamps = 1_700_000_000 * 10**9 + np.arange(5) * 5_000_000 + 123
    out = rng.normal(size=(5, 6))
    var = np.abs(rng.normal(size=6))
    got = encode_imu(stamps, out, "imu2", var)
    vec = T["geometry_msgs/msg/Vector3"]
    for k, data in enumerate(got):
        cov_o, cov_w, cov_a = np.zeros(9), np.zeros(9), np.zeros(9)
        cov_o[0] = -1.0
        cov_w[[0, 4, 8]] = var[0]
        cov_a[[0, 4, 8]] = var[3]
        msg = T[cdr.IMU](
            header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
                sec=int(stamps[k] // 10**9), nanosec=int(stamps[k] % 10**9)), frame_id="imu2"),
            orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=cov_o, angular_velocity=vec(*out[k, :3]),
            angular_velocity_covariance=cov_w, linear_acceleration=vec(*out[k, 3:]),
            linear_acceleration_covariance=cov_a)
        assert data == bytes(store.serialize_cdr(msg, cdr.IMU))


@pytest.mark.parametrize("little", [True, False])
def test_decode_doubles_reads_imu_in_both_byte_orders(little):
    store = get_typestore()
    T = store.types
    rng = np.random.default_rng(9)
    vec = T["geometry_msgs/msg/Vector3"]
    payloads, want, stamps = [], [], []
    for k in range(7):
        v = rng.normal(size=37)
        msg = T[cdr.IMU](
            header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
                sec=1_700_000_000 + k, nanosec=k), frame_id="imu" * k),
            orientation=T["geometry_msgs/msg/Quaternion"](*v[:4]),
            orientation_covariance=v[4:13], angular_velocity=vec(*v[13:16]),
            angular_velocity_covariance=v[16:25], linear_acceleration=vec(*v[25:28]),
            linear_acceleration_covariance=v[28:])
        payloads.append(bytes(store.serialize_cdr(msg, cdr.IMU, little_endian=little)))
        want.append(v)
        stamps.append((1_700_000_000 + k) * 10**9 + k)
    s, vals = cdr.decode_doubles(cdr.IMU, payloads, range(37))
    np.testing.assert_array_equal(s, stamps)
    np.testing.assert_array_equal(vals, want)
    with pytest.raises(BagError, match="columns must be in 0..36"):
        cdr.decode_doubles(cdr.IMU, payloads, [37])
    with pytest.raises(BagError, match="#2: .* too short"):
        cdr.decode_doubles(cdr.IMU, payloads[:2] + [payloads[2][:-8]], [0])
