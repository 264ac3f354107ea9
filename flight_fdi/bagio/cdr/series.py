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

The 3-D simulator's topics: ``encode_doubles`` / ``decode_doubles`` for any type that is a
header followed by doubles (``sensor_msgs/Imu``: 37; the height references
``sensor_msgs/FluidPressure``: 2 and ``geometry_msgs/PointStamped``: 3), ``encode_navsatfix`` for
``sensor_msgs/NavSatFix``, which ``decode_doubles`` also reads (its 12 doubles: latitude,
longitude, altitude, position_covariance[9]; they follow ``status``: int8 status at ``12 + L``,
uint16 service 2-aligned after it, then the doubles 8-aligned, then uint8 covariance_type;
``decode_navsatfix_flags`` reads status and covariance_type).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import BagError

TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
TWIST_COV_STAMPED = "geometry_msgs/msg/TwistWithCovarianceStamped"
IMU = "sensor_msgs/msg/Imu"
NAVSATFIX = "sensor_msgs/msg/NavSatFix"
FLUID_PRESSURE = "sensor_msgs/msg/FluidPressure"
POINT_STAMPED = "geometry_msgs/msg/PointStamped"

#: number of doubles after the header for each supported type
_DOUBLES = {TWIST_STAMPED: 6, TWIST_COV_STAMPED: 6 + 36}
#: other types made of a header and doubles (encode_doubles / decode_doubles only)
_HEADER_DOUBLES = {IMU: 4 + 9 + 3 + 9 + 3 + 9,
                   FLUID_PRESSURE: 2,           # fluid_pressure (Pa), variance (Pa^2; 0: unknown)
                   POINT_STAMPED: 3}            # point x, y, z
#: types whose doubles follow a sensor_msgs/NavSatStatus (decode_doubles only): number of doubles
_AFTER_STATUS = {NAVSATFIX: 3 + 9}
_NS = 1_000_000_000


def supported(msgtype: str) -> bool:
    return msgtype in _DOUBLES


def align8(n: np.ndarray | int):
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
    ndouble = _DOUBLES.get(msgtype, _HEADER_DOUBLES.get(msgtype))
    if ndouble is None:
        raise BagError(f"fast CDR encoding does not support {msgtype!r}")
    stamp_ns = np.asarray(stamp_ns, dtype=np.int64).reshape(-1)
    n = stamp_ns.size
    values = np.asarray(values, dtype=np.float64)
    if values.shape != (n, ndouble):
        raise BagError(f"encode {msgtype}: values must have shape ({n}, {ndouble}), "
                       f"got {values.shape}")
    off = align8(12 + len(frame_id.encode("utf-8")) + 1)
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
    pd = align8(ps + 2)                            # 12 doubles, 8-aligned
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
    stamp_ns, values = decode_doubles(msgtype, payloads, twist_cols + [6 + c for c in cov_cols],
                                      what)
    twist = values[:, :len(twist_cols)]
    cov_out = values[:, len(twist_cols):] if has_cov else None
    return stamp_ns, twist, cov_out


def decode_doubles(msgtype: str, payloads: "Payloads | Sequence[bytes | memoryview]",
                   cols: Sequence[int], what: str = "message") -> tuple[np.ndarray, np.ndarray]:
    """(stamp_ns (N,) int64, the doubles at ``cols`` (N, len(cols))) of a series of a type made
    of a header and doubles (the twists, sensor_msgs/Imu: 37 doubles in declaration order), or
    of sensor_msgs/NavSatFix (its 12 doubles). Each message has its own frame_id, so its own
    offsets. Raises BagError naming ``what`` when a message is too short or malformed."""
    ndouble = _ndouble(msgtype)
    if ndouble is None:
        raise BagError(f"fast CDR decoding does not support {msgtype!r}")
    cols = [int(c) for c in cols]
    if any(not 0 <= c < ndouble for c in cols):
        raise BagError(f"decode {msgtype}: columns must be in 0..{ndouble - 1}")
    if not isinstance(payloads, Payloads):
        payloads = Payloads.from_list(payloads)
    n = len(payloads)
    stamp_ns = np.zeros(n, np.int64)
    values = np.zeros((n, len(cols)))
    # in blocks: the gathers index with (messages x bytes) int64 arrays, which for a 10-hour
    # flight in one piece would be several hundred MB
    for a in range(0, n, _BLOCK):
        b = min(n, a + _BLOCK)
        stamp_ns[a:b], values[a:b] = _decode_block(
            msgtype, payloads.buf, payloads.starts[a:b], payloads.lengths[a:b], cols, what, a)
    return stamp_ns, values


#: messages decoded per block
_BLOCK = 65536


def _ndouble(msgtype: str) -> int | None:
    return _DOUBLES.get(msgtype, _HEADER_DOUBLES.get(msgtype, _AFTER_STATUS.get(msgtype)))


def _first_double(msgtype: str, strlen: np.ndarray) -> tuple[np.ndarray, int]:
    """(offset in the payload of the first double, bytes the message has after the doubles) of
    messages whose frame_ids take ``strlen`` bytes (with the NUL)."""
    end = 12 + strlen
    if msgtype in _AFTER_STATUS:       # int8 status, uint16 service (2-aligned); uint8 after
        return 4 + align8(((end + 2) & ~1) + 2), 1
    return 4 + align8(end), 0


def _decode_block(msgtype: str, buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray,
                  cols: list[int], what: str, first: int) -> tuple[np.ndarray, np.ndarray]:
    """(stamp_ns, the doubles at ``cols``) of messages ``first`` ... of a series."""
    n = starts.size
    ndouble = _ndouble(msgtype)
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
    off, tail = _first_double(msgtype, strlen)
    short = off + 8 * ndouble + tail > lengths
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


def decode_navsatfix_flags(payloads: "Payloads | Sequence[bytes | memoryview]",
                           what: str = "message") -> tuple[np.ndarray, np.ndarray]:
    """(status.status int8 (N,), position_covariance_type uint8 (N,)) of sensor_msgs/NavSatFix
    messages (each with its own frame_id, so its own offsets); BagError naming ``what`` for a
    message too short to hold them (``decode_doubles`` checks the rest)."""
    if not isinstance(payloads, Payloads):
        payloads = Payloads.from_list(payloads)
    n = len(payloads)
    if n == 0:
        return np.zeros(0, np.int8), np.zeros(0, np.uint8)
    starts, lengths, buf = payloads.starts, payloads.lengths, payloads.buf
    if lengths.min() < 16:
        bad = int(np.argmin(lengths))
        raise BagError(f"{what} #{bad}: {lengths[bad]} bytes is too short for {NAVSATFIX}")
    raw = buf[starts[:, None] + np.arange(12, 16)]
    little = buf[starts + 1] == 1
    raw[~little] = raw[~little][:, ::-1]
    strlen = np.ascontiguousarray(raw).view("<u4").reshape(n).astype(np.int64)
    off, tail = _first_double(NAVSATFIX, strlen)
    short = off + 96 + tail > lengths
    if np.any(short):
        bad = int(np.flatnonzero(short)[0])
        raise BagError(f"{what} #{bad}: {lengths[bad]} bytes is too short for {NAVSATFIX} "
                       f"with a frame_id of {strlen[bad]} bytes")
    status = buf[starts + 16 + strlen].view(np.int8)
    return status.copy(), buf[starts + off + 96].copy()
