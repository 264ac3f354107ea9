"""Per-message CDR for the nodes' hot paths: the filter node subscribes with ``raw=True`` and
publishes pre-serialized ``bytes``, reading the few input fields it needs and writing its two
outputs without building rclpy message objects (~40 us per message each way in rclpy, ~1-4 us
here); the bag player and the recorder read a message's header stamp or header bytes.

The wire rules are in :mod:`flight_fdi.bagio.cdr`. Everything from frame_id through the name
list of an output (frame_id, channel, the row or state names) is the same for every message of
one channel: its encoding is cached, and so is the ``struct.Struct`` that packs a whole message
for one prefix length and set of sequence lengths, so that encoding is a single ``pack`` call.

The output equals ``rclpy.serialization.serialize_message`` byte for byte except where that
leaves bytes uninitialised: its alignment padding, and the spare bytes (up to 24 seen) it may
report after the end of a message (its buffer length is a size estimate; a publisher sends the
exact length, which is what is returned here).
"""
from __future__ import annotations

import struct
from typing import Sequence

from . import variable

_LITTLE = (struct.Struct("<iII"), struct.Struct("<3d"), struct.Struct("<3d24xd48xd48xd"))
_BIG = (struct.Struct(">iII"), struct.Struct(">3d"), struct.Struct(">3d24xd48xd48xd"))
#: bytes after std_msgs/Header: geometry_msgs/Twist (6 float64), TwistWithCovariance (+ 36)
_TWIST_SIZE = 48
_TWIST_COV_SIZE = 48 + 36 * 8

_U32 = struct.Struct("<I")
_INT32_MIN, _INT32_END = -(2**31), 2**31
_UINT32_END = 2**32
_CACHE_SIZE = 64

#: the fields after the name list, one code each: D float64[], Q bool[], d float64, ? bool,
#: B uint8
_INNOVATION = "DDdd?BDQQ"
_FILTER_STATE = "DDDDDDd???"
_SEQUENCES = {"D": ("d", 8), "Q": ("?", 1)}
_SIZES = {"d": 8, "?": 1, "B": 1}

#: (frame_id, channel, names) -> CDR of those fields (the stream starts at position 8)
_PREFIXES: dict[tuple[str, str, tuple[str, ...]], bytes] = {}
#: (field codes, prefix length, sequence lengths) -> Struct packing the whole message
_LAYOUTS: dict[tuple[str, int, tuple[int, ...]], struct.Struct] = {}


class WireError(ValueError):
    """Bytes that are not a message of the expected type, or a value a field cannot hold."""


# --- decoding ----------------------------------------------------------------------------------

def _stamped(data: bytes, size: int) -> tuple[tuple[struct.Struct, ...], int, int, int]:
    """(structs of the byte order, sec, nanosec, offset of the first field after the header)
    of a stamped message whose fields after std_msgs/Header (the first one a float64) take
    ``size`` bytes."""
    if len(data) < 16:
        raise WireError(f"{len(data)} bytes is too short for a stamped message")
    if data[0] or data[1] > 1:
        raise WireError(f"unknown CDR encapsulation {bytes(data[:4]).hex()}")
    structs = _LITTLE if data[1] else _BIG
    sec, nanosec, length = structs[0].unpack_from(data, 4)
    at = 4 + ((12 + length + 7) & ~7)
    if at + size > len(data):
        raise WireError(f"{len(data)} bytes is too short for a frame_id of {length} bytes")
    return structs, sec, nanosec, at


def decode_twist_stamped(data: bytes) -> tuple[int, int, float, float, float]:
    """geometry_msgs/msg/TwistStamped -> (stamp.sec, stamp.nanosec, twist.linear.x, .y, .z)"""
    structs, sec, nanosec, at = _stamped(data, _TWIST_SIZE)
    x, y, z = structs[1].unpack_from(data, at)
    return sec, nanosec, x, y, z


def decode_twist_cov_stamped(data: bytes
                             ) -> tuple[int, int, float, float, float, float, float, float]:
    """geometry_msgs/msg/TwistWithCovarianceStamped -> (sec, nanosec, twist.twist.linear.x, .y,
    .z, twist.covariance[0], twist.covariance[7], twist.covariance[14])"""
    structs, sec, nanosec, at = _stamped(data, _TWIST_COV_SIZE)
    x, y, z, c0, c7, c14 = structs[2].unpack_from(data, at)
    return sec, nanosec, x, y, z, c0, c7, c14


_ODOM_LITTLE = struct.Struct("<4d")  # pose.pose.orientation x, y, z, w
#: twist.linear, then the linear block of twist.covariance (entries 0-2, 6-8, 12-14)
_ODOM_TWIST = struct.Struct("<3d24x3d24x3d24x3d")
#: offsets (from the 8-aligned start of the doubles) of orientation and twist
_ODOM_ORIENTATION_AT, _ODOM_TWIST_AT, _ODOM_SIZE = (
    8 * variable.ODOM_ORIENTATION, 8 * variable.ODOM_TWIST, 8 * variable.ODOM_DOUBLES)
