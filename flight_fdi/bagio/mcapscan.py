"""Fast extraction of the raw messages of chosen channels from an MCAP file: the numpy
back-end of the bag reader (``reader.read_raw`` / ``reader.scan_mcap``; not called elsewhere).

rosbags yields one message at a time through Python generators (several microseconds each), too
slow for a 3-hour flight. This scanner walks the top-level records of the MCAP data section,
decompresses each chunk once and locates the messages of the wanted channels with the chunk's
Message Index records (numpy, no per-message Python work). Chunks without message indexes are
walked record by record for the messages' places, their heads then read with numpy. One walk of
the records (``_records``) serves the data section, a chunk's channel records and such a chunk.
Format: https://mcap.dev/spec (magic, then records of ``opcode u8, length u64, content``;
little endian).

Only what the reader needs is supported: uncompressed or zstd chunks, no nested chunks.
Anything else raises ``Unsupported`` and the caller falls back to rosbags' reader.
"""
from __future__ import annotations

import struct
import sys
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from .cdr import Payloads
from .errors import BagError

if sys.version_info >= (3, 14):  # pragma: no cover
    from compression import zstd
else:
    from backports import zstd

#: the MCAP magic and record opcodes (https://mcap.dev/spec; the writer, bagstore, uses them too)
MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 1, 2, 3, 4, 5, 6
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_STATISTICS, OP_METADATA = 0x07, 0x08, 0x0B, 0x0C
OP_METADATA_INDEX, OP_SUMMARY_OFFSET, OP_DATA_END = 0x0D, 0x0E, 0x0F
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_MSG_HEAD = struct.Struct("<HIQQ")  # channel_id, sequence, log_time, publish_time


class Unsupported(Exception):
    """A valid MCAP feature this fast path does not handle (use the generic reader)."""


@dataclass
class ChannelMessages:
    """Raw messages of one channel: receive (log) times and payloads, in file order."""

    log_ns: np.ndarray
    payloads: Payloads
    #: position in the file (chunk number, offset) used to order messages with equal times
    order: np.ndarray


def _string(buf: bytes | memoryview, pos: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(buf, pos)
    pos += 4
    return bytes(buf[pos:pos + n]).decode("utf-8"), pos + n


def _records(buf: bytes | memoryview, start: int, end: int) -> Iterator[tuple[int, int, int]]:
    """(opcode, content start, content end) of each record of ``buf[start:end]``, in order --
    the one walk of the records (the file's data section, a chunk's records). A record whose
    length runs past ``end`` is yielded as it is: the caller says what that means."""
    u64 = _U64.unpack_from
    pos = start
    while pos + 9 <= end:
        content = pos + 9
        pos = content + u64(buf, pos + 1)[0]
        yield buf[content - 9], content, pos


def _channel_topic(content: bytes) -> tuple[int, str]:
    (cid,) = _U16.unpack_from(content, 0)
    topic, _ = _string(content, 4)
    return cid, topic


#: per chunk: ((compression, offset of its data in the file, compressed size, uncompressed
#: size), its message-index records (channel id, index bytes))
_Piece = tuple[tuple[str, int, int, int], list[tuple[int, bytes]]]
#: a message outside any chunk: (channel id, log time, data)
_Loose = tuple[int, int, bytes]


def scan(path: str, topics: set[str], what: str) -> dict[str, ChannelMessages]:
    """Messages of ``topics`` in ``path`` (an .mcap file), per topic in receive-time order."""
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise BagError(f"bag '{what}': cannot read {path}: {exc.strerror}") from None
    if data[:8] != MAGIC:
        raise BagError(f"bag '{what}': {path} is not an MCAP file")
    channels, pieces, loose = _top_level(data, path, what)
    # the chunks are decompressed into ONE buffer, so that the records are never held twice (a
    # 10-hour flight is several hundred MB of them)
    buf, bases = _decompress(data, pieces, loose, path, what)
    del data
    chunk_views = [memoryview(buf[int(bases[k]):int(bases[k + 1])]) for k in range(len(pieces))]
    # channel records may also sit inside chunks (rosbags and rosbag2 put them there)
    for raw in chunk_views:
        _collect_channels(raw, channels, what, path, leading_only=True)
    if not set(topics) <= set(channels.values()):
        for raw in chunk_views:  # rare: a channel record after messages in a chunk
            _collect_channels(raw, channels, what, path, leading_only=False)
    wanted = {cid: t for cid, t in channels.items() if t in topics}
    per_topic: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]] = {
        t: [] for t in topics}
    for k, ((_, indexes), raw) in enumerate(zip(pieces, chunk_views)):
        base = int(bases[k])
        if indexes:
            found = _from_index(buf[base:int(bases[k + 1])], indexes, wanted, what, path)
        else:
            found = _from_records(buf[base:int(bases[k + 1])], raw, wanted, what, path)
        for cid, (log, offs, lens) in found.items():
            order = np.stack([np.full(offs.size, k, dtype=np.int64), offs], axis=1)
            per_topic[wanted[cid]].append((log, offs + base, lens, order))
    if loose:  # after the chunks in the buffer, in file order
        k, at = len(pieces), int(bases[-1])
        for j, (cid, log, d) in enumerate(loose):
            buf[at:at + len(d)] = np.frombuffer(d, dtype=np.uint8)
            if cid in wanted:
                per_topic[wanted[cid]].append((np.array([log], np.int64),
                                               np.array([at], np.int64),
                                               np.array([len(d)], np.int64),
                                               np.array([[k, j]], np.int64)))
            at += len(d)
    return {topic: _in_time_order(parts, buf) for topic, parts in per_topic.items()}


