"""The storage files of an incrementally written bag (:class:`~.writer.RecordingBag`): one
MCAP file appended to with one ``pwrite`` per flush, or one sqlite3 file with one transaction
per flush. No rclpy.

* mcap: each flush writes ONE ``pwrite`` at the end of the data section: the new chunk(s) with
  their message indexes, a Data End record and a Footer without summary (``summary_start = 0``),
  which every MCAP reader accepts by scanning the data section. The next flush overwrites that
  tail. A clean close writes the full summary (schemas, channels, chunk indexes, statistics,
  the rosbag2 metadata record) so that indexed reading is fast. Format: https://mcap.dev/spec;
* sqlite3 (rosbag2 schema version 4): each flush inserts the buffered messages in one
  transaction and commits it (rollback journal: a kill never leaves half a transaction visible
  to a normal SQLite reader).

A message is ``(connection id, receive time ns, publish time ns, CDR bytes)``.
"""
from __future__ import annotations

import os
import sqlite3
import struct
import sys
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

if sys.version_info >= (3, 14):  # pragma: no cover
    from compression import zstd
else:
    from backports import zstd

from .mcapscan import (MAGIC, OP_CHANNEL, OP_CHUNK, OP_CHUNK_INDEX, OP_DATA_END, OP_FOOTER,
                       OP_HEADER, OP_MESSAGE, OP_MESSAGE_INDEX, OP_METADATA, OP_METADATA_INDEX,
                       OP_SCHEMA, OP_STATISTICS, OP_SUMMARY_OFFSET)

_CHUNK_TARGET = 1 << 20  # bytes of messages per chunk (as rosbag2 and rosbags)


def _rec(op: int, content: bytes) -> bytes:
    return struct.pack("<BQ", op, len(content)) + content


def _str(text: str) -> bytes:
    raw = text.encode("utf-8")
    return struct.pack("<I", len(raw)) + raw


def _strmap(items: dict[str, str]) -> bytes:
    body = b"".join(_str(k) + _str(v) for k, v in items.items())
    return struct.pack("<I", len(body)) + body


@dataclass
class _ChunkInfo:
    start_ns: int
    end_ns: int
    offset: int               # file offset of the chunk record
    length: int               # chunk record length (opcode + length + content)
    index_offsets: dict[int, int]
    index_length: int
    compressed_size: int
    uncompressed_size: int


