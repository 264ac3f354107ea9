"""Writing rosbag2 bags with rosbags (no rclpy).

``open_writer`` is a context manager around rosbags' ``Writer`` (rosbag2 format version 9, the
one ROS 2 Jazzy writes). Connections are added on first use with the full message definition and
RIHS01 type hash of the type, so ``ros2 bag`` and other tools decode the bag without our code.

Storage: ``mcap`` (Jazzy's default) with zstd chunk compression by default, or ``sqlite3``
(optionally with per-message zstd compression, rosbag2's "message" mode).
"""
from __future__ import annotations

import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np

from .errors import BagError
from .typestore import get_typestore, msg_definition

STORAGES = ("mcap", "sqlite3")
COMPRESSIONS = ("none", "zstd")
QOS_PROFILES = ("default", "transient_local")


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
        if topic in self._connections:
            if self._types[topic] != msgtype:
                raise BagError(f"topic {topic} already carries {self._types[topic]}, "
                               f"cannot also write {msgtype}")
            return
        if not topic.startswith("/"):
            raise BagError(f"topic {topic!r} must be an absolute name starting with '/'")
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
        if topic not in self._connections:
            self.add_topic(topic, msgtype)
        elif self._types[topic] != msgtype:
            raise BagError(f"topic {topic} already carries {self._types[topic]}, "
                           f"cannot also write {msgtype}")
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

    if storage not in STORAGES:
        raise BagError(f"unknown storage {storage!r}; choose one of {', '.join(STORAGES)}")
    if compression not in COMPRESSIONS:
        raise BagError(f"unknown compression {compression!r}; choose one of "
                       f"{', '.join(COMPRESSIONS)}")
    path = Path(path)
    if path.exists() or path.is_symlink():
        if not overwrite:
            raise BagError(f"bag '{path}' exists already (use --force to overwrite)")
        if path.is_dir() and not path.is_symlink():
            if not (path / "metadata.yaml").exists() and any(path.iterdir()):
                raise BagError(f"'{path}' is a non-empty directory that is not a bag; "
                               "not overwriting it")
            shutil.rmtree(path)
        else:
            path.unlink()
    if not path.parent.is_dir():
        raise BagError(f"cannot write bag '{path}': directory '{path.parent}' does not exist")
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