def _top_level(data: bytes, path: str, what: str
               ) -> tuple[dict[int, str], list[_Piece], list[_Loose]]:
    """The channels, chunks (with their message indexes) and loose messages of the data
    section (the summary section after Data End repeats the schemas and channels)."""
    total = len(data)
    channels: dict[int, str] = {}
    pieces: list[_Piece] = []
    loose: list[_Loose] = []
    in_data = True
    try:
        for op, start, end in _records(data, 8, total):
            if end > total:
                raise BagError(f"bag '{what}': {path} is truncated (a record runs past the end)")
            if op == OP_DATA_END:
                in_data = False
            elif op == OP_CHANNEL:
                cid, topic = _channel_topic(data[start:end])
                channels[cid] = topic
            elif op == OP_CHUNK and in_data:
                pieces.append((_chunk_info(data, start, end, path, what), []))
            elif op == OP_MESSAGE_INDEX and in_data:
                if not pieces:
                    raise BagError(f"bag '{what}': {path} has a message index before any chunk")
                (cid,) = _U16.unpack_from(data, start)
                (n,) = _U32.unpack_from(data, start + 2)
                pieces[-1][1].append((cid, data[start + 6:start + 6 + n]))
            elif op == OP_MESSAGE and in_data:
                cid, _, log, _ = _MSG_HEAD.unpack_from(data, start)
                loose.append((cid, log, data[start + 22:end]))
    except (struct.error, UnicodeDecodeError):
        raise BagError(f"bag '{what}': {path} is truncated or corrupt") from None
    return channels, pieces, loose


def _chunk_info(data: bytes, start: int, end: int, path: str, what: str
                ) -> tuple[str, int, int, int]:
    """(compression, offset of the chunk's data, compressed size, uncompressed size) of the
    chunk record whose content is ``data[start:end]``."""
    (usize,) = _U64.unpack_from(data, start + 16)
    comp, p = _string(data, start + 28)
    (clen,) = _U64.unpack_from(data, p)
    if p + 8 + clen > end:
        raise BagError(f"bag '{what}': {path} has a chunk larger than its record")
    if comp not in ("", "zstd"):
        raise Unsupported(f"chunk compression {comp!r}")
    declared = clen if comp == "" else _zstd_size(data[p + 8:p + 8 + clen])
    if declared is not None and declared != usize:
        raise BagError(f"bag '{what}': {path} has a chunk of {declared} bytes, "
                       f"expected {usize}")
    return comp, p + 8, clen, usize


def _decompress(data: bytes, pieces: list[_Piece], loose: list[_Loose], path: str, what: str
                ) -> tuple[np.ndarray, np.ndarray]:
    """(one buffer holding every chunk's records back to back, with room for the loose
    messages after them; the start of chunk k in it, bases[k], and the end bases[-1])."""
    sizes = [d[3] for d, _ in pieces]
    bases = np.concatenate([[0], np.cumsum(sizes, dtype=np.int64)]).astype(np.int64) \
        if pieces else np.zeros(1, np.int64)
    loose_size = sum(len(d) for _, _, d in loose)
    try:
        buf = np.empty(int(bases[-1]) + loose_size, dtype=np.uint8)
    except (MemoryError, ValueError):
        raise BagError(f"bag '{what}': {path} declares chunks of {int(bases[-1])} bytes in "
                       "all, more than can be held (a corrupt size field?)") from None
    for k, ((comp, at, clen, usize), _) in enumerate(pieces):
        b0 = int(bases[k])
        if comp == "zstd":
            try:
                out = zstd.decompress(data[at:at + clen])
            except Exception as exc:
                raise BagError(f"bag '{what}': {path} has a corrupt compressed chunk "
                               f"({_first_line(exc)})") from None
            if len(out) != usize:
                raise BagError(f"bag '{what}': {path} has a chunk of {len(out)} bytes, "
                               f"expected {usize}")
            buf[b0:b0 + usize] = np.frombuffer(out, dtype=np.uint8)
            del out
        else:
            buf[b0:b0 + usize] = np.frombuffer(data, dtype=np.uint8, count=clen, offset=at)
    return buf, bases


