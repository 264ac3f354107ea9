"""The filter node's hand-written CDR (flight_fdi/bagio/cdr/message.py) against rclpy's serialization.

rclpy.serialization.serialize_message leaves the alignment padding uninitialised and may report
spare bytes after the end of the message (its buffer length is a size estimate), so the encoders
are compared with it byte for byte everywhere else: ``_padding`` finds the padding from the
message definition alone (a generic walk over the field types, independent of wire.py), where
wire.py must write zeros. Their bytes must also deserialize with rclpy and with rosbags (an
independent CDR reader that insists on the exact length). The decoders read rclpy's own bytes.
"""
from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Twist, TwistStamped, TwistWithCovariance, \
    TwistWithCovarianceStamped, Vector3
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Header

from flight_fdi.bagio import get_typestore
from flight_fdi.bagio.cdr import message as wire
from flight_fdi_msgs.msg import FilterState, Innovation

NAN_PAYLOAD = struct.unpack("<d", struct.pack("<Q", 0x7FF8_0000_DEAD_BEEF))[0]
SPECIAL = [math.nan, -math.nan, NAN_PAYLOAD, math.inf, -math.inf, -0.0, 0.0,
           1.7976931348623157e308, 5e-324, -2.2250738585072014e-308]
#: 1- to 4-byte UTF-8 characters, so that string lengths hit every alignment
ALPHABET = list("abcxyz_/0") + ["é", "ψ", "中", "✓", "🚀"]
#: message class, type name, its name list and the field after it
KINDS = {"innovation": (Innovation, "flight_fdi_msgs/msg/Innovation", "row_names", "innovation"),
         "filter_state": (FilterState, "flight_fdi_msgs/msg/FilterState", "state_names", "x")}


# --- random values -----------------------------------------------------------------------------

def _text(rng, n_max=20):
    return "".join(ALPHABET[int(k)] for k in rng.integers(0, len(ALPHABET),
                                                          int(rng.integers(0, n_max + 1))))


def _floats(rng, n):
    out = (rng.normal(0.0, 1.0, n) * 10.0 ** rng.integers(-300, 300, n)).tolist()
    for k in range(n):
        if rng.random() < 0.3:
            out[k] = SPECIAL[int(rng.integers(len(SPECIAL)))]
    return out


def _bools(rng, n):
    return [bool(b) for b in rng.random(n) < 0.5]


def _stamp(rng):
    edge = [(-(2**31), 0), (2**31 - 1, 2**32 - 1), (0, 0)]
    if rng.random() < 0.1:
        return edge[int(rng.integers(len(edge)))]
    return int(rng.integers(-(2**31), 2**31)), int(rng.integers(0, 2**32))


def _random_innovation(rng):
    def count():
        return int(rng.integers(0, 8))
    return dict(frame_id=_text(rng), channel=_text(rng),
                row_names=[_text(rng) for _ in range(count())],
                innovation=_floats(rng, count()), innovation_covariance=_floats(rng, count()),
                beta2=_floats(rng, 1)[0], gate_threshold=_floats(rng, 1)[0],
                gate_exceeded=bool(rng.random() < 0.5), alarm_state=int(rng.integers(0, 256)),
                row_beta2=_floats(rng, count()), row_excluded=_bools(rng, count()),
                row_failed=_bools(rng, count()))


def _random_filter_state(rng):
    return dict(frame_id=_text(rng), channel=_text(rng),
                state_names=[_text(rng) for _ in range(int(rng.integers(0, 8)))],
                **{k: _floats(rng, int(rng.integers(0, 8))) for k in "xpzrhu"},
                dt=_floats(rng, 1)[0], fused=bool(rng.random() < 0.5),
                gated=bool(rng.random() < 0.5), reset=bool(rng.random() < 0.5))


RANDOM = {"innovation": (_random_innovation, wire.encode_innovation),
          "filter_state": (_random_filter_state, wire.encode_filter_state)}


