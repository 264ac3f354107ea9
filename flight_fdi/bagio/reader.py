"""The one bag reader (rosbag2 directories, .mcap or .db3 files; rosbags, no rclpy).

Every reading of a bag goes through here:

* :func:`open_bag` / :func:`bag_topics` -- open a bag (BagError, one line, for a missing, foreign
  or corrupt one) and list its topics;
* :func:`read_raw` / :func:`read_topics_raw` -- the raw (CDR) messages of chosen topics as
  arrays (:class:`RawSeries`: receive times and :class:`~flight_fdi.bagio.cdr.Payloads`), for the
  vectorised decoders (``read_flight``, the IMU reader). Back-ends: :mod:`.mcapscan` (whole MCAP
  chunks with numpy; :func:`scan_mcap`) where the bag allows it, rosbags' message iterator
  otherwise (:func:`read_raw_generic`); both give the same messages in the same order;
* :func:`read_messages` -- decoded messages of any type, in receive-time order;
* :class:`BagStream` -- raw messages one at a time in receive-time order, with the recorded
  QoS (the bag player).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

import numpy as np

from . import cdr
from .errors import BagError
from .typestore import get_typestore

# --------------------------------------------------------------------------- opening a bag


def open_bag(path: str | Path):
    """An open rosbags Reader of the bag at ``path`` (close it); BagError when it cannot be."""
    from rosbags.rosbag2 import Reader

    p = Path(path)
    if not p.exists():
        raise BagError(f"bag '{p}' does not exist")
    if p.is_dir() and not (p / "metadata.yaml").exists():
        raise BagError(f"bag '{p}': not a rosbag2 bag (no metadata.yaml in the directory)")
    if p.is_file() and p.suffix not in (".mcap", ".db3"):
        raise BagError(f"bag '{p}': not a rosbag2 bag (expected a bag directory, .mcap or .db3)")
    try:
        reader = Reader(p)
        reader.open()
    except BagError:
        raise
    except Exception as exc:
        raise BagError(f"bag '{p}' cannot be opened: {reason(exc)}") from None
    return reader


def reason(exc: BaseException) -> str:
    """The first line of an exception's message (its type name when it has none)."""
    text = str(exc).strip().rstrip(".") or type(exc).__name__
    return text.splitlines()[0]


def bag_topics(path: str | Path) -> dict[str, str]:
    """{topic: message type} of a bag."""
    reader = open_bag(path)
    try:
        return {c.topic: c.msgtype for c in reader.connections}
    finally:
        reader.close()


def topic_list(topics: dict[str, str]) -> str:
    """The topic names for an error message ("none" when there are none)."""
    return ", ".join(sorted(topics)) or "none"


# --------------------------------------------------------------------------- raw messages

@dataclass
class RawSeries:
    """Raw messages of one topic in receive-time order."""

    log_ns: np.ndarray
    payloads: cdr.Payloads


def read_raw(reader: Any, path: Path, topics: set[str]) -> dict[str, RawSeries]:
    """Raw messages of ``topics`` (which must exist) of the bag open in ``reader`` (from
    :func:`open_bag`), in receive-time order: MCAP scanned with numpy where possible."""
    files: list[Path] | None = None
    try:  # which mcap files back the bag (rosbags internals; any surprise: generic path)
        from rosbags.rosbag2.reader import DirectoryReader
        from rosbags.rosbag2.storage_mcap import McapReader

        storage = reader.storage
        if isinstance(storage, DirectoryReader):
            if not storage.metadata.compression_mode and all(
                    isinstance(s, McapReader) for s in storage.storages):
                files = [Path(s.path) for s in storage.storages]
        elif isinstance(storage, McapReader):
            files = [Path(storage.path)]
    except (ImportError, AttributeError):
        files = None
    if files:
        out = scan_mcap(files, topics, path)
        if out is not None:
            return out
    return read_raw_generic(reader, path, topics)


def scan_mcap(files: list[Path], topics: set[str], path: str | Path
              ) -> dict[str, RawSeries] | None:
    """Raw messages of ``topics`` from the MCAP files of one bag (``path`` names it in errors)
    with :mod:`.mcapscan`, merged in receive-time order; None when a file uses a feature the
    scanner does not handle (use :func:`read_raw_generic`)."""
    from . import mcapscan

    try:
        parts = [mcapscan.scan(str(f), set(topics), str(path)) for f in files]
    except mcapscan.Unsupported:
        return None
    return _merge_files(parts, set(topics))


