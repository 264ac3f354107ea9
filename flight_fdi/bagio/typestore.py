"""The rosbags type store: ROS 2 Jazzy's standard messages plus the project's own messages.

The custom messages are registered from the ``.msg`` files themselves (one source of truth, no
generated code): ``flight_fdi_msgs/msg/<Name>`` from each ``<Name>.msg``. The files are looked up
in the source tree first (``<repo>/msg_defs/msg``), then in an installed interface package
(``share/flight_fdi_msgs/msg`` under each ``AMENT_PREFIX_PATH`` prefix and under ``sys.prefix``).
"""
from __future__ import annotations

import os
import sys
from functools import lru_cache
from pathlib import Path

from .errors import BagError

PACKAGE = "flight_fdi_msgs"


def msg_search_dirs() -> list[Path]:
    """Directories searched for the project's ``.msg`` files, in order."""
    dirs = [Path(__file__).resolve().parents[2] / "msg_defs" / "msg"]
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    prefixes.append(sys.prefix)
    dirs.extend(Path(p) / "share" / PACKAGE / "msg" for p in prefixes)
    return dirs


def find_msg_dir() -> Path:
    """The first search directory that holds ``.msg`` files (BagError when there is none)."""
    searched = msg_search_dirs()
    for d in searched:
        if d.is_dir() and any(d.glob("*.msg")):
            return d
    raise BagError(f"the {PACKAGE} message definitions (*.msg) were not found; searched "
                   + ", ".join(str(d) for d in searched))


def custom_msgtypes() -> list[str]:
    """Type names of the project's messages, e.g. ``flight_fdi_msgs/msg/FilterState``."""
    return sorted(f"{PACKAGE}/msg/{p.stem}" for p in find_msg_dir().glob("*.msg"))


@lru_cache(maxsize=1)
def get_typestore():
    """rosbags' ROS 2 Jazzy type store with the ``flight_fdi_msgs`` messages registered (cached)."""
    from rosbags.typesys import Stores, get_types_from_msg
    from rosbags.typesys import get_typestore as _rosbags_typestore

    store = _rosbags_typestore(Stores.ROS2_JAZZY)
    msg_dir = find_msg_dir()
    types: dict = {}
    for path in sorted(msg_dir.glob("*.msg")):
        name = f"{PACKAGE}/msg/{path.stem}"
        try:
            types.update(get_types_from_msg(path.read_text(encoding="utf-8"), name))
        except Exception as exc:  # rosbags raises its own parser errors
            raise BagError(f"message definition {path}: cannot be parsed ({exc})") from None
    try:
        store.register(types)
    except Exception as exc:
        raise BagError(f"cannot register the {PACKAGE} messages from {msg_dir}: {exc}") from None
    return store


def msg_definition(msgtype: str) -> tuple[str, str]:
    """(ROS 2 message definition text with its dependencies, RIHS01 type hash) of ``msgtype``.

    This is what a bag stores for a connection so that other tools can decode it.
    """
    store = get_typestore()
    if msgtype not in store.fielddefs:
        raise BagError(f"unknown message type {msgtype!r}")
    text, _ = store.generate_msgdef(msgtype, ros_version=2)
    return text, store.hash_rihs01(msgtype)


def field_names(msgtype: str) -> list[str]:
    """The field names of ``msgtype`` in declaration order."""
    store = get_typestore()
    if msgtype not in store.fielddefs:
        raise BagError(f"unknown message type {msgtype!r}")
    return [name for name, _ in store.fielddefs[msgtype][1]]
