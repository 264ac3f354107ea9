"""Vectorised CDR of the variable-layout messages the project reads and writes in series:
std_msgs/String, flight_fdi_msgs/FilterState (walked with numpy, all the messages of one prefix
at once: ``decode_filter_state_columns``), nav_msgs/Odometry (two strings, then 85 doubles). The
wire rules are in :mod:`flight_fdi.bagio.cdr`.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..errors import BagError
from .series import _NS, Payloads, align8

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


def _string_at(data: bytes, e: str, p: int) -> tuple[str, int]:
    """The CDR string whose length is at payload position ``p`` (4-aligned here) and the
    position after it."""
    p = (p + 3) & ~3
    (n,) = struct.unpack_from(e + "I", data, 4 + p)
    if n < 1 or 4 + p + 4 + n > len(data):
        raise ValueError(f"string of length {n} does not fit")
    return data[4 + p + 4:4 + p + 4 + n - 1].decode("utf-8"), p + 4 + n


def _state_prefix(data: bytes, e: str) -> tuple[str, str, tuple[str, ...], int]:
    """(frame_id, channel, state_names, payload position after them) of a FilterState."""
    frame_id, p = _string_at(data, e, 8)
    channel, p = _string_at(data, e, p)
    p = (p + 3) & ~3
    (count,) = struct.unpack_from(e + "I", data, 4 + p)
    p += 4
    names = []
    for _ in range(count):
        name, p = _string_at(data, e, p)
        names.append(name)
    return frame_id, channel, tuple(names), p


def _checked(data: bytes) -> str:
    """The struct byte order of a CDR message (ValueError when it is not one)."""
    if len(data) < 16 or data[0] != 0 or data[1] > 1:
        raise ValueError("not a CDR message")
    return "<" if data[1] == 1 else ">"


def _malformed(what: str, i: int, exc: Exception) -> BagError:
    return BagError(f"{what} #{i}: not a valid {FILTER_STATE} ({exc})")


#: the sequences of a FilterState after its state names, in wire order
FILTER_STATE_SEQUENCES = ("x", "p", "z", "r", "h", "u")


@dataclass
class FilterStateColumns:
    """A series of flight_fdi_msgs/FilterState messages as columns (N messages): where each
    float64[] sequence lies in ``buf`` and how long it is, the scalars as arrays. The strings
    (frame_id, channel, state_names) are those of ``prefixes[prefix[i]]``."""

    buf: np.ndarray             # the messages back to back (read-only uint8)
    little: np.ndarray          # (N,) bool: CDR_LE (else CDR_BE)
    stamp_ns: np.ndarray        # (N,) int64
    prefix: np.ndarray          # (N,) int64 index into prefixes
    prefixes: list              # [(frame_id, channel, state_names)]
    offset: np.ndarray          # (6, N) int64: byte in buf of each sequence's first element
    count: np.ndarray           # (6, N) int64: elements of each sequence
    dt: np.ndarray              # (N,) float64
    fused: np.ndarray           # (N,) bool
    gated: np.ndarray           # (N,) bool
    reset: np.ndarray           # (N,) bool

    def of_channel(self, channel: str) -> np.ndarray:
        """The numbers (ascending) of the messages of ``channel``."""
        hits = [k for k, (_, c, _) in enumerate(self.prefixes) if c == channel]
        return np.flatnonzero(np.isin(self.prefix, hits))

    def values(self, field: str, index: np.ndarray) -> np.ndarray:
        """(len(index), k) float64: sequence ``field`` of the messages ``index``, which must all
        hold k elements (ValueError otherwise; k = 0 for no message)."""
        f = FILTER_STATE_SEQUENCES.index(field)
        index = np.asarray(index, dtype=np.int64)
        counts = self.count[f, index]
        k = int(counts[0]) if counts.size else 0
        if np.any(counts != k):
            raise ValueError(f"FilterState {field} of different lengths")
        raw = np.ascontiguousarray(self.buf[self.offset[f, index][:, None]
                                            + np.arange(8 * k)[None, :]])
        big = ~self.little[index]
        if np.any(big):
            raw[big] = raw[big].reshape(-1, k, 8)[:, :, ::-1].reshape(-1, 8 * k)
        return raw.view("<f8").reshape(index.size, k).astype(float)

    def array(self, field: int, i: int) -> np.ndarray:
        """Sequence number ``field`` (FILTER_STATE_SEQUENCES) of message ``i``: a read-only
        view for CDR_LE, a copy for CDR_BE."""
        o, n = int(self.offset[field, i]), int(self.count[field, i])
        raw = self.buf[o:o + 8 * n]
        return raw.view("<f8") if self.little[i] else raw.view(">f8").astype(float)


def _gather(buf: np.ndarray, at: np.ndarray, size: int, dtype: str) -> np.ndarray:
    """One value of ``dtype`` (``size`` bytes) per message at byte ``at`` of ``buf``."""
    return np.ascontiguousarray(buf[at[:, None] + np.arange(size)]).view(dtype).reshape(-1)


def _same_bytes(buf: np.ndarray, at: np.ndarray, pattern: bytes) -> np.ndarray:
    """Per position in ``at``: whether ``buf`` holds ``pattern`` there (in blocks: the gather
    indexes with (messages x bytes) int64 arrays)."""
    want = np.frombuffer(pattern, dtype=np.uint8)
    out = np.zeros(at.size, dtype=bool)
    block = max(1, (1 << 20) // max(1, want.size))
    for k in range(0, at.size, block):
        out[k:k + block] = np.all(buf[at[k:k + block, None] + np.arange(want.size)] == want,
                                  axis=1)
    return out


def _prefix_groups(payloads: Payloads, what: str, bad: list[tuple[int, Exception]]
                   ) -> tuple[np.ndarray, list, list]:
    """(prefix number per message (-1: malformed), [(frame_id, channel, state_names)],
    [(byte order, payload position of x's count)]). The prefix up to x is the same within one
    stream: it is decoded once per distinct prefix and recognised by its bytes. Malformed
    messages are added to ``bad`` as (number, reason)."""
    buf, starts, lengths = payloads.buf, payloads.starts, payloads.lengths
    n = len(payloads)
    group = np.full(n, -1, dtype=np.int64)
    prefixes, layouts = [], []
    head = np.zeros((n, 2), dtype=np.uint8)
    fits = lengths >= 16
    head[fits] = buf[starts[fits, None] + np.arange(2)]
    cdr_ok = fits & (head[:, 0] == 0) & (head[:, 1] <= 1)
    if not cdr_ok.all():
        bad.append((int(np.argmin(cdr_ok)), ValueError("not a CDR message")))
    todo = np.flatnonzero(cdr_ok)
    while todo.size:
        i = int(todo[0])
        data = buf[starts[i]:starts[i] + lengths[i]].tobytes()
        e = "<" if data[1] else ">"
        try:
            frame_id, channel, names, p = _state_prefix(data, e)
        except (ValueError, struct.error, UnicodeDecodeError) as exc:
            bad.append((i, exc))
            break
        cand = todo[(head[todo, 1] == data[1]) & (lengths[todo] >= 4 + p)]
        same = cand[_same_bytes(buf, starts[cand] + 12, data[12:4 + p])]
        group[same] = len(prefixes)
        prefixes.append((frame_id, channel, names))
        layouts.append((e, p))
        todo = todo[group[todo] < 0]
    return group, prefixes, layouts


def _walk(buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray, e: str, p: int
          ) -> tuple[np.ndarray, ...]:
    """The fields after the state names of messages of one prefix (byte order ``e``, x's
    count at payload position ``p``), all at once: (offsets (6, n), counts (6, n), dt, flags
    (n, 3), ok (n,) False for a message too short for its sequences)."""
    n = starts.size
    pos = np.full(n, p, dtype=np.int64)
    ok = np.ones(n, dtype=bool)
    offsets, counts = np.zeros((6, n), np.int64), np.zeros((6, n), np.int64)
    for f in range(6):
        pos = (pos + 3) & ~3
        ok &= 4 + pos + 4 <= lengths
        cnt = np.where(ok, _gather(buf, np.where(ok, starts + 4 + pos, 0), 4, e + "u4"), 0)
        pos = pos + 4
        pos = np.where(cnt > 0, (pos + 7) & ~7, pos)
        offsets[f], counts[f] = starts + 4 + pos, cnt
        pos = pos + 8 * cnt.astype(np.int64)
        ok &= 4 + pos <= lengths
    pos = (pos + 7) & ~7
    ok &= 4 + pos + 8 + 3 <= lengths
    at = np.where(ok, starts + 4 + pos, 0)
    dt = np.where(ok, _gather(buf, at, 8, e + "f8"), 0.0)
    flags = buf[at[:, None] + 8 + np.arange(3)] != 0
    return offsets, counts, dt.astype(float), flags, ok


def decode_filter_state_columns(payloads: "Payloads | Sequence[bytes | memoryview]",
                                what: str = "message") -> FilterStateColumns:
    """Every field of a series of flight_fdi_msgs/FilterState messages (either byte order) as
    :class:`FilterStateColumns`: the layout is walked with numpy for all the messages of one
    prefix (frame_id, channel, state_names) at once. BagError naming ``what`` and the first
    malformed message's number."""
    if not isinstance(payloads, Payloads):
        payloads = Payloads.from_list(payloads)
    n = len(payloads)
    buf = payloads.buf.view()
    buf.flags.writeable = False
    bad: list[tuple[int, Exception]] = []
    group, prefixes, layouts = _prefix_groups(payloads, what, bad)
    starts, lengths = payloads.starts, payloads.lengths
    little = np.zeros(n, dtype=bool)
    stamp_ns = np.zeros(n, dtype=np.int64)
    offset, count = np.zeros((6, n), np.int64), np.zeros((6, n), np.int64)
    dt, flags = np.zeros(n), np.zeros((n, 3), dtype=bool)
    for g, (e, p) in enumerate(layouts):
        idx = np.flatnonzero(group == g)
        s = starts[idx]
        sec = _gather(buf, s + 4, 4, e + "i4").astype(np.int64)
        stamp_ns[idx] = sec * _NS + _gather(buf, s + 8, 4, e + "u4").astype(np.int64)
        little[idx] = e == "<"
        offset[:, idx], count[:, idx], dt[idx], flags[idx], ok = _walk(buf, s, lengths[idx],
                                                                      e, p)
        if not ok.all():
            bad.append((int(idx[np.argmin(ok)]), ValueError("message too short")))
    if bad:
        raise _malformed(what, *min(bad, key=lambda b: b[0]))
    return FilterStateColumns(buf, little, stamp_ns, group, prefixes, offset, count, dt,
                              flags[:, 0], flags[:, 1], flags[:, 2])


def decode_filter_state_x(payloads: "Payloads | Sequence[bytes | memoryview]",
                          what: str = "message"
                          ) -> tuple[np.ndarray, list[str], list[tuple[str, ...]],
                                     list[np.ndarray]]:
    """The leading fields of flight_fdi_msgs/FilterState messages, without full deserialization.

    Returns (stamp_ns (N,), channel per message, state_names per message, x per message)
    (:func:`decode_filter_state_columns`: ~10x faster than rosbags' generic deserializer for
    the many truth messages of a long flight).
    """
    cols = decode_filter_state_columns(payloads, what)
    pre = [cols.prefixes[g] for g in cols.prefix.tolist()]
    return (cols.stamp_ns, [q[1] for q in pre], [q[2] for q in pre],
            [cols.array(0, i) for i in range(len(pre))])


@dataclass(slots=True)
class FilterStateRecord:
    """One flight_fdi_msgs/FilterState, every field (arrays: read-only float64 views)."""

    stamp_ns: int
    frame_id: str
    channel: str
    state_names: tuple[str, ...]
    x: np.ndarray
    p: np.ndarray
    z: np.ndarray
    r: np.ndarray
    h: np.ndarray
    u: np.ndarray
    dt: float
    fused: bool
    gated: bool
    reset: bool


def decode_filter_states(payloads: "Payloads | Sequence[bytes | memoryview]",
                         what: str = "message") -> list[FilterStateRecord]:
    """Every field of a series of flight_fdi_msgs/FilterState messages (either byte order),
    one record per message (:func:`decode_filter_state_columns`). BagError naming ``what`` and
    the message number for a malformed one."""
    c = decode_filter_state_columns(payloads, what)
    return [FilterStateRecord(stamp, *c.prefixes[g], *(c.array(f, i) for f in range(6)), dt,
                              fused, gated, reset)
            for i, (stamp, g, dt, fused, gated, reset) in enumerate(zip(
                c.stamp_ns.tolist(), c.prefix.tolist(), c.dt.tolist(), c.fused.tolist(),
                c.gated.tolist(), c.reset.tolist()))]


# --------------------------------------------------------------------------- nav_msgs/Odometry

ODOMETRY = "nav_msgs/msg/Odometry"
#: doubles after child_frame_id: pose.pose (position 3, orientation 4), pose.covariance (36),
#: twist.twist (linear 3, angular 3), twist.covariance (36)
ODOM_ORIENTATION, ODOM_TWIST, ODOM_TWIST_COV, ODOM_DOUBLES = 3, 43, 49, 85
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
    d = align8(c + 4 + len2)
    short = 4 + d + 8 * ODOM_DOUBLES > lengths
    if np.any(short):
        bad = int(np.flatnonzero(short)[0])
        raise BagError(f"{what} #{bad}: {lengths[bad]} bytes is too short for {ODOMETRY}")
    cols = [ODOM_ORIENTATION + i for i in range(4)] + [ODOM_TWIST + i for i in range(3)] \
        + [ODOM_TWIST_COV + i for i in LINEAR_COV]
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
    for k in range(n):
        sec, nsec = divmod(int(stamp_ns[k]), _NS)
        b = bytearray(b"\x00\x01\x00\x00")
        b += struct.pack("<iII", sec, nsec, len(f)) + f
        b += bytes(-(len(b) - 4) % 4) + struct.pack("<I", len(ch)) + ch
        b += bytes(-(len(b) - 4) % 8)
        doubles = np.zeros(ODOM_DOUBLES)
        doubles[ODOM_ORIENTATION:ODOM_ORIENTATION + 4] = orientation[k]
        doubles[ODOM_TWIST:ODOM_TWIST + 3] = linear[k]
        tc = np.zeros((6, 6))
        tc[:3, :3] = cov[k]
        doubles[ODOM_TWIST_COV:] = tc.reshape(-1)
        b += doubles.astype("<f8").tobytes()
        out.append(bytes(b))
    return out