def _merge_files(parts: list[dict], topics: set[str]) -> dict[str, RawSeries]:
    if len(parts) == 1:
        return {t: RawSeries(m.log_ns, m.payloads) for t, m in parts[0].items()}
    out: dict[str, RawSeries] = {}
    for t in topics:
        bufs, starts, lens, logs, base = [], [], [], [], 0
        for k, part in enumerate(parts):
            m = part[t]
            bufs.append(m.payloads.buf)
            starts.append(m.payloads.starts + base)
            lens.append(m.payloads.lengths)
            logs.append(m.log_ns)
            base += m.payloads.buf.size
        log = np.concatenate(logs)
        order = np.argsort(log, kind="stable")
        out[t] = RawSeries(log[order], cdr.Payloads(np.concatenate(bufs),
                                                    np.concatenate(starts)[order],
                                                    np.concatenate(lens)[order]))
    return out


def read_raw_generic(reader: Any, path: Path, topics: set[str]) -> dict[str, RawSeries]:
    """As :func:`read_raw`, through rosbags' message iterator (any storage, compression)."""
    conns = [c for c in reader.connections if c.topic in topics]
    logs: dict[str, list[int]] = {t: [] for t in topics}
    datas: dict[str, list[bytes]] = {t: [] for t in topics}
    try:
        for conn, t_ns, data in reader.messages(connections=conns):
            logs[conn.topic].append(t_ns)
            datas[conn.topic].append(data)
        # (a damaged sqlite3 record can hold a receive time or data of the wrong type)
        return {t: RawSeries(np.array(logs[t], dtype=np.int64), cdr.Payloads.from_list(datas[t]))
                for t in topics}
    except BagError:
        raise
    except Exception as exc:
        raise BagError(f"bag '{path}' is corrupt: {reason(exc)}") from None


def read_topics_raw(path: str | Path, topics: Iterable[str],
                    check: Callable[[dict[str, str]], None] | None = None
                    ) -> dict[str, RawSeries]:
    """Raw messages of ``topics`` of the bag at ``path`` (see :func:`read_raw`). ``check``
    receives {topic: message type} of the bag before anything is read (raise BagError there to
    refuse it); by default every topic must exist. An mcap bag directory without rosbag2
    compression is read without rosbags' Reader (whose YAML parsing of metadata.yaml alone takes
    ~0.3 s)."""
    p = Path(path)
    topics = list(topics)
    check = check or (lambda available: require_topics(p, available, topics))
    listed = _mcap_files(p)
    if listed is not None:
        files, available = listed
        check(available)
        out = scan_mcap(files, set(topics), p)
        if out is not None:
            return out
    reader = open_bag(p)
    try:
        check({c.topic: c.msgtype for c in reader.connections})
        return read_raw(reader, p, set(topics))
    finally:
        reader.close()


def require_topics(path: Path, available: dict[str, str], topics: list[str]) -> None:
    """BagError naming the bag's topics unless every one of ``topics`` is ``available``."""
    missing = [t for t in topics if t not in available]
    if missing:
        raise BagError(f"bag '{path}': no topic {', '.join(missing)} "
                       f"(topics: {topic_list(available)})")