_ODOM_BIG = (struct.Struct(">4d"), struct.Struct(">3d24x3d24x3d24x3d"))


def decode_odometry(data: bytes, rotate: bool = True
                    ) -> tuple[int, int, float, float, float, float, float, float]:
    """nav_msgs/msg/Odometry -> (sec, nanosec, twist.linear x, y, z, variances of the three),
    with the twist in the navigation frame (header.frame_id):

    REP 105 gives the twist in child_frame_id (the body). With ``rotate`` and a child_frame_id
    that is neither empty nor equal to header.frame_id, the velocity is rotated by
    pose.pose.orientation (v_nav = R(q) v_body) and the variances are the diagonal of
    R C R^T (C the linear block of the covariance); a quaternion that is not unit gives NaN
    velocities (the caller drops them as non-finite). Otherwise the twist is taken as it is."""
    structs, sec, nanosec, _ = _stamped(data, 0)
    n1 = structs[0].unpack_from(data, 4)[2]
    at = 4 + ((12 + n1 + 3) & ~3)  # child_frame_id's length
    if at + 4 > len(data):
        raise WireError(f"{len(data)} bytes is too short for an Odometry message")
    little = structs is _LITTLE
    (n2,) = struct.unpack_from("<I" if little else ">I", data, at)
    start = 4 + ((at - 4 + 4 + n2 + 7) & ~7)
    if start + _ODOM_SIZE > len(data):
        raise WireError(f"{len(data)} bytes is too short for an Odometry message")
    q_s, tw_s = (_ODOM_LITTLE, _ODOM_TWIST) if little else _ODOM_BIG
    x, y, z, *c = tw_s.unpack_from(data, start + _ODOM_TWIST_AT)
    if not rotate or n2 <= 1 or (n1 == n2 and data[16:16 + n1] == data[at + 4:at + 4 + n2]):
        return sec, nanosec, x, y, z, c[0], c[4], c[8]
    qx, qy, qz, qw = q_s.unpack_from(data, start + _ODOM_ORIENTATION_AT)
    if not abs(qx * qx + qy * qy + qz * qz + qw * qw - 1.0) <= 1e-3:
        nan = float("nan")
        return sec, nanosec, nan, nan, nan, c[0], c[4], c[8]
    # R(q) row by row (unrolled: this is the per-message path): (R v)_i, (R C R^T)_ii
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = c
    xx, yy, zz, xy, xz, yz = qx * qx, qy * qy, qz * qz, qx * qy, qx * qz, qy * qz
    wx, wy, wz = qw * qx, qw * qy, qw * qz
    a, b, d = 1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)
    vx = a * x + b * y + d * z
    px = a * (a * c00 + b * c01 + d * c02) + b * (a * c10 + b * c11 + d * c12) \
        + d * (a * c20 + b * c21 + d * c22)
    a, b, d = 2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)
    vy = a * x + b * y + d * z
    py = a * (a * c00 + b * c01 + d * c02) + b * (a * c10 + b * c11 + d * c12) \
        + d * (a * c20 + b * c21 + d * c22)
    a, b, d = 2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)
    vz = a * x + b * y + d * z
    pz = a * (a * c00 + b * c01 + d * c02) + b * (a * c10 + b * c11 + d * c12) \
        + d * (a * c20 + b * c21 + d * c22)
    return sec, nanosec, vx, vy, vz, px, py, pz


_STAMP = (struct.Struct(">iI"), struct.Struct("<iI"))
_NS = 1_000_000_000


def header_stamp_ns(data: bytes) -> int | None:
    """Header stamp (ns) of a CDR message that starts with std_msgs/Header (None if too short)."""
    if len(data) < 12:
        return None
    sec, nsec = _STAMP[data[1] & 1].unpack_from(data, 4)
    return sec * _NS + nsec


def header_bytes(data: bytes) -> bytes | None:
    """The std_msgs/Header (CDR) a serialized stamped message starts with: the encapsulation,
    stamp and frame_id are the first fields of both (None when ``data`` is too short)."""
    if len(data) < 16:
        return None
    fmt = "<I" if data[1] & 1 else ">I"
    end = 16 + struct.unpack_from(fmt, data, 12)[0]
    return bytes(data[:end]) if end <= len(data) else None


# --- encoding ----------------------------------------------------------------------------------

def _remember(cache: dict, key: object, value: object) -> None:
    """Store in a bounded cache (emptied when full: a node has only a few channels)."""
    if len(cache) >= _CACHE_SIZE:
        cache.clear()
    cache[key] = value


