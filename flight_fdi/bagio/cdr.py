"""Vectorised CDR encoding/decoding of the fixed-layout velocity messages.

Full per-message (de)serialization through rosbags costs tens of microseconds per message, far
too slow for a 3-hour flight (650 000 messages). ``geometry_msgs/TwistStamped`` and
``geometry_msgs/TwistWithCovarianceStamped`` have a fixed layout apart from the header's
``frame_id`` string, so whole series are encoded and decoded here with numpy.

Layout (offsets relative to the CDR payload, which starts after the 4-byte encapsulation header;
doubles are 8-byte aligned relative to the payload start)::

    0   int32   header.stamp.sec
    4   uint32  header.stamp.nanosec
    8   uint32  length L of frame_id, including its terminating NUL
    12  char[L] frame_id
    a = align8(12 + L)
    a   float64 twist.linear.{x,y,z}, twist.angular.{x,y,z}        (6 doubles)
    a+48 float64 covariance[36]       (TwistWithCovarianceStamped only)

Both encapsulations are decoded: CDR_LE (``00 01``) and CDR_BE (``00 00``). Encoding writes CDR_LE.
The tests check both directions against rosbags' own serializer.

Encoding only (the 3-D simulator's topics): ``encode_doubles`` for any type that is a header
followed by doubles (``sensor_msgs/Imu``: 37), ``encode_navsatfix`` for ``sensor_msgs/NavSatFix``.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .errors import BagError

TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
TWIST_COV_STAMPED = "geometry_msgs/msg/TwistWithCovarianceStamped"
IMU = "sensor_msgs/msg/Imu"
NAVSATFIX = "sensor_msgs/msg/NavSatFix"

#: number of doubles after the header for each supported type
_DOUBLES = {TWIST_STAMPED: 6, TWIST_COV_STAMPED: 6 + 36}
#: header + doubles types that are only encoded here
_ENCODE_ONLY = {IMU: 4 + 9 + 3 + 9 + 3 + 9}
_NS = 1_000_000_000


def supported(msgtype: str) -> bool:
    return msgtype in _DOUBLES


def _align8(n: np.ndarray | int):
    return (n + 7) & ~7


def encode(msgtype: str, stamp_ns: np.ndarray, frame_id: str, twist: np.ndarray,
           covariance: np.ndarray | None = None) -> list[bytes]:
    """Serialize a series of messages to CDR (little endian), one ``bytes`` per message.

    ``stamp_ns`` (N,) integer nanoseconds; ``twist`` (N, 6) = linear x, y, z, angular x, y, z;
    ``covariance`` (36,) for all messages or (N, 36) (TwistWithCovarianceStamped only).
    """
    if msgtype not in _DOUBLES:
        raise BagError(f"fast CDR encoding does not support {msgtype!r}")
    stamp_ns = np.asarray(stamp_ns, dtype=np.int64).reshape(-1)
    n = stamp_ns.size
    twist = np.asarray(twist, dtype=np.float64)
    if twist.shape != (n, 6):
        raise BagError(f"encode {msgtype}: twist must have shape ({n}, 6), got {twist.shape}")
    values = twist
    if msgtype == TWIST_COV_STAMPED:
        if covariance is None:
            covariance = np.zeros(36)
        cov = np.asarray(covariance, dtype=np.float64)
        if cov.shape == (36,):
            cov = np.broadcast_to(cov, (n, 36))
        if cov.shape != (n, 36):
            raise BagError(f"encode {msgtype}: covariance must have shape (36,) or ({n}, 36)")
        values = np.concatenate([twist, cov], axis=1)
    elif covariance is not None:
        raise BagError(f"encode {msgtype}: this type has no covariance")
    return encode_doubles(msgtype, stamp_ns, frame_id, values)


def _header_rows(stamp_ns: np.ndarray, frame_id: str, size: int) -> tuple[np.ndarray, int]:
    """(n, size) zero buffer with the encapsulation and header written; payload offset after
    the frame_id's NUL."""
    raw = frame_id.encode("utf-8") + b"\x00"
    if b"\x00" in raw[:-1]:
        raise BagError(f"frame_id {frame_id!r} contains a NUL character")
    n = stamp_ns.size
    buf = np.zeros((n, size), dtype=np.uint8)
    buf[:, 1] = 1  # CDR_LE encapsulation: 00 01 00 00
    sec, nsec = np.divmod(stamp_ns, _NS)
    if n and (sec.min() < -(2**31) or sec.max() >= 2**31):
        raise BagError("encode: a stamp does not fit a builtin_interfaces/Time (int32 seconds)")
    buf[:, 4:8] = sec.astype("<i4").view(np.uint8).reshape(n, 4)
    buf[:, 8:12] = nsec.astype("<u4").view(np.uint8).reshape(n, 4)
    buf[:, 12:16] = np.frombuffer(np.uint32(len(raw)).astype("<u4").tobytes(), dtype=np.uint8)
    buf[:, 16:16 + len(raw)] = np.frombuffer(raw, dtype=np.uint8)
    return buf, 12 + len(raw)