def _message(cls, sec, nanosec, fields):
    """The rclpy message with these wire.encode_* arguments."""
    body = {k: v for k, v in fields.items() if k != "frame_id"}
    return cls(header=Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=fields["frame_id"]),
               **body)


# --- an independent model of the layout --------------------------------------------------------

_PRIMITIVE_SIZES = {"boolean": 1, "octet": 1, "uint8": 1, "int32": 4, "uint32": 4, "double": 8}


def _padding(msg):
    """(stream offsets of the alignment padding, stream length, {top-level field: stream offset
    where it starts, before its alignment}) of the XCDR1 encoding of an rclpy message, from its
    field types."""
    pad, starts, pos = [], {}, 0

    def align(size):
        nonlocal pos
        while pos % size:
            pad.append(pos)
            pos += 1

    def walk(m, top):
        nonlocal pos
        for name, typ in m.get_fields_and_field_types().items():
            if top:
                starts[name] = pos
            value = getattr(m, name)
            items = [value]
            if typ.startswith("sequence<"):
                typ, items = typ[len("sequence<"):-1], list(value)
                align(4)
                pos += 4
            for item in items:
                if typ == "string":
                    align(4)
                    pos += 4 + len(item.encode()) + 1
                elif typ in _PRIMITIVE_SIZES:
                    align(_PRIMITIVE_SIZES[typ])
                    pos += _PRIMITIVE_SIZES[typ]
                else:
                    walk(item, False)

    walk(msg, True)
    return pad, pos, starts


# --- encoders ----------------------------------------------------------------------------------

def _same(got, want):
    """Bit-equal floats (NaN sign and payload included), or equal values."""
    if isinstance(want, float):
        return struct.pack("<d", float(got)) == struct.pack("<d", want)
    return got == want


def _assert_fields(msg, stamp, fields):
    """msg (rclpy or rosbags) holds the stamp and the wire.encode_* arguments ``fields``."""
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == stamp
    for name, want in fields.items():
        got = msg.header.frame_id if name == "frame_id" else getattr(msg, name)
        if isinstance(want, list):
            got = list(got)
            assert len(got) == len(want) and all(map(_same, got, want)), (name, got, want)
        else:
            assert _same(got, want), (name, got, want)


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_encoders_match_rclpy_byte_for_byte(kind):
    cls, _, names, after_names = KINDS[kind]
    make, encode = RANDOM[kind]
    rng = np.random.default_rng(20240 + len(kind))
    alignments = {names: set(), after_names: set()}
    for _ in range(400):
        fields = make(rng)
        sec, nanosec = _stamp(rng)
        data = encode(sec, nanosec, **fields)
        msg = _message(cls, sec, nanosec, fields)
        theirs = bytes(serialize_message(msg))
        pad, length, starts = _padding(msg)
        assert isinstance(data, bytes) and len(data) == 4 + length <= len(theirs)
        assert data[:4] == theirs[:4] == b"\x00\x01\x00\x00"
        pad = {4 + k for k in pad}
        assert all(data[k] == 0 for k in pad)
        keep = [k for k in range(len(data)) if k not in pad]
        assert [data[k] for k in keep] == [theirs[k] for k in keep]
        for field, seen in alignments.items():
            seen.add(starts[field] % 8)
    # the strings before and after the name list ended at every position modulo 8
    assert alignments == {names: set(range(8)), after_names: set(range(8))}


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_encoders_round_trip_through_rclpy_and_rosbags(kind):
    cls, msgtype, _, _ = KINDS[kind]
    make, encode = RANDOM[kind]
    store = get_typestore()
    rng = np.random.default_rng(7 + len(kind))
    for _ in range(200):
        fields = make(rng)
        stamp = _stamp(rng)
        data = encode(*stamp, **fields)
        _assert_fields(deserialize_message(data, cls), stamp, fields)
        _assert_fields(store.deserialize_cdr(data, msgtype), stamp, fields)