def _put_string(out: bytearray, text: str) -> None:
    """Append one CDR string to ``out`` (which starts at a 4-aligned stream position)."""
    if not isinstance(text, str):
        raise WireError(f"a string field cannot hold {type(text).__name__} {text!r}")
    if "\x00" in text:
        raise WireError(f"a string field cannot hold a NUL character: {text!r}")
    try:
        raw = text.encode("utf-8")
    except UnicodeEncodeError as exc:
        raise WireError(f"a string field must be valid UTF-8: {exc}") from None
    out += bytes(-len(out) % 4)
    out += _U32.pack(len(raw) + 1) + raw + b"\x00"


def _prefix(frame_id: str, channel: str, names: Sequence[str]) -> bytes:
    """CDR of frame_id, channel and the string[] names (cached)."""
    key = (frame_id, channel, tuple(names))
    prefix = _PREFIXES.get(key)
    if prefix is None:
        out = bytearray()
        _put_string(out, frame_id)
        _put_string(out, channel)
        out += bytes(-len(out) % 4) + _U32.pack(len(key[2]))
        for name in key[2]:
            _put_string(out, name)
        prefix = bytes(out)
        _remember(_PREFIXES, key, prefix)
    return prefix


def _fields_format(codes: str, pos: int, counts: tuple[int, ...]) -> str:
    """struct format of the fields ``codes`` (see _INNOVATION) from stream position ``pos``,
    the sequences holding ``counts`` elements, with the alignment padding as ``x``."""
    parts = []
    sequence_counts = iter(counts)
    for code in codes:
        if code in _SEQUENCES:
            item, size = _SEQUENCES[code]
            count = next(sequence_counts)
            pad = -pos % 4
            parts.append(f"{pad}xI")
            pos += pad + 4
            if count:
                pad = -pos % size
                parts.append(f"{pad}x{count}{item}")
                pos += pad + count * size
        else:
            pad = -pos % _SIZES[code]
            parts.append(f"{pad}x{code}")
            pos += pad + _SIZES[code]
    return "".join(parts)


def _layout(codes: str, prefix: bytes, counts: tuple[int, ...]) -> struct.Struct:
    """Struct packing (1, sec, nanosec, prefix, fields...) into a whole message (cached)."""
    key = (codes, len(prefix), counts)
    layout = _LAYOUTS.get(key)
    if layout is None:
        fields = _fields_format(codes, 8 + len(prefix), counts)
        layout = struct.Struct(f"<xBxxiI{len(prefix)}s{fields}")
        _remember(_LAYOUTS, key, layout)
    return layout


def _check_stamp(sec: int, nanosec: int) -> None:
    if not (_INT32_MIN <= sec < _INT32_END and 0 <= nanosec < _UINT32_END):
        raise WireError(f"stamp sec={sec} nanosec={nanosec} does not fit builtin_interfaces/Time")


def encode_innovation(sec: int, nanosec: int, frame_id: str, channel: str,
                      row_names: Sequence[str], innovation: Sequence[float],
                      innovation_covariance: Sequence[float], beta2: float,
                      gate_threshold: float, gate_exceeded: bool, alarm_state: int,
                      row_beta2: Sequence[float], row_excluded: Sequence[bool],
                      row_failed: Sequence[bool]) -> bytes:
    """flight_fdi_msgs/msg/Innovation serialized exactly as rclpy.serialization.serialize_message
    does."""
    _check_stamp(sec, nanosec)
    if not 0 <= alarm_state <= 255:
        raise WireError(f"alarm_state {alarm_state} does not fit a uint8")
    prefix = _prefix(frame_id, channel, row_names)
    counts = (len(innovation), len(innovation_covariance), len(row_beta2), len(row_excluded),
              len(row_failed))
    try:
        return _layout(_INNOVATION, prefix, counts).pack(
            1, sec, nanosec, prefix, counts[0], *innovation, counts[1], *innovation_covariance,
            beta2, gate_threshold, gate_exceeded, alarm_state, counts[2], *row_beta2, counts[3],
            *row_excluded, counts[4], *row_failed)
    except struct.error as exc:
        raise WireError(f"Innovation: {exc}") from None


def encode_filter_state(sec: int, nanosec: int, frame_id: str, channel: str,
                        state_names: Sequence[str], x: Sequence[float], p: Sequence[float],
                        z: Sequence[float], r: Sequence[float], h: Sequence[float],
                        u: Sequence[float], dt: float, fused: bool, gated: bool,
                        reset: bool) -> bytes:
    """flight_fdi_msgs/msg/FilterState serialized exactly as
    rclpy.serialization.serialize_message does."""
    _check_stamp(sec, nanosec)
    prefix = _prefix(frame_id, channel, state_names)
    counts = (len(x), len(p), len(z), len(r), len(h), len(u))
    try:
        return _layout(_FILTER_STATE, prefix, counts).pack(
            1, sec, nanosec, prefix, counts[0], *x, counts[1], *p, counts[2], *z, counts[3], *r,
            counts[4], *h, counts[5], *u, dt, fused, gated, reset)
    except struct.error as exc:
        raise WireError(f"FilterState: {exc}") from None