class McapStorage:
    """The mcap file of a bag, appended to with one ``pwrite`` per flush (see module doc)."""

    suffix = ".mcap"
    identifier = "mcap"

    def __init__(self, path: Path, compression: str) -> None:
        self.path = path
        self.compression = "zstd" if compression == "zstd" else ""
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        self._schemas: dict[str, tuple[int, bytes]] = {}   # msgtype -> (id, record)
        self._channels: list[bytes] = []
        self._pending: list[bytes] = []                   # top-level records not yet written
        self._chunks: list[_ChunkInfo] = []
        self._seq: dict[int, int] = {}
        self._stats: dict[int, int] = {}
        self._start = 2**63 - 1
        self._end_t = 0
        header = MAGIC + _rec(OP_HEADER, _str("ros2") + _str("flight_fdi recorder_node"))
        self._end = len(header)  # file offset where the data section continues
        self._pwrite(header + self._tail(), 0)

    def add_connection(self, cid: int, topic: str, msgtype: str, msgdef: str,
                       qos_yaml: str) -> None:
        if msgtype not in self._schemas:
            sid = len(self._schemas) + 1
            rec = _rec(OP_SCHEMA, struct.pack("<H", sid) + _str(msgtype) + _str("ros2msg")
                       + _str(msgdef))
            self._schemas[msgtype] = (sid, rec)
            self._pending.append(rec)
        sid = self._schemas[msgtype][0]
        rec = _rec(OP_CHANNEL, struct.pack("<HH", cid, sid) + _str(topic) + _str("cdr")
                   + _strmap({"offered_qos_profiles": qos_yaml}))
        self._channels.append(rec)
        self._pending.append(rec)
        self._seq[cid] = 0
        self._stats[cid] = 0

    def _chunk(self, messages: Sequence[tuple[int, int, int, bytes]], offset: int) -> bytes:
        """A chunk record and its message index records, to be written at ``offset``."""
        body = bytearray()
        index: dict[int, list[tuple[int, int]]] = {}
        start, end = 2**63 - 1, 0
        for cid, t_ns, pub_ns, data in messages:
            seq = self._seq[cid]
            self._seq[cid] = seq + 1
            self._stats[cid] += 1
            index.setdefault(cid, []).append((t_ns, len(body)))
            body += _rec(OP_MESSAGE, struct.pack("<HIQQ", cid, seq & 0xFFFFFFFF, t_ns, pub_ns)
                         + data)
            start, end = min(start, t_ns), max(end, t_ns)
        raw = bytes(body)
        packed = zstd.compress(raw) if self.compression else raw
        chunk = _rec(OP_CHUNK, struct.pack("<QQQI", start, end, len(raw), zlib.crc32(raw))
                     + _str(self.compression) + struct.pack("<Q", len(packed)) + packed)
        out = bytearray(chunk)
        offsets: dict[int, int] = {}
        for cid, entries in index.items():
            offsets[cid] = offset + len(out)
            pairs = b"".join(struct.pack("<QQ", t, o) for t, o in entries)
            out += _rec(OP_MESSAGE_INDEX, struct.pack("<HI", cid, len(pairs)) + pairs)
        self._chunks.append(_ChunkInfo(start, end, offset, len(chunk), offsets,
                                       len(out) - len(chunk), len(packed), len(raw)))
        self._start, self._end_t = min(self._start, start), max(self._end_t, end)
        return bytes(out)

    def _data(self, messages: Sequence[tuple[int, int, int, bytes]]) -> bytes:
        """Pending top-level records and the messages as chunks, from offset ``self._end``."""
        out = bytearray(b"".join(self._pending))
        self._pending.clear()
        i = 0
        while i < len(messages):
            j, size = i, 0
            while j < len(messages) and (size < _CHUNK_TARGET or j == i):
                size += 31 + len(messages[j][3])
                j += 1
            out += self._chunk(messages[i:j], self._end + len(out))
            i = j
        return bytes(out)

    @staticmethod
    def _tail(summary_start: int = 0, summary_offset_start: int = 0) -> bytes:
        return (_rec(OP_DATA_END, struct.pack("<I", 0))
                + _rec(OP_FOOTER, struct.pack("<QQI", summary_start, summary_offset_start, 0))
                + MAGIC)

    def _pwrite(self, blob: bytes, offset: int) -> None:
        view = memoryview(blob)
        while view:
            n = os.pwrite(self._fd, view, offset)
            view, offset = view[n:], offset + n

    def flush(self, messages: Sequence[tuple[int, int, int, bytes]]) -> None:
        if not messages and not self._pending:
            return
        data = self._data(messages)
        self._pwrite(data + self._tail(), self._end)
        self._end += len(data)

    def close(self, messages: Sequence[tuple[int, int, int, bytes]], metadata_yaml: str) -> None:
        data = bytearray(self._data(messages))
        meta_offset = self._end + len(data)
        meta = _rec(OP_METADATA, _str("rosbag2") + _strmap({"serialized_metadata": metadata_yaml}))
        data += meta
        data += _rec(OP_DATA_END, struct.pack("<I", 0))
        summary_start = self._end + len(data)
        groups: list[tuple[int, int, int]] = []
        summary = bytearray()

        def group(op: int, records: list[bytes]) -> None:
            if records:
                groups.append((op, summary_start + len(summary), sum(map(len, records))))
                summary.extend(b"".join(records))

        group(OP_SCHEMA, [rec for _, rec in self._schemas.values()])
        group(OP_CHANNEL, self._channels)
        group(OP_CHUNK_INDEX, [
            _rec(OP_CHUNK_INDEX, struct.pack("<QQQQ", c.start_ns, c.end_ns, c.offset, c.length)
                 + struct.pack("<I", 10 * len(c.index_offsets))
                 + b"".join(struct.pack("<HQ", k, v) for k, v in c.index_offsets.items())
                 + struct.pack("<Q", c.index_length) + _str(self.compression)
                 + struct.pack("<QQ", c.compressed_size, c.uncompressed_size))
            for c in self._chunks])
        count = sum(self._stats.values())
        stats = sorted(self._stats.items())
        group(OP_STATISTICS, [_rec(OP_STATISTICS, struct.pack(
            "<QHIIII", count, len(self._schemas), len(self._channels), 0, 1, len(self._chunks))
            + struct.pack("<QQ", self._start if count else 0, self._end_t)
            + struct.pack("<I", 10 * len(stats))
            + b"".join(struct.pack("<HQ", k, v) for k, v in stats))])
        group(OP_METADATA_INDEX, [_rec(OP_METADATA_INDEX, struct.pack(
            "<QQ", meta_offset, len(meta)) + _str("rosbag2"))])
        data += summary
        summary_offset_start = self._end + len(data)
        for op, start, length in groups:
            data += _rec(OP_SUMMARY_OFFSET, struct.pack("<BQQ", op, start, length))
        data += _rec(OP_FOOTER, struct.pack("<QQI", summary_start, summary_offset_start, 0))
        data += MAGIC
        self._pwrite(bytes(data), self._end)
        self._end += len(data)
        os.ftruncate(self._fd, self._end)  # nothing follows the footer
        os.close(self._fd)
        self._fd = -1

    def abort(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


class Sqlite3Storage:
    """The sqlite3 file of a bag (rosbag2 schema version 4); one transaction per flush."""

    suffix = ".db3"
    identifier = "sqlite3"
    SCHEMA = """
    CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL);
    CREATE TABLE metadata(id INTEGER PRIMARY KEY, metadata_version INTEGER NOT NULL,
                          metadata TEXT NOT NULL);
    CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
                        serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL,
                        type_description_hash TEXT NOT NULL);
    CREATE TABLE message_definitions(id INTEGER PRIMARY KEY, topic_type TEXT NOT NULL,
                                     encoding TEXT NOT NULL,
                                     encoded_message_definition TEXT NOT NULL,
                                     type_description_hash TEXT NOT NULL);
    CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
                          timestamp INTEGER NOT NULL, data BLOB NOT NULL);
    CREATE INDEX timestamp_idx ON messages (timestamp ASC);
    INSERT INTO schema(schema_version, ros_distro) VALUES (4, 'jazzy');
    """

    def __init__(self, path: Path, compression: str) -> None:
        self.path = path
        self.compress = compression == "zstd"
        self._db = sqlite3.connect(str(path), isolation_level=None)
        self._db.execute("PRAGMA journal_mode=DELETE")
        self._db.execute("PRAGMA synchronous=NORMAL")
        self._db.executescript("BEGIN;" + self.SCHEMA + "COMMIT;")
        self._types: set[str] = set()
        self._pending: list[tuple[str, tuple]] = []

    def add_connection(self, cid: int, topic: str, msgtype: str, msgdef: str,
                       qos_yaml: str, rihs01: str = "") -> None:
        if msgtype not in self._types:
            self._types.add(msgtype)
            self._pending.append((
                "INSERT INTO message_definitions (topic_type, encoding, "
                "encoded_message_definition, type_description_hash) VALUES (?, ?, ?, ?)",
                (msgtype, "ros2msg", msgdef, rihs01)))
        self._pending.append(("INSERT INTO topics VALUES (?, ?, ?, ?, ?, ?)",
                              (cid, topic, msgtype, "cdr", qos_yaml, rihs01)))

    def _write(self, messages: Sequence[tuple[int, int, int, bytes]],
               extra: Sequence[tuple[str, tuple]] = ()) -> None:
        if not messages and not self._pending and not extra:
            return
        rows = [(cid, t_ns, zstd.compress(data) if self.compress else data)
                for cid, t_ns, _, data in messages]
        self._db.execute("BEGIN")
        try:
            for sql, args in self._pending:
                self._db.execute(sql, args)
            self._db.executemany("INSERT INTO messages (topic_id, timestamp, data) "
                                 "VALUES (?, ?, ?)", rows)
            for sql, args in extra:
                self._db.execute(sql, args)
            self._db.execute("COMMIT")
        except BaseException:
            self._db.execute("ROLLBACK")
            raise
        self._pending.clear()

    def flush(self, messages: Sequence[tuple[int, int, int, bytes]]) -> None:
        self._write(messages)

    def close(self, messages: Sequence[tuple[int, int, int, bytes]], metadata_yaml: str) -> None:
        self._write(messages, [("INSERT INTO metadata (metadata_version, metadata) VALUES (?, ?)",
                                (9, metadata_yaml))])
        self._db.close()

    def abort(self) -> None:
        self._db.close()