def rows(buf: np.ndarray) -> list[bytes]:
    """The rows of an (n, size) uint8 array as n ``bytes`` payloads."""
    n, size = buf.shape
    flat = buf.tobytes()
    return [flat[i:i + size] for i in range(0, n * size, size)]


def encode_doubles(msgtype: str, stamp_ns: np.ndarray, frame_id: str,
                   values: np.ndarray) -> list[bytes]:
    """Serialize a type made of a header and doubles; ``values`` (N, number of doubles) in
    declaration order (e.g. Imu: orientation x y z w, its covariance, angular_velocity, ...)."""
    ndouble = _DOUBLES.get(msgtype, _ENCODE_ONLY.get(msgtype))
    if ndouble is None:
        raise BagError(f"fast CDR encoding does not support {msgtype!r}")
    stamp_ns = np.asarray(stamp_ns, dtype=np.int64).reshape(-1)
    n = stamp_ns.size
    values = np.asarray(values, dtype=np.float64)
    if values.shape != (n, ndouble):
        raise BagError(f"encode {msgtype}: values must have shape ({n}, {ndouble}), "
                       f"got {values.shape}")
    off = _align8(12 + len(frame_id.encode("utf-8")) + 1)
    buf, _ = _header_rows(stamp_ns, frame_id, 4 + off + 8 * ndouble)
    buf[:, 4 + off:] = np.ascontiguousarray(values, dtype="<f8").view(np.uint8).reshape(n, -1)
    return rows(buf)


def encode_navsatfix(stamp_ns: np.ndarray, frame_id: str, status: int, service: int,
                     llh: np.ndarray, covariance: np.ndarray, covariance_type: int
                     ) -> list[bytes]:
    """Serialize sensor_msgs/NavSatFix messages: ``llh`` (N, 3) latitude, longitude (deg),
    altitude (m); ``covariance`` (9,) or (N, 9) ENU m^2, row-major."""
    stamp_ns = np.asarray(stamp_ns, dtype=np.int64).reshape(-1)
    n = stamp_ns.size
    llh = np.asarray(llh, dtype=np.float64)
    cov = np.broadcast_to(np.asarray(covariance, dtype=np.float64), (n, 9))
    if llh.shape != (n, 3):
        raise BagError(f"encode {NAVSATFIX}: llh must have shape ({n}, 3), got {llh.shape}")
    p = 12 + len(frame_id.encode("utf-8")) + 1      # status (int8) at p
    ps = (p + 1 + 1) & ~1                           # service (uint16), 2-aligned
    pd = _align8(ps + 2)                            # 12 doubles, 8-aligned
    buf, _ = _header_rows(stamp_ns, frame_id, 4 + pd + 96 + 1)
    buf[:, 4 + p] = np.uint8(np.int8(status).view(np.uint8))
    buf[:, 4 + ps:4 + ps + 2] = np.frombuffer(np.uint16(service).astype("<u2").tobytes(),
                                              dtype=np.uint8)
    doubles = np.ascontiguousarray(np.concatenate([llh, cov], axis=1), dtype="<f8")
    buf[:, 4 + pd:4 + pd + 96] = doubles.view(np.uint8).reshape(n, 96)
    buf[:, 4 + pd + 96] = np.uint8(covariance_type)
    return rows(buf)