def _in_time_order(parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
                   buf: np.ndarray) -> ChannelMessages:
    """One topic's messages found in the chunks, sorted by log time (ties in file order)."""
    if not parts:
        none = np.zeros(0, np.int64)
        return ChannelMessages(none, Payloads(buf, none, none), np.zeros((0, 2), np.int64))
    log = np.concatenate([p[0] for p in parts])
    starts = np.concatenate([p[1] for p in parts])
    lens = np.concatenate([p[2] for p in parts])
    order = np.concatenate([p[3] for p in parts])
    idx = np.lexsort((order[:, 1], order[:, 0], log))
    return ChannelMessages(log[idx], Payloads(buf, starts[idx], lens[idx]), order[idx])


def _zstd_size(frame: bytes) -> int | None:
    """The content size a zstd frame declares (None when it declares none or is unreadable:
    decompressing it then tells)."""
    try:
        size = zstd.get_frame_info(frame).decompressed_size
    except Exception:
        return None
    return None if size is None else int(size)


def _first_line(exc: BaseException) -> str:
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0]


def _collect_channels(raw: bytes | memoryview, channels: dict[int, str], what: str, path: str,
                      leading_only: bool) -> None:
    """Find the channel records in a chunk: those before its first message, or all of them."""
    try:
        for op, start, end in _records(raw, 0, len(raw)):
            if op == OP_CHANNEL:
                cid, topic = _channel_topic(raw[start:end])
                channels[cid] = topic
            elif op != OP_SCHEMA and leading_only:
                return
    except (struct.error, UnicodeDecodeError):
        raise BagError(f"bag '{what}': {path} has a corrupt chunk") from None


def _from_index(arr: np.ndarray, indexes: list[tuple[int, bytes]], wanted: dict[int, str],
                what: str, path: str) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    found: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    size = arr.size
    for cid, entries in indexes:
        if cid not in wanted or not entries:
            continue
        if len(entries) % 16:
            raise BagError(f"bag '{what}': {path} has a malformed message index")
        pairs = np.frombuffer(entries, dtype="<u8").reshape(-1, 2).astype(np.int64)
        log, offs = pairs[:, 0], pairs[:, 1]
        if offs.min() < 0 or offs.max() + 31 > size:
            raise BagError(f"bag '{what}': {path} has a message index pointing outside its chunk")
        if np.any(arr[offs] != OP_MESSAGE):
            raise BagError(f"bag '{what}': {path} has a message index that does not point at "
                           "messages")
        rec_len = arr[(offs + 1)[:, None] + np.arange(8)].view("<u8").reshape(-1).astype(np.int64)
        chan = arr[(offs + 9)[:, None] + np.arange(2)].view("<u2").reshape(-1)
        if np.any(chan != cid) or np.any(rec_len < 22) or np.any(offs + 9 + rec_len > size):
            raise BagError(f"bag '{what}': {path} has a corrupt message record")
        prev = found.get(cid)
        start = offs + 31
        lens = rec_len - 22
        if prev is not None:
            log, start, lens = (np.concatenate([prev[0], log]), np.concatenate([prev[1], start]),
                                np.concatenate([prev[2], lens]))
        found[cid] = (log, start, lens)
    return found


def _from_records(arr: np.ndarray, raw: memoryview, wanted: dict[int, str], what: str,
                  path: str) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The messages of one uncompressed chunk without message indexes (``arr``, and ``raw``
    the same bytes): its records walked once for the messages' places, their heads (channel,
    log time, length) then read with numpy, as :func:`_from_index` does."""
    total = len(raw)
    places: list[int] = []
    last = 0        # the end of the last record: the chunk's end unless one overruns it
    for op, start, last in _records(raw, 0, total):
        if op == OP_MESSAGE:
            places.append(start)
        elif op == OP_CHUNK:
            raise BagError(f"bag '{what}': {path} has a nested chunk")
    if last != total:
        raise BagError(f"bag '{what}': {path} has a corrupt chunk (records overrun it)")
    content = np.array(places, dtype=np.int64)
    rec_len = arr[(content - 8)[:, None] + np.arange(8)].view("<u8").reshape(-1).astype(np.int64)
    if np.any(rec_len < 22):
        raise BagError(f"bag '{what}': {path} has a corrupt message record")
    chan = arr[content[:, None] + np.arange(2)].view("<u2").reshape(-1)
    log = arr[(content + 6)[:, None] + np.arange(8)].view("<u8").reshape(-1).astype(np.int64)
    found = {}
    for cid in np.unique(chan):
        if int(cid) in wanted:
            mine = chan == cid
            found[int(cid)] = (log[mine], content[mine] + 22, rec_len[mine] - 22)
    return found
