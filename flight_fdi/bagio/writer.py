"""Writing rosbag2 bags (no rclpy): the one place where bags are created.

Two ways to write, one API (``add_topic``, ``write_raw`` / ``write``, ``set_metadata``), one path
policy (:func:`prepare_path`) and one list of formats:

* :func:`open_writer` -- a whole bag at once (simulator, CLI): a context manager around rosbags'
  ``Writer`` (rosbag2 format version 9, the one ROS 2 Jazzy writes), mcap with zstd chunk
  compression by default or sqlite3 (optionally rosbag2's per-message zstd, "message" mode).
  The sample bags in ``bags/`` are its output, byte for byte.
* :class:`RecordingBag` -- a bag written while it is recorded (``recorder_node``) that survives
  a kill. rosbags' writers keep everything in memory or in an open transaction until
  ``close()``: after ``kill -9`` an mcap file has no footer and an sqlite3 bag has no committed
  messages, and neither has a ``metadata.yaml``. Here ``metadata.yaml`` is written when the bag
  is created and atomically replaced at every :meth:`RecordingBag.flush`, and the storage file
  (:mod:`.bagstore`) grows by one write (mcap) or one transaction (sqlite3) per flush, so after a
  kill at most the messages since the last flush are lost. The only unsafe window is a write
  system call interrupted half-way (microseconds per flush); a page-cache write survives the
  death of the process, so no fsync is needed against a kill.

Connections carry the full message definition and RIHS01 type hash of their type, so
``ros2 bag`` and other tools decode the bags without this package.
"""
from __future__ import annotations

import os
import shutil
import sqlite3
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np

from .bagstore import McapStorage, Sqlite3Storage
from .errors import BagError
from .typestore import get_typestore, msg_definition

STORAGES = ("mcap", "sqlite3")
COMPRESSIONS = ("none", "zstd")
QOS_PROFILES = ("default", "transient_local")


def check_format(storage: str, compression: str) -> None:
    """BagError unless ``storage`` is one of STORAGES and ``compression`` one of COMPRESSIONS."""
    if storage not in STORAGES:
        raise BagError(f"unknown storage {storage!r}; choose one of {', '.join(STORAGES)}")
    if compression not in COMPRESSIONS:
        raise BagError(f"unknown compression {compression!r}; choose one of "
                       f"{', '.join(COMPRESSIONS)}")


def prepare_path(path: str | Path, overwrite: bool, hint: str) -> Path:
    """``path`` ready for a new bag directory: an existing bag (or file) is removed when
    ``overwrite`` (BagError naming ``hint`` otherwise); a non-empty directory that is not a bag
    is never removed; the parent directory must exist."""
    path = Path(path)
    if path.exists() or path.is_symlink():
        if not overwrite:
            raise BagError(f"bag '{path}' exists already ({hint})")
        if path.is_dir() and not path.is_symlink():
            if not (path / "metadata.yaml").exists() and any(path.iterdir()):
                raise BagError(f"'{path}' is a non-empty directory that is not a bag; "
                               "not overwriting it")
            shutil.rmtree(path)
        else:
            path.unlink()
    if not path.parent.is_dir():
        raise BagError(f"cannot create bag '{path}': directory '{path.parent}' does not exist")
    return path


def _new_topic(topic: str, msgtype: str, known: str | None, verb: str) -> bool:
    """True when ``topic`` is to be added; False when it exists with ``msgtype`` already;
    BagError when it exists with another type or is not an absolute name."""
    if known is not None:
        if known != msgtype:
            raise BagError(f"topic {topic} {verb} {known}, cannot also write {msgtype}")
        return False
    if not topic.startswith("/"):
        raise BagError(f"topic {topic!r} must be an absolute name starting with '/'")
    return True


def qos_profile(name: str):
    """The offered QoS profile stored with a connection.

    ``default``: reliable, volatile, keep last 10 (what a plain publisher offers).
    ``transient_local``: reliable, transient local, keep last 1 (a latched topic such as a
    published-once model description): a player republishes it so late joiners still get it.
    """
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness,
                                    QosReliability, QosTime)

    if name not in QOS_PROFILES:
        raise BagError(f"unknown QoS profile {name!r}; choose one of {', '.join(QOS_PROFILES)}")
    infinite = QosTime(9223372036, 854775807)  # how Jazzy writes "infinite" durations
    transient = name == "transient_local"
    return Qos(
        history=QosHistory.KEEP_LAST,
        depth=1 if transient else 10,
        reliability=QosReliability.RELIABLE,
        durability=QosDurability.TRANSIENT_LOCAL if transient else QosDurability.VOLATILE,
        deadline=infinite,
        lifespan=infinite,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=infinite,
        avoid_ros_namespace_conventions=False,
    )