def _mcap_files(p: Path) -> tuple[list[Path], dict[str, str]] | None:
    """(mcap files, {topic: type}) of an mcap bag directory without rosbag2 compression, read
    from its metadata.yaml; None: use rosbags' Reader."""
    import yaml

    meta = p / "metadata.yaml"
    if not (p.is_dir() and meta.is_file()):
        return None
    try:
        info = yaml.load(meta.read_text(), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
        info = info["rosbag2_bagfile_information"]
        if info.get("storage_identifier") != "mcap" or info.get("compression_mode"):
            return None
        files = [p / f for f in info["relative_file_paths"]]
        available = {x["topic_metadata"]["name"]: x["topic_metadata"]["type"]
                     for x in info["topics_with_message_count"]}
    except (yaml.YAMLError, KeyError, TypeError, OSError, UnicodeDecodeError):
        return None
    if not files or not all(f.is_file() for f in files):
        return None
    return files, available


# --------------------------------------------------------------------------- generic iteration

def read_messages(path: str | Path, topics: Iterable[str] | None = None
                  ) -> Iterator[tuple[str, str, int, Any]]:
    """Yield (topic, msgtype, receive time ns, decoded message) in receive-time order.

    The project's messages (flight_fdi_msgs) and ROS 2 Jazzy's standard messages are known;
    other types are registered from the definitions stored in the bag.
    """
    p = Path(path)
    reader = open_bag(p)
    try:
        available = {c.topic: c.msgtype for c in reader.connections}
        if topics is None:
            conns = list(reader.connections)
        else:
            wanted = list(topics)
            missing = [t for t in wanted if t not in available]
            if missing:
                raise BagError(f"bag '{p}': no topic {', '.join(missing)} "
                               f"(topics: {topic_list(available)})")
            conns = [c for c in reader.connections if c.topic in wanted]
        store = get_typestore()
        _register_bag_types(store, conns, p)
        try:
            it = reader.messages(connections=conns)
            for conn, t_ns, data in it:
                if not isinstance(t_ns, int):  # a damaged sqlite3 record
                    raise BagError(f"bag '{p}' is corrupt: a message on {conn.topic} has the "
                                   f"receive time {t_ns!r}, not an integer")
                try:
                    msg = store.deserialize_cdr(data, conn.msgtype)
                except Exception as exc:
                    raise BagError(f"bag '{p}': a {conn.msgtype} message on {conn.topic} cannot "
                                   f"be decoded: {reason(exc)}") from None
                yield conn.topic, conn.msgtype, t_ns, msg
        except BagError:
            raise
        except Exception as exc:
            raise BagError(f"bag '{p}' is corrupt: {reason(exc)}") from None
    finally:
        reader.close()


def _register_bag_types(store: Any, conns: list, path: Path) -> None:
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.typesys import get_types_from_idl, get_types_from_msg

    for conn in conns:
        if conn.msgtype in store.fielddefs:
            continue
        fmt, text = conn.msgdef.format, conn.msgdef.data
        try:
            if fmt == MessageDefinitionFormat.MSG:
                types = get_types_from_msg(text, conn.msgtype)
            elif fmt == MessageDefinitionFormat.IDL:
                types = get_types_from_idl(text)
            else:
                raise BagError(f"bag '{path}': {conn.topic} has the unknown type {conn.msgtype} "
                               "and the bag stores no definition for it")
            store.register({k: v for k, v in types.items() if k not in store.fielddefs})
        except BagError:
            raise
        except Exception as exc:
            raise BagError(f"bag '{path}': the definition of {conn.msgtype} stored in the bag "
                           f"cannot be used: {reason(exc)}") from None


# --------------------------------------------------------------------------- streaming

class BagStream:
    """The messages of ``topics`` of a bag, in receive-time order, as raw CDR (no rclpy).

    ``BagStream(path, topics)``: ``types`` {topic: msgtype}, ``latched`` (topics whose recorded
    publishers were all transient local), ``count`` (from the bag's metadata) and
    ``messages()`` yielding (topic, t_ns, bytes). BagError for a missing or unreadable bag or
    unknown topics.
    """

    def __init__(self, path: str | Path, topics: list[str]) -> None:
        from rosbags.interfaces import QosDurability

        self.path = Path(path)
        self._reader = open_bag(self.path)
        conns = self._reader.connections
        available = {c.topic: c.msgtype for c in conns}
        missing = [t for t in topics if t not in available]
        if missing:
            self.close()
            raise BagError(f"bag '{self.path}' has no topic {', '.join(missing)} (topics: "
                           f"{topic_list(available)})")
        self._conns = [c for c in conns if c.topic in topics]
        self.types = {t: available[t] for t in topics}
        self.latched: set[str] = set()
        for t in topics:
            offered = [q for c in self._conns if c.topic == t
                       for q in (getattr(c.ext, "offered_qos_profiles", None) or [])]
            if offered and all(q.durability == QosDurability.TRANSIENT_LOCAL for q in offered):
                self.latched.add(t)
        self.count = sum(c.msgcount for c in self._conns)

    def messages(self) -> Iterator[tuple[str, int, bytes]]:
        try:
            for conn, t_ns, data in self._reader.messages(connections=self._conns):
                yield conn.topic, t_ns, bytes(data)
        except BagError:
            raise
        except Exception as exc:
            raise BagError(f"bag '{self.path}' is corrupt: {reason(exc)}") from None

    def close(self) -> None:
        try:
            self._reader.close()
        except Exception:
            pass