def test_numpy_inputs_encode_like_lists():
    rng = np.random.default_rng(11)
    fields = _random_filter_state(rng)
    arrays = {k: np.array(v, dtype=float) if k in "xpzrhu" else v for k, v in fields.items()}
    arrays["fused"] = np.bool_(fields["fused"])
    assert wire.encode_filter_state(1, 2, **arrays) == wire.encode_filter_state(1, 2, **fields)
    fields = _random_innovation(rng)
    arrays = {k: np.array(v) if isinstance(v, list) and k != "row_names" else v
              for k, v in fields.items()}
    arrays["alarm_state"] = np.uint8(fields["alarm_state"])
    assert wire.encode_innovation(1, 2, **arrays) == wire.encode_innovation(1, 2, **fields)


def test_prefix_cache_stays_bounded_and_correct():
    for k in range(3 * wire._CACHE_SIZE):
        channel = "c" * (k % 11) + str(k)
        data = wire.encode_filter_state(k, 0, "", channel, ["a"], [1.0], [], [], [], [], [],
                                        0.5, True, False, True)
        msg = deserialize_message(data, FilterState)
        assert (msg.header.stamp.sec, msg.channel, msg.dt, msg.reset) == (k, channel, 0.5, True)
    assert len(wire._PREFIXES) <= wire._CACHE_SIZE
    assert len(wire._LAYOUTS) <= wire._CACHE_SIZE


# --- decoders ----------------------------------------------------------------------------------

def _twist_stamped(rng, frame_id):
    sec, nanosec = _stamp(rng)
    lin, ang = _floats(rng, 3), _floats(rng, 3)
    return TwistStamped(header=Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id),
                        twist=Twist(linear=Vector3(x=lin[0], y=lin[1], z=lin[2]),
                                    angular=Vector3(x=ang[0], y=ang[1], z=ang[2])))


def _twist_cov_stamped(rng, frame_id):
    inner = _twist_stamped(rng, frame_id)
    return TwistWithCovarianceStamped(header=inner.header, twist=TwistWithCovariance(
        twist=inner.twist, covariance=_floats(rng, 36)))


def _want(msg):
    """The decoder result expected for msg."""
    stamp, twist = msg.header.stamp, msg.twist
    if isinstance(msg, TwistWithCovarianceStamped):
        lin, cov = twist.twist.linear, twist.covariance
        return (stamp.sec, stamp.nanosec, lin.x, lin.y, lin.z, cov[0], cov[7], cov[14])
    return (stamp.sec, stamp.nanosec, twist.linear.x, twist.linear.y, twist.linear.z)


def _frame_ids(rng):
    """frame_ids of every length 0..20 (ASCII), and random UTF-8 ones."""
    return ["f" * n for n in range(21)] + [_text(rng) for _ in range(60)]


@pytest.mark.parametrize("make, decode", [(_twist_stamped, wire.decode_twist_stamped),
                                          (_twist_cov_stamped, wire.decode_twist_cov_stamped)])
def test_decoders_read_rclpy_bytes_exactly(make, decode):
    rng = np.random.default_rng(5)
    for frame_id in _frame_ids(rng):
        msg = make(rng, frame_id)
        got = decode(bytes(serialize_message(msg)))
        want = _want(msg)
        assert len(got) == len(want) and all(map(_same, got, want)), (frame_id, got, want)
        assert type(got[0]) is int and type(got[1]) is int


def _big_endian(sec, nanosec, frame_id, values):
    """A TwistStamped (6 values) or TwistWithCovarianceStamped (42) as CDR_BE, built by hand."""
    raw = frame_id.encode() + b"\x00"
    head = struct.pack(">iII", sec, nanosec, len(raw)) + raw
    head += bytes(-len(head) % 8)
    return b"\x00\x00\x00\x00" + head + struct.pack(f">{len(values)}d", *values)