class BagWriter:
    """A bag open for writing. Use through ``open_writer``."""

    def __init__(self, writer: Any, path: Path) -> None:
        self._writer = writer
        self.path = path
        self._connections: dict[str, Any] = {}
        self._types: dict[str, str] = {}
        self.counts: dict[str, int] = {}

    def add_topic(self, topic: str, msgtype: str, qos: str = "default") -> None:
        """Add a connection explicitly (needed only to choose a non-default QoS profile)."""
        if not _new_topic(topic, msgtype, self._types.get(topic), "already carries"):
            return
        msgdef, rihs01 = msg_definition(msgtype)
        try:
            conn = self._writer.add_connection(topic, msgtype, msgdef=msgdef, rihs01=rihs01,
                                               offered_qos_profiles=[qos_profile(qos)])
        except Exception as exc:
            raise BagError(f"bag '{self.path}': cannot add topic {topic}: {exc}") from None
        self._connections[topic] = conn
        self._types[topic] = msgtype
        self.counts[topic] = 0

    def _conn(self, topic: str, msgtype: str):
        self.add_topic(topic, msgtype)  # (checks the type of an existing topic)
        return self._connections[topic]

    @staticmethod
    def _check_time(t_ns: int) -> int:
        t = int(t_ns)
        if t < 0:
            raise BagError(f"bag receive time must be >= 0 ns, got {t}")
        return t

    def write(self, topic: str, msgtype: str, msg: Any, t_ns: int) -> None:
        """Serialize a rosbags message object and write it with receive time ``t_ns``."""
        try:
            data = get_typestore().serialize_cdr(msg, msgtype)
        except Exception as exc:
            raise BagError(f"cannot serialize a {msgtype} for {topic}: {exc}") from None
        self.write_raw(topic, msgtype, data, t_ns)

    def write_raw(self, topic: str, msgtype: str, data: bytes | memoryview, t_ns: int) -> None:
        """Write an already serialized (CDR) message."""
        conn = self._conn(topic, msgtype)
        self._writer.write(conn, self._check_time(t_ns), data)
        self.counts[topic] += 1

    def write_series(self, series: Sequence[tuple[str, str, np.ndarray, Sequence[bytes]]]) -> None:
        """Write several serialized series interleaved in receive-time order.

        ``series``: (topic, msgtype, t_ns (N,), payloads (N)) tuples. Messages with equal times
        keep the order of ``series`` and, within a series, their given order.
        """
        conns, times, payloads = [], [], []
        for topic, msgtype, t_ns, data in series:
            t_ns = np.asarray(t_ns, dtype=np.int64).reshape(-1)
            if t_ns.size != len(data):
                raise BagError(f"write_series {topic}: {t_ns.size} times for {len(data)} messages")
            if t_ns.size and t_ns.min() < 0:
                raise BagError(f"write_series {topic}: bag receive times must be >= 0 ns")
            conns.append(self._conn(topic, msgtype))
            times.append(t_ns)
            payloads.append(data)
        if not conns:
            return
        which = np.concatenate([np.full(t.size, k, dtype=np.int64) for k, t in enumerate(times)])
        index = np.concatenate([np.arange(t.size) for t in times])
        t_all = np.concatenate(times)
        order = np.lexsort((index, which, t_all))
        write = self._writer.write
        for k, i, t in zip(which[order].tolist(), index[order].tolist(), t_all[order].tolist()):
            write(conns[k], t, payloads[k][i])
        for (topic, _, t_ns, _), _c in zip(series, conns):
            self.counts[topic] += len(t_ns)

    def set_metadata(self, key: str, value: str) -> None:
        """A key/value pair in the bag's ``custom_data`` (metadata.yaml)."""
        self._writer.set_custom_data(str(key), str(value))