class Payloads:
    """Serialized messages stored back to back: message i is ``buf[starts[i]:][:lengths[i]]``."""

    __slots__ = ("buf", "starts", "lengths")

    def __init__(self, buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray) -> None:
        self.buf = np.asarray(buf, dtype=np.uint8).reshape(-1)
        self.starts = np.asarray(starts, dtype=np.int64).reshape(-1)
        self.lengths = np.asarray(lengths, dtype=np.int64).reshape(-1)
        if self.starts.shape != self.lengths.shape:
            raise BagError("payloads: starts and lengths differ in size")
        if self.starts.size and (self.starts.min() < 0 or self.lengths.min() < 0
                                 or (self.starts + self.lengths).max() > self.buf.size):
            raise BagError("payloads: a message extends beyond its buffer")

    @classmethod
    def from_list(cls, payloads: Sequence[bytes | memoryview]) -> "Payloads":
        n = len(payloads)
        lengths = np.fromiter(map(len, payloads), dtype=np.int64, count=n)
        starts = np.zeros(n, dtype=np.int64)
        if n:
            np.cumsum(lengths[:-1], out=starts[1:])
        return cls(np.frombuffer(b"".join(payloads), dtype=np.uint8), starts, lengths)

    def take(self, index: np.ndarray) -> "Payloads":
        """The messages at ``index`` (same buffer)."""
        return Payloads(self.buf, self.starts[index], self.lengths[index])

    def __len__(self) -> int:
        return int(self.starts.size)

    def __getitem__(self, i: int) -> bytes:
        s = int(self.starts[i])
        return self.buf[s:s + int(self.lengths[i])].tobytes()