def test_big_endian_input_is_read():
    rng = np.random.default_rng(9)
    for frame_id in _frame_ids(rng):
        sec, nanosec = _stamp(rng)
        values = _floats(rng, 42)
        got = wire.decode_twist_stamped(_big_endian(sec, nanosec, frame_id, values[:6]))
        assert all(map(_same, got, (sec, nanosec, *values[:3])))
        got = wire.decode_twist_cov_stamped(_big_endian(sec, nanosec, frame_id, values))
        want = (sec, nanosec, *values[:3], values[6], values[13], values[20])
        assert all(map(_same, got, want)), (frame_id, got, want)


def test_encapsulation_options_are_not_interpreted():
    data = bytes(serialize_message(_twist_stamped(np.random.default_rng(1), "map")))
    assert wire.decode_twist_stamped(data[:2] + b"\x00\x03" + data[4:]) == \
        wire.decode_twist_stamped(data)


# --- malformed input ---------------------------------------------------------------------------

@pytest.mark.parametrize("make, decode", [(_twist_stamped, wire.decode_twist_stamped),
                                          (_twist_cov_stamped, wire.decode_twist_cov_stamped)])
def test_truncated_input_is_a_wire_error(make, decode):
    rng = np.random.default_rng(3)
    for frame_id in ("", "abc", "abcd", "map", "base_link_ψ"):
        data = bytes(serialize_message(make(rng, frame_id)))
        decode(data)
        for cut in range(len(data)):
            with pytest.raises(wire.WireError, match="too short"):
                decode(data[:cut])


@pytest.mark.parametrize("decode", [wire.decode_twist_stamped, wire.decode_twist_cov_stamped])
def test_bad_length_or_encapsulation_is_a_wire_error(decode):
    data = bytes(serialize_message(_twist_cov_stamped(np.random.default_rng(4), "odom")))
    for length in (2**32 - 1, 2**32 - 8, 2**31, len(data)):
        with pytest.raises(wire.WireError, match="too short"):
            decode(data[:12] + struct.pack("<I", length) + data[16:])
    # neither CDR_BE nor CDR_LE: garbage, PL_CDR_LE, XCDR2 (PLAIN_CDR2 BE / LE)
    for head in (b"\x01\x00", b"\x01\x01", b"\x00\x03", b"\x00\x06", b"\x00\x07", b"\xff\xff"):
        with pytest.raises(wire.WireError, match="encapsulation"):
            decode(head + data[2:])


# --- encoder validation ------------------------------------------------------------------------

OK_INNOVATION = dict(frame_id="", channel="x", row_names=["gps"], innovation=[0.1],
                     innovation_covariance=[0.2], beta2=0.3, gate_threshold=10.0,
                     gate_exceeded=False, alarm_state=0, row_beta2=[0.3],
                     row_excluded=[False], row_failed=[False])
OK_FILTER_STATE = dict(frame_id="", channel="x", state_names=["v"], x=[1.0], p=[1.0], z=[],
                       r=[], h=[], u=[], dt=0.1, fused=False, gated=False, reset=True)


@pytest.mark.parametrize("sec, nanosec", [(2**31, 0), (-(2**31) - 1, 0), (0, -1), (0, 2**32)])
def test_stamp_out_of_range_is_a_wire_error(sec, nanosec):
    with pytest.raises(wire.WireError, match="does not fit"):
        wire.encode_innovation(sec, nanosec, **OK_INNOVATION)
    with pytest.raises(wire.WireError, match="does not fit"):
        wire.encode_filter_state(sec, nanosec, **OK_FILTER_STATE)


