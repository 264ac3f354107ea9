"""The 3-D contract topics decoded as whole series (``bagio.ins3d_series.read_series``: the one
CDR codec) equal rosbags' per-message decode (``read_series_messages``, the reader of before)
bit for bit: on the bundled ins3d bags, and on a bag whose messages have frame_ids of every
length (multi-byte UTF-8 too), NaN and infinite values, duplicate and out-of-order header stamps,
equal receive times, big-endian messages -- in mcap and sqlite3 storage."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from flight_fdi.bagio import BagError, get_typestore
from flight_fdi.bagio.ins3d_input import TOPICS, TYPES, build_input, read_ins3d
from flight_fdi.bagio.ins3d_series import arrays, read_series, read_series_messages
from flight_fdi.bagio.writer import open_writer
from flight_fdi.core.errors import CoreError

BAGS = Path(__file__).resolve().parents[2] / "bags"
#: frame_ids of many lengths (the doubles' offsets follow them), one of multi-byte characters
FRAMES = ["", "a", "ab", "abc", "base_link", "enu", "x" * 7, "x" * 8, "reference_frame_01",
          "ménage", "ü" * 5, "a_much_longer_frame_id_than_any_other_0123456789"]


def _same(a, b, where=""):
    """Same dtype, shape and bytes (NaN payloads and the sign of zero included)."""
    a, b = np.asarray(a), np.asarray(b)
    assert (a.dtype, a.shape) == (b.dtype, b.shape), where
    assert a.tobytes() == b.tobytes(), where


def _same_series(path: Path, names: dict[str, str] = TOPICS) -> tuple:
    fast, slow = read_series(path, names), read_series_messages(path, names)
    for role in names:
        _same(fast[role][0], slow[role][0], f"{role} stamps")
        _same(fast[role][1], slow[role][1], f"{role} values")
    got, want = arrays(fast, names, path), arrays(slow, names, path)
    for i, (a, b) in enumerate(zip(got, want)):
        _same(a, b, f"array {i}")
    return got


def test_the_bundled_nominal_bag_decodes_bit_for_bit():
    """read_ins3d (the series path) gives the input the per-message decode gives."""
    bag = BAGS / "ins3d_nominal"
    *values, t0 = _same_series(bag)
    want = build_input(*values)
    got = read_ins3d(bag)
    assert got.t0_ns == t0 and got.messages == {
        "/ins/velocity": 36001, "/ins/imu": 36000, "/ins/fix": 9001,
        "/reference/velocity": 18001}
    _same(got.q, want.q, "q")
    for field in ("t", "C", "f_n", "v", "lat"):
        _same(getattr(got.steps, field), getattr(want.steps, field), field)
    for field in ("t", "z", "step"):
        _same(getattr(got.refs, field), getattr(want.refs, field), field)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ins3d_accel_y_step", "ins3d_gyro_x_step"])
def test_the_other_bundled_bags_decode_bit_for_bit(name):
    _same_series(BAGS / name)


def _header(T, stamp_ns: int, frame: str):
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec),
                                    frame_id=frame)


def _message(T, role: str, stamp_ns: int, frame: str, x: np.ndarray, rng):
    """A contract message of ``role`` (rosbags' types) with the values ``x`` and noise
    everywhere else (covariances, NavSatFix's status and service...)."""
    V3, h = T["geometry_msgs/msg/Vector3"], _header(T, stamp_ns, frame)
    if role == "ins_imu":
        q = T["geometry_msgs/msg/Quaternion"](x=x[0], y=x[1], z=x[2], w=x[3])
        return T[TYPES[role]](header=h, orientation=q, orientation_covariance=rng.normal(size=9),
                              angular_velocity=V3(x=x[4], y=x[5], z=x[6]),
                              angular_velocity_covariance=rng.normal(size=9),
                              linear_acceleration=V3(x=x[7], y=x[8], z=x[9]),
                              linear_acceleration_covariance=rng.normal(size=9))
    if role == "ins_fix":
        status = T["sensor_msgs/msg/NavSatStatus"](status=int(rng.integers(-128, 128)),
                                                   service=int(rng.integers(0, 2**16)))
        return T[TYPES[role]](header=h, status=status, latitude=x[0], longitude=x[1],
                              altitude=x[2], position_covariance=rng.normal(size=9),
                              position_covariance_type=int(rng.integers(0, 256)))
    twist = T["geometry_msgs/msg/Twist"](linear=V3(x=x[0], y=x[1], z=x[2]),
                                         angular=V3(x=x[3], y=x[4], z=x[5]))
    if role == "ins_velocity":
        return T[TYPES[role]](header=h, twist=twist)
    cov = rng.normal(size=36)
    cov[[0, 7, 14]] = x[6:9]
    inner = T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=cov)
    return T[TYPES[role]](header=h, twist=inner)


#: values per message of each role (rosbags' message fields, _message)
_WIDTH = {"ins_imu": 10, "ins_fix": 3, "ins_velocity": 6, "ref_velocity": 9}


def _stamps(rng, n: int, period_ns: int, unique: bool) -> np.ndarray:
    """Header stamps at ``period_ns`` with jitter, some out of order, some repeated (not when
    ``unique``), some negative seconds."""
    s = -3_000_000_000 + period_ns * np.arange(n) + rng.integers(-1000, 1000, n)
    swap = 2 * rng.choice((n - 1) // 2, size=n // 10, replace=False)   # disjoint pairs
    s[swap], s[swap + 1] = s[swap + 1].copy(), s[swap].copy()      # out of order
    if not unique:
        dup = rng.choice(np.arange(1, n), size=n // 10, replace=False)
        s[dup] = s[dup - 1]                                         # repeated
    return s


def _odd_bag(path: Path, storage: str, plausible: bool, seed: int) -> None:
    """``plausible``: distinct stamps, finite values, reference variances > 0 (what the
    analysis accepts); otherwise NaN, infinite and -0.0 values and repeated stamps."""
    store, rng = get_typestore(), np.random.default_rng(seed)
    T = store.types
    counts = {"ins_imu": 120, "ins_velocity": 110, "ins_fix": 40, "ref_velocity": 30}
    with open_writer(path, storage=storage, compression="none" if seed % 2 else "zstd") as w:
        for role, n in counts.items():
            period = 50_000_000 if role != "ins_fix" else 150_000_000
            stamps = _stamps(rng, n, period, plausible)
            x = rng.normal(size=(n, _WIDTH[role])) * 10.0 ** rng.integers(-9, 4, (n, 1))
            if plausible and role == "ref_velocity":
                x[:, 6:9] = np.abs(x[:, 6:9]) + 1e-3
            elif not plausible:
                odd = rng.random(x.shape) < 0.05
                x[odd] = rng.choice([np.nan, np.inf, -np.inf, -0.0], odd.sum())
                x[3] = np.frombuffer(np.uint64(0x7FF8_0000_DEAD_BEEF).tobytes(), np.float64)[0]
            log = np.sort(rng.integers(0, 10**10, n))
            log[5:9] = log[4]                                       # equal receive times
            for i in range(n):
                msg = _message(T, role, int(stamps[i]), FRAMES[rng.integers(len(FRAMES))],
                               x[i], rng)
                little = rng.random() > 0.2                         # some big-endian ones
                data = store.serialize_cdr(msg, TYPES[role], little_endian=little)
                w.write_raw(TOPICS[role], TYPES[role], bytes(data), int(log[i]))


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
@pytest.mark.parametrize("seed", [1, 2])
def test_odd_frame_ids_values_and_stamps_decode_bit_for_bit(tmp_path, storage, seed):
    """A repeated IMU stamp: the same refusal from both (the analysis's, after decoding)."""
    bag = tmp_path / "odd"
    _odd_bag(bag, storage, plausible=False, seed=seed)
    values = _same_series(bag)
    with pytest.raises(CoreError, match="increase"):
        build_input(*values[:-1])
    with pytest.raises(CoreError, match="increase"):
        read_ins3d(bag)


def test_an_odd_bag_with_unique_imu_stamps_reads_as_before(tmp_path):
    """Out-of-order but distinct IMU stamps: read_ins3d gives the per-message decode's input."""
    bag = tmp_path / "odd"
    _odd_bag(bag, "mcap", plausible=True, seed=3)
    *values, t0 = _same_series(bag)
    got, want = read_ins3d(bag), build_input(*values)
    assert got.t0_ns == t0 < 0
    _same(got.q, want.q, "q")
    for field in ("t", "C", "f_n", "v", "lat"):
        _same(getattr(got.steps, field), getattr(want.steps, field), field)
    for field in ("t", "z", "step"):
        _same(getattr(got.refs, field), getattr(want.refs, field), field)


def test_a_truncated_message_is_a_one_line_error(tmp_path):
    """A NavSatFix cut before its last byte (covariance_type): BagError naming the topic."""
    store, rng = get_typestore(), np.random.default_rng(5)
    bag = tmp_path / "cut"
    with open_writer(bag) as w:
        for role in TOPICS:
            for i in range(3):
                msg = _message(store.types, role, 10**9 * i, "enu", rng.normal(size=_WIDTH[role]),
                               rng)
                data = bytes(store.serialize_cdr(msg, TYPES[role]))
                if role == "ins_fix" and i == 2:
                    data = data[:-1]
                w.write_raw(TOPICS[role], TYPES[role], data, 10**9 * i)
    with pytest.raises(BagError, match=r"/ins/fix #2: .* too short") as err:
        read_ins3d(bag)
    assert "\n" not in str(err.value)