def decode(msgtype: str, payloads: "Payloads | Sequence[bytes | memoryview]",
           what: str = "message", twist_cols: Sequence[int] = range(6),
           cov_cols: Sequence[int] | None = None
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Decode a series: (stamp_ns (N,) int64, twist (N, len(twist_cols)), covariance or None).

    ``twist_cols`` picks twist entries (0..2 linear x, y, z; 3..5 angular); ``cov_cols`` picks
    covariance entries (row-major 6x6; default all 36 for TwistWithCovarianceStamped, None for
    TwistStamped). Only the picked values are gathered, which keeps long series fast.
    Raises BagError naming ``what`` when a message is too short or malformed.
    """
    if msgtype not in _DOUBLES:
        raise BagError(f"fast CDR decoding does not support {msgtype!r}")
    has_cov = _DOUBLES[msgtype] > 6
    if cov_cols is None:
        cov_cols = range(36) if has_cov else ()
    elif not has_cov and len(cov_cols):
        raise BagError(f"decode {msgtype}: this type has no covariance")
    twist_cols = list(twist_cols)
    cov_cols = list(cov_cols)
    if any(not 0 <= c < 6 for c in twist_cols) or any(not 0 <= c < 36 for c in cov_cols):
        raise BagError("decode: twist columns must be in 0..5 and covariance columns in 0..35")
    if not isinstance(payloads, Payloads):
        payloads = Payloads.from_list(payloads)
    n = len(payloads)
    cols = twist_cols + [6 + c for c in cov_cols]
    stamp_ns = np.zeros(n, np.int64)
    values = np.zeros((n, len(cols)))
    # in blocks: the gathers index with (messages x bytes) int64 arrays, which for a 10-hour
    # flight in one piece would be several hundred MB
    for a in range(0, n, _BLOCK):
        b = min(n, a + _BLOCK)
        stamp_ns[a:b], values[a:b] = _decode_block(
            msgtype, payloads.buf, payloads.starts[a:b], payloads.lengths[a:b], cols, what, a)
    twist = values[:, :len(twist_cols)]
    cov_out = values[:, len(twist_cols):] if has_cov else None
    return stamp_ns, twist, cov_out


#: messages decoded per block
_BLOCK = 65536


def _decode_block(msgtype: str, buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray,
                  cols: list[int], what: str, first: int) -> tuple[np.ndarray, np.ndarray]:
    """(stamp_ns, the doubles at ``cols``) of messages ``first`` ... of a series."""
    n = starts.size
    ndouble = _DOUBLES[msgtype]
    if n == 0:
        return np.zeros(0, np.int64), np.zeros((0, len(cols)))
    if lengths.min() < 16:
        bad = int(np.argmin(lengths))
        raise BagError(f"{what} #{first + bad}: {lengths[bad]} bytes is too short for {msgtype}")
    head = buf[starts[:, None] + np.arange(16)]  # encapsulation, sec, nanosec, strlen
    if np.any(head[:, 0] != 0) or np.any(head[:, 1] > 1):
        bad = int(np.flatnonzero((head[:, 0] != 0) | (head[:, 1] > 1))[0])
        raise BagError(f"{what} #{first + bad}: not a CDR message (encapsulation "
                       f"{bytes(head[bad, :2]).hex()})")
    little = head[:, 1] == 1
    all_little = bool(np.all(little))
    if not all_little:
        for a in (4, 8, 12):  # byte-swap the big-endian words
            head[~little, a:a + 4] = head[~little, a:a + 4][:, ::-1]
    words = np.ascontiguousarray(head[:, 4:16]).view("<u4").reshape(n, 3).astype(np.int64)
    sec = np.where(words[:, 0] >= 2**31, words[:, 0] - 2**32, words[:, 0])
    nsec, strlen = words[:, 1], words[:, 2]
    off = 4 + _align8(12 + strlen)
    short = off + 8 * ndouble > lengths
    if np.any(short):
        bad = int(np.flatnonzero(short)[0])
        raise BagError(f"{what} #{first + bad}: {lengths[bad]} bytes is too short for {msgtype} "
                       f"with a frame_id of {strlen[bad]} bytes")
    raw = buf[(starts + off)[:, None, None] + (8 * np.asarray(cols))[None, :, None]
              + np.arange(8)[None, None, :]]
    if not all_little:
        raw[~little] = raw[~little][:, :, ::-1]
    values = np.ascontiguousarray(raw).view("<f8").reshape(n, len(cols))
    return sec * _NS + nsec, values


FILTER_STATE = "flight_fdi_msgs/msg/FilterState"
STRING = "std_msgs/msg/String"


def decode_string(payload: bytes | memoryview, what: str = "message") -> str:
    """The text of one std_msgs/String message (a CDR string: u32 length with its NUL, the
    bytes, the NUL), without loading a type store."""
    data = bytes(payload)
    if len(data) < 9 or data[0] != 0 or data[1] > 1:
        raise BagError(f"{what}: not a CDR message")
    (n,) = np.frombuffer(data, dtype="<u4" if data[1] == 1 else ">u4", count=1, offset=4)
    n = int(n)
    if n < 1 or 8 + n > len(data) or data[8 + n - 1] != 0:
        raise BagError(f"{what}: not a valid {STRING} (string length {n}, "
                       f"{len(data) - 8} bytes after the header)")
    try:
        return data[8:8 + n - 1].decode("utf-8")
    except UnicodeDecodeError:
        raise BagError(f"{what}: {STRING} is not UTF-8") from None


def decode_filter_state_x(payloads: "Payloads | Sequence[bytes | memoryview]",
                          what: str = "message"
                          ) -> tuple[np.ndarray, list[str], list[tuple[str, ...]],
                                     list[np.ndarray]]:
    """The leading fields of flight_fdi_msgs/FilterState messages, without full deserialization.

    Returns (stamp_ns (N,), channel per message, state_names per message, x per message). The
    layout is walked field by field (header, channel, state_names, x) with CDR alignment, which
    is ~10x faster than rosbags' generic deserializer for the many truth messages of a long flight.
    """
    import struct

    if not isinstance(payloads, Payloads):
        payloads = Payloads.from_list(payloads)
    raw = payloads.buf.tobytes() if payloads.buf.size else b""
    n = len(payloads)
    stamps = np.zeros(n, dtype=np.int64)
    channels: list[str] = []
    names: list[tuple[str, ...]] = []
    xs: list[np.ndarray] = []
    # everything from frame_id up to x is identical within one stream: remember those prefixes
    known: list[tuple[bytes, str, tuple[str, tuple[str, ...], int, int]]] = []
    for i, (start, length) in enumerate(zip(payloads.starts.tolist(), payloads.lengths.tolist())):
        data = raw[start:start + length]
        try:
            if len(data) < 16 or data[0] != 0 or data[1] > 1:
                raise ValueError("not a CDR message")
            e = "<" if data[1] == 1 else ">"
            sec, nsec = struct.unpack_from(e + "iI", data, 4)
            hit = next((h for pref, ee, h in known if ee == e and data.startswith(pref, 12)),
                       None)
            if hit is None:
                (flen,) = struct.unpack_from(e + "I", data, 12)
                p = 12 + flen  # payload-relative position after frame_id
                p = (p + 3) & ~3
                (clen,) = struct.unpack_from(e + "I", data, 4 + p)
                channel = data[4 + p + 4:4 + p + 4 + clen - 1].decode("utf-8")
                p += 4 + clen
                p = (p + 3) & ~3
                (count,) = struct.unpack_from(e + "I", data, 4 + p)
                p += 4
                state_names = []
                for _ in range(count):
                    p = (p + 3) & ~3
                    (slen,) = struct.unpack_from(e + "I", data, 4 + p)
                    state_names.append(data[4 + p + 4:4 + p + 4 + slen - 1].decode("utf-8"))
                    p += 4 + slen
                p = (p + 3) & ~3
                (nx,) = struct.unpack_from(e + "I", data, 4 + p)
                p += 4
                p = (p + 7) & ~7
                hit = (channel, tuple(state_names), p, nx)
                if len(known) < 64:
                    known.append((data[12:4 + p], e, hit))
            channel, state_names_t, p, nx = hit
            if 4 + p + 8 * nx > len(data):
                raise ValueError("message too short")
            x = np.frombuffer(data, dtype=e + "f8", count=nx, offset=4 + p).astype(float)
        except (ValueError, struct.error, UnicodeDecodeError) as exc:
            raise BagError(f"{what} #{i}: not a valid {FILTER_STATE} ({exc})") from None
        stamps[i] = sec * _NS + nsec
        channels.append(channel)
        names.append(state_names_t)
        xs.append(x)
    return stamps, channels, names, xs


# --------------------------------------------------------------------------- nav_msgs/Odometry

ODOMETRY = "nav_msgs/msg/Odometry"
#: doubles after child_frame_id: pose.pose (position 3, orientation 4), pose.covariance (36),
#: twist.twist (linear 3, angular 3), twist.covariance (36)
_ODOM_ORIENTATION, _ODOM_TWIST, _ODOM_TWIST_COV, _ODOM_DOUBLES = 3, 43, 49, 85
#: covariance entries of the linear velocity block (rows/columns 0..2 of the 6x6)
LINEAR_COV = (0, 1, 2, 6, 7, 8, 12, 13, 14)


def _strings_at(buf: np.ndarray, starts: np.ndarray, at: np.ndarray, lengths: np.ndarray,
                what: str, name: str) -> str:
    """The one string (without its NUL) that every message holds at payload offset ``at`` with
    length ``lengths`` (incl. NUL); BagError when the messages disagree."""
    if lengths.size == 0:
        return ""
    if np.any(lengths != lengths[0]):
        raise BagError(f"{what}: {name} changes within the topic")
    n = int(lengths[0])
    if n == 0:
        return ""
    raw = buf[(starts + 4 + at)[:, None] + np.arange(n)[None, :]]
    if np.any(raw != raw[0]):
        raise BagError(f"{what}: {name} changes within the topic")
    return bytes(raw[0, :-1]).decode("utf-8", "replace")


def decode_odometry(payloads: "Payloads | Sequence[bytes | memoryview]", what: str = "message"
                    ) -> tuple[np.ndarray, np.ndarray, str, str]:
    """nav_msgs/msg/Odometry series (little-endian CDR; vectorised like :func:`decode`):
    (stamp_ns (N,), values (N, 16) = orientation x, y, z, w, twist.linear x, y, z, the 9
    entries of the linear block of twist.covariance (row-major), header.frame_id,
    child_frame_id). Both strings must be the same in every message.

    Layout after the encapsulation: sec, nanosec, frame_id (u32 length + bytes), then
    child_frame_id at align4, then 85 doubles at align8 (pose 7, pose covariance 36, twist 6,
    twist covariance 36)."""
    if not isinstance(payloads, Payloads):
        payloads = Payloads.from_list(payloads)
    n = len(payloads)
    buf, starts, lengths = payloads.buf, payloads.starts, payloads.lengths
    if n == 0:
        return np.zeros(0, np.int64), np.zeros((0, 16)), "", ""
    if lengths.min() < 20:
        bad = int(np.argmin(lengths))
        raise BagError(f"{what} #{bad}: {lengths[bad]} bytes is too short for {ODOMETRY}")
    head = buf[starts[:, None] + np.arange(16)]
    if np.any(head[:, 0] != 0) or np.any(head[:, 1] != 1):
        raise BagError(f"{what}: {ODOMETRY} in big-endian or unknown CDR encapsulation is not "
                       "supported")
    words = np.ascontiguousarray(head[:, 4:16]).view("<u4").reshape(n, 3).astype(np.int64)
    sec = np.where(words[:, 0] >= 2**31, words[:, 0] - 2**32, words[:, 0])
    nsec, len1 = words[:, 1], words[:, 2]
    c = (12 + len1 + 3) & ~3
    if np.any(4 + c + 4 > lengths):
        raise BagError(f"{what}: too short for {ODOMETRY} with its frame_id")
    len2 = np.ascontiguousarray(buf[(starts + 4 + c)[:, None] + np.arange(4)]).view(
        "<u4").reshape(n).astype(np.int64)
    d = _align8(c + 4 + len2)
    short = 4 + d + 8 * _ODOM_DOUBLES > lengths
    if np.any(short):
        bad = int(np.flatnonzero(short)[0])
        raise BagError(f"{what} #{bad}: {lengths[bad]} bytes is too short for {ODOMETRY}")
    cols = [_ODOM_ORIENTATION + i for i in range(4)] + [_ODOM_TWIST + i for i in range(3)] \
        + [_ODOM_TWIST_COV + i for i in LINEAR_COV]
    raw = buf[(starts + 4 + d)[:, None, None] + (8 * np.asarray(cols))[None, :, None]
              + np.arange(8)[None, None, :]]
    values = np.ascontiguousarray(raw).view("<f8").reshape(n, len(cols))
    frame = _strings_at(buf, starts, np.full(n, 12), len1, what, "header.frame_id")
    child = _strings_at(buf, starts, c + 4, len2, what, "child_frame_id")
    return sec * _NS + nsec, values, frame, child


def encode_odometry(stamp_ns: np.ndarray, frame_id: str, child_frame_id: str,
                    orientation: np.ndarray, linear: np.ndarray,
                    linear_covariance: np.ndarray | None = None) -> list[bytes]:
    """Serialize nav_msgs/Odometry (little endian; position and angular rates zero) -- for
    tests and sample bags. orientation (N, 4) x, y, z, w; linear (N, 3); linear_covariance
    (3, 3) or (N, 3, 3) of twist.linear (the rest of both covariances zero)."""
    stamp_ns = np.asarray(stamp_ns, dtype=np.int64).reshape(-1)
    n = stamp_ns.size
    out = []
    f = frame_id.encode() + b"\x00"
    ch = child_frame_id.encode() + b"\x00"
    cov = np.zeros((n, 3, 3)) if linear_covariance is None else np.broadcast_to(
        np.asarray(linear_covariance, dtype=float), (n, 3, 3))
    import struct

    for k in range(n):
        sec, nsec = divmod(int(stamp_ns[k]), _NS)
        b = bytearray(b"\x00\x01\x00\x00")
        b += struct.pack("<iII", sec, nsec, len(f)) + f
        b += bytes(-(len(b) - 4) % 4) + struct.pack("<I", len(ch)) + ch
        b += bytes(-(len(b) - 4) % 8)
        doubles = np.zeros(_ODOM_DOUBLES)
        doubles[_ODOM_ORIENTATION:_ODOM_ORIENTATION + 4] = orientation[k]
        doubles[_ODOM_TWIST:_ODOM_TWIST + 3] = linear[k]
        tc = np.zeros((6, 6))
        tc[:3, :3] = cov[k]
        doubles[_ODOM_TWIST_COV:] = tc.reshape(-1)
        b += doubles.astype("<f8").tobytes()
        out.append(bytes(b))
    return out