@pytest.mark.parametrize("field, value, match", [
    ("alarm_state", 256, "uint8"), ("alarm_state", -1, "uint8"),
    ("frame_id", "a\x00", "NUL"), ("channel", "\x00", "NUL"),
    ("row_names", ["ok", "b\x00c"], "NUL"),
    ("channel", "\ud800", "UTF-8"), ("row_names", ["\udcff"], "UTF-8"),
    ("row_names", [b"gps"], "string"), ("innovation", ["0.1"], "float"),
])
def test_bad_innovation_value_is_a_wire_error(field, value, match):
    wire.encode_innovation(0, 0, **OK_INNOVATION)
    with pytest.raises(wire.WireError, match=match):
        wire.encode_innovation(0, 0, **{**OK_INNOVATION, field: value})


@pytest.mark.parametrize("field, value, match", [
    ("frame_id", "\x00", "NUL"), ("state_names", ["\ud800"], "UTF-8"), ("dt", None, "float"),
])
def test_bad_filter_state_value_is_a_wire_error(field, value, match):
    wire.encode_filter_state(0, 0, **OK_FILTER_STATE)
    with pytest.raises(wire.WireError, match=match):
        wire.encode_filter_state(0, 0, **{**OK_FILTER_STATE, field: value})


def test_convert_bytes_equal_the_messages_the_node_used_to_build():
    """convert.innovation_bytes / filter_state_bytes decode to innovation_msg / filter_state_msg
    (one field mapping), including a row with S = 0 (row beta2 as NumPy gives it: inf, NaN)."""
    from types import SimpleNamespace

    from flight_fdi.nodes import convert

    res = SimpleNamespace(nu=np.array([0.5, 0.0, 2.0]), S=np.diag([0.25, 0.0, 0.0]), beta2=1.0,
                          threshold=9.0, exceeded=False, alarm_state=0)
    stamp = convert.s_to_stamp(12.5)
    want = convert.innovation_msg(stamp, "x", ["a", "b", "c"], res, row_failed=[0, 1, 0])
    got = deserialize_message(convert.innovation_bytes((12, 500_000_000), "x", ["a", "b", "c"],
                                                       res, row_failed=[0, 1, 0]), Innovation)
    assert got.header.stamp == want.header.stamp and got.row_failed == want.row_failed
    for name in ("innovation", "innovation_covariance", "row_beta2"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
    np.testing.assert_array_equal(got.row_beta2, [1.0, np.nan, np.inf])
    x, P = [1.0, 2.0], np.array([[1.0, 0.5], [0.5, 2.0]])
    want = convert.filter_state_msg(stamp, "x", ["p", "v"], x, P, z=[0.1], R=[[0.01]],
                                    H=[[1.0, 0.0]], dt=0.1, fused=True)
    got = deserialize_message(convert.filter_state_bytes(
        (12, 500_000_000), "x", ["p", "v"], x, P, z=[0.1], R=[[0.01]], H=[[1.0, 0.0]], dt=0.1,
        fused=True), FilterState)
    for name in ("x", "p", "z", "r", "h", "u"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
    assert (got.dt, got.fused, got.gated, got.reset) == (want.dt, want.fused, want.gated,
                                                        want.reset)


# --- nav_msgs/Odometry (either input of the filter node) ---------------------------------------

def _odometry(rng, child):
    from nav_msgs.msg import Odometry

    m = Odometry()
    m.header.stamp.sec, m.header.stamp.nanosec = 1_700_000_000, 123_456_789
    m.header.frame_id = _text(rng)
    m.child_frame_id = child
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    o = m.pose.pose.orientation
    o.x, o.y, o.z, o.w = (float(c) for c in q)
    m.pose.pose.position.x = 3.0
    m.pose.covariance = list(rng.normal(size=36))
    lin = m.twist.twist.linear
    lin.x, lin.y, lin.z = (float(c) for c in rng.normal(size=3) * 50)
    m.twist.twist.angular.z = 0.1
    a = rng.normal(size=(6, 6))
    m.twist.covariance = list((a @ a.T).reshape(-1))
    return m, q


@pytest.mark.parametrize("seed", range(8))
def test_odometry_decoder_reads_rclpy_bytes_and_rotates_into_the_header_frame(seed):
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    m, q = _odometry(rng, _text(rng, 12) + "_b")  # a child frame: body twist (REP 105)
    data = serialize_message(m)
    sec, nanosec, *vals = wire.decode_odometry(data)
    assert (sec, nanosec) == (1_700_000_000, 123_456_789)
    R = Rotation.from_quat(q).as_matrix()  # independent: scipy's (x, y, z, w) convention
    v = np.array([m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.linear.z])
    C = np.array(m.twist.covariance).reshape(6, 6)[:3, :3]
    np.testing.assert_allclose(vals[:3], R @ v, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(vals[3:], np.diag(R @ C @ R.T), rtol=1e-10)
    # not rotated: odometry_twist_frame "header", an empty child frame, or child == header
    flat = (*v, *np.diag(C))
    assert wire.decode_odometry(data, rotate=False)[2:] == pytest.approx(flat, rel=1e-15)
    for child in ("", m.header.frame_id):
        m.child_frame_id = child
        assert wire.decode_odometry(serialize_message(m))[2:] == pytest.approx(flat, rel=1e-15)
    # the bag reader's vectorised decoder agrees (same bytes, same rotation)
    from flight_fdi.bagio import cdr

    m.child_frame_id = "base_link"
    s, values, frame, child = cdr.decode_odometry([serialize_message(m)])
    assert (frame, child) == (m.header.frame_id, "base_link")
    np.testing.assert_array_equal(values[0, :4], q)
    np.testing.assert_array_equal(values[0, 4:7], v)
    np.testing.assert_array_equal(values[0, 7:].reshape(3, 3), C)


def test_odometry_with_a_non_unit_quaternion_gives_nan_and_short_bytes_an_error():
    m, _ = _odometry(np.random.default_rng(1), "base_link")
    m.pose.pose.orientation.w += 0.5
    out = wire.decode_odometry(serialize_message(m))
    assert all(math.isnan(x) for x in out[2:5])
    with pytest.raises(wire.WireError, match="too short for an Odometry"):
        wire.decode_odometry(serialize_message(m)[:200])


def test_velocity_decoders_of_the_node_and_their_speed():
    import time

    from flight_fdi.nodes.convert import VELOCITY_TYPES, velocity_decoder

    rng = np.random.default_rng(2)
    m, _ = _odometry(rng, "base_link")
    odom = serialize_message(m)
    ts = serialize_message(TwistStamped(header=Header(stamp=Time(sec=5)),
                                        twist=Twist(linear=Vector3(x=1.0, y=2.0, z=3.0))))
    assert velocity_decoder(VELOCITY_TYPES[0])(ts)[:3] == (5, 0, (1.0, 2.0, 3.0))
    assert all(math.isnan(v) for v in velocity_decoder(VELOCITY_TYPES[0])(ts)[3])
    assert velocity_decoder(VELOCITY_TYPES[2], "header")(odom)[2] == pytest.approx(
        (m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.linear.z))
    with pytest.raises(ValueError, match="unsupported"):
        velocity_decoder("std_msgs/msg/String")
    # the hot path: a rotated Odometry stays within a few times a TwistStamped (both us)
    f_odom, f_ts = velocity_decoder(VELOCITY_TYPES[2]), velocity_decoder(VELOCITY_TYPES[0])

    def per_call(f, data, n=5000):
        t = time.perf_counter()
        for _ in range(n):
            f(data)
        return (time.perf_counter() - t) / n

    best = min(per_call(f_odom, odom) / per_call(f_ts, ts) for _ in range(3))
    assert best < 15.0  # measured ~5x (about 10 us vs 2 us per message, loaded machine)
    assert per_call(f_odom, odom) < 100e-6  # far below rclpy's ~40 us message objects x 2