@contextmanager
def open_writer(path: str | Path, storage: str = "mcap", compression: str = "zstd",
                overwrite: bool = False) -> Iterator[BagWriter]:
    """Open a new rosbag2 bag directory for writing.

    ``storage``: ``mcap`` (default, with zstd chunk compression unless ``compression='none'``) or
    ``sqlite3`` (``compression='zstd'`` then compresses each message, rosbag2's "message" mode).
    An existing path is an error unless ``overwrite``. When the body raises, the partial bag is
    removed.
    """
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin

    check_format(storage, compression)
    path = prepare_path(path, overwrite, "use --force to overwrite")
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    writer = Writer(path, version=9, storage_plugin=plugin)
    if compression == "zstd":
        mode = CompressionMode.STORAGE if storage == "mcap" else CompressionMode.MESSAGE
        writer.set_compression(mode, CompressionFormat.ZSTD)
    try:
        writer.open()
    except Exception as exc:
        raise BagError(f"cannot create bag '{path}': {exc}") from None
    bag = BagWriter(writer, path)
    try:
        yield bag
    except BaseException:
        try:
            writer.abort()
        finally:
            shutil.rmtree(path, ignore_errors=True)
        raise
    try:
        writer.close()
    except Exception as exc:
        shutil.rmtree(path, ignore_errors=True)
        raise BagError(f"cannot finish bag '{path}': {exc}") from None


# --------------------------------------------------------------------------- incremental writing

#: rosbag2's spelling of an infinite duration
_INFINITE = {"sec": 9223372036, "nsec": 854775807}


def qos_dict(history: str = "keep_last", depth: int = 10, reliability: str = "reliable",
             durability: str = "volatile", deadline_ns: int | None = None,
             lifespan_ns: int | None = None, liveliness: str = "automatic",
             lease_ns: int | None = None, avoid_ros_namespace_conventions: bool = False) -> dict:
    """One offered QoS profile as rosbag2 (format version 9) writes it in metadata.yaml."""
    def dur(ns: int | None) -> dict:
        if ns is None or ns >= 2**63 - 1 or ns <= 0:
            return dict(_INFINITE)
        return {"sec": int(ns // 1_000_000_000), "nsec": int(ns % 1_000_000_000)}

    return {"history": history, "depth": int(depth), "reliability": reliability,
            "durability": durability, "deadline": dur(deadline_ns), "lifespan": dur(lifespan_ns),
            "liveliness": liveliness, "liveliness_lease_duration": dur(lease_ns),
            "avoid_ros_namespace_conventions": bool(avoid_ros_namespace_conventions)}


def _yaml_dump(data: Any) -> str:
    import yaml

    dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)  # libyaml: ~20x faster
    return yaml.dump(data, Dumper=dumper, default_flow_style=False, sort_keys=False)



# --------------------------------------------------------------------------- the bag


@dataclass
class _Topic:
    cid: int
    name: str
    msgtype: str
    rihs01: str
    qos: list[dict]
    count: int = 0      # messages received (buffered or written)
    written: int = 0    # messages on disk


class RecordingBag:
    """A rosbag2 bag written incrementally: readable after every :meth:`flush`, complete after
    :meth:`close` (see the module docstring). Not thread-safe; no rclpy.

    ``add_topic(name, msgtype, offered_qos)``, ``write(name, t_ns, data)`` (buffered),
    ``flush()`` (periodically), ``close()``. Errors are :class:`BagError`.
    """

    def __init__(self, path: str | Path, storage: str = "mcap", compression: str = "none",
                 overwrite: bool = False) -> None:
        check_format(storage, compression)
        self.path = prepare_path(path, overwrite, "set overwrite to replace it")
        self.storage = storage
        self.compression = compression
        cls = McapStorage if storage == "mcap" else Sqlite3Storage
        self.file = self.path / f"{self.path.name}_0{cls.suffix}"
        try:
            self.path.mkdir()
            self._store: Any = cls(self.file, compression)
        except (OSError, sqlite3.Error) as exc:
            raise BagError(f"cannot create bag '{self.path}': {exc}") from None
        self.topics: dict[str, _Topic] = {}
        self._by_cid: dict[int, _Topic] = {}
        self._buffer: list[tuple[int, int, int, bytes]] = []
        self._last_t = 0
        self._t_range: tuple[int, int] | None = None  # receive times on disk
        self.clamped = 0     # receive times raised to keep them in order
        self.flushes = 0
        self.closed = False
        self.custom_data: dict[str, str] = {"recorder": "flight_fdi recorder_node",
                                            "closed_cleanly": "false"}
        self._write_metadata()

    # -- topics and messages
    def add_topic(self, name: str, msgtype: str, offered_qos: Sequence[dict] = ()) -> None:
        """Add a connection; its message definition comes from the project's type store."""
        if self.closed:
            raise BagError(f"bag '{self.path}' is closed")
        known = self.topics[name].msgtype if name in self.topics else None
        if not _new_topic(name, msgtype, known, "is recorded as"):
            return
        msgdef, rihs01 = msg_definition(msgtype)
        qos = [dict(q) for q in offered_qos]
        topic = _Topic(len(self.topics) + 1, name, msgtype, rihs01, qos)
        qos_yaml = _yaml_dump(qos).strip() if qos else ""
        if self.storage == "mcap":
            self._store.add_connection(topic.cid, name, msgtype, msgdef, qos_yaml)
        else:
            self._store.add_connection(topic.cid, name, msgtype, msgdef, qos_yaml, rihs01)
        self.topics[name] = topic
        self._by_cid[topic.cid] = topic

    def write(self, name: str, t_ns: int, data: bytes, publish_ns: int | None = None) -> None:
        """Buffer one serialized message received at ``t_ns`` (on disk after the next flush)."""
        if self.closed:
            raise BagError(f"bag '{self.path}' is closed")
        topic = self.topics.get(name)
        if topic is None:
            raise BagError(f"topic {name} was not added to bag '{self.path}'")
        t = int(t_ns)
        if t < self._last_t:
            t = self._last_t
            self.clamped += 1
        self._last_t = t
        self._buffer.append((topic.cid, t, t if publish_ns is None else int(publish_ns),
                             bytes(data)))
        topic.count += 1

    @property
    def message_count(self) -> int:
        """Messages received (buffered or on disk)."""
        return sum(t.count for t in self.topics.values())

    @property
    def pending(self) -> int:
        """Messages buffered since the last flush."""
        return len(self._buffer)

    def _account(self, messages: Sequence[tuple[int, int, int, bytes]]) -> None:
        for cid, t, _, _ in messages:
            self._by_cid[cid].written += 1
        if messages:
            lo, hi = messages[0][1], messages[-1][1]  # times are kept in order
            self._t_range = (lo, hi) if self._t_range is None else (self._t_range[0], hi)

    def flush(self) -> None:
        """Write the buffered messages; the bag on disk is then readable and holds all of them."""
        if self.closed:
            return
        messages, self._buffer = self._buffer, []
        try:
            self._store.flush(messages)
        except (OSError, sqlite3.Error) as exc:
            raise BagError(f"bag '{self.path}': writing failed: {exc}") from None
        self._account(messages)
        self._write_metadata()
        self.flushes += 1

    def close(self) -> None:
        """Flush and complete the bag (mcap summary, sqlite3 metadata). Idempotent."""
        if self.closed:
            return
        self.closed = True
        messages, self._buffer = self._buffer, []
        self._account(messages)
        self.custom_data["closed_cleanly"] = "true"
        info = self._metadata()["rosbag2_bagfile_information"]
        try:
            self._store.close(messages, _yaml_dump(info))
        except (OSError, sqlite3.Error) as exc:
            self._store.abort()
            raise BagError(f"bag '{self.path}': closing failed: {exc}") from None
        self._write_metadata()

    # -- metadata.yaml
    def _metadata(self) -> dict:
        total = sum(t.written for t in self.topics.values())
        start, end = self._t_range or (0, 0)
        zstd_msg = self.compression == "zstd" and self.storage == "sqlite3"
        info = {
            "version": 9,
            "storage_identifier": self._store.identifier,
            "duration": {"nanoseconds": end - start},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": total,
            "topics_with_message_count": [
                {"topic_metadata": {"name": t.name, "type": t.msgtype,
                                    "serialization_format": "cdr",
                                    "offered_qos_profiles": t.qos,
                                    "type_description_hash": t.rihs01},
                 "message_count": t.written} for t in self.topics.values()],
            "compression_format": "zstd" if zstd_msg else "",
            "compression_mode": "MESSAGE" if zstd_msg else "",
            "relative_file_paths": [self.file.name],
            "files": [{"path": self.file.name,
                       "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": end - start}, "message_count": total}],
            "custom_data": dict(self.custom_data),
            "ros_distro": "jazzy",
        }
        return {"rosbag2_bagfile_information": info}

    def _write_metadata(self) -> None:
        tmp = self.path / ".metadata.yaml.tmp"
        try:
            tmp.write_text(_yaml_dump(self._metadata()), encoding="utf-8")
            os.replace(tmp, self.path / "metadata.yaml")
        except OSError as exc:
            raise BagError(f"bag '{self.path}': cannot write metadata.yaml: {exc}") from None
