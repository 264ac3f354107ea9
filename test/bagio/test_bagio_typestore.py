"""The type store knows the project's messages, exactly as the .msg files and the issue define them,
and every field survives a bag write/read through rosbags."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from flight_fdi.bagio import BagError, get_typestore, msg_definition, open_writer, read_messages
from flight_fdi.bagio import typestore as ts_mod
from msg_contract import REQUIRED_FIELDS, msg_file_fields

REPO = Path(__file__).resolve().parents[2]
NAMES = ("Innovation", "FilterState", "ModelInfo", "FaultLocalization", "SmoothedState",
         "VoteStatus")
DTYPES = {"float64": "f8", "float32": "f4", "int8": "i1", "int16": "i2", "int32": "i4",
          "int64": "i8", "uint8": "u1", "byte": "u1", "char": "u1", "uint16": "u2",
          "uint32": "u4", "uint64": "u8", "bool": "bool"}


def _base_values(typ: str, count: int, k: int, name: str) -> list:
    if typ == "string":
        return [f"{name}_{k}_{i}" + "x" * i for i in range(count)]
    if typ == "bool":
        return [i % 2 == 0 for i in range(count)]  # a lone bool is True (not the default)
    if typ.startswith("float"):
        return [1.25 + k + 0.5 * i for i in range(count)]
    return [(3 + k + i) % 100 + 1 for i in range(count)]


def _value(store, field: tuple, k: int, name: str):
    from rosbags.interfaces import Nodetype

    kind, arg = field
    if kind == Nodetype.BASE:
        return _base_values(arg[0], 1, k, name)[0]
    if kind == Nodetype.NAME:
        return fill(store, arg, k + 1)
    (sub_kind, sub_arg), size = arg
    count = size if kind == Nodetype.ARRAY else 3
    if sub_kind == Nodetype.BASE:
        vals = _base_values(sub_arg[0], count, k, name)
        return vals if sub_arg[0] == "string" else np.array(vals, dtype=DTYPES[sub_arg[0]])
    return [fill(store, sub_arg, k + i) for i in range(count)]


def fill(store, typename: str, k: int = 0):
    """An instance with every field set to a non-default value."""
    cls = store.types[typename]
    _, fields = store.fielddefs[typename]
    return cls(**{name: _value(store, f, k, name) for name, f in fields})


def _names(msg) -> list[str]:
    """Field names (not constants) from the type store's definition."""
    return [name for name, _ in get_typestore().fielddefs[msg.__msgtype__][1]]


def same(a, b) -> bool:
    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b)
    if isinstance(a, list):
        return isinstance(b, list) and len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    if hasattr(a, "__dataclass_fields__"):
        return type(a).__name__ == type(b).__name__ and all(
            same(getattr(a, f), getattr(b, f)) for f in _names(a))
    return type(a) is type(b) and a == b


def test_all_custom_messages_registered_from_msg_files():
    store = get_typestore()
    assert sorted(ts_mod.custom_msgtypes()) == sorted(f"flight_fdi_msgs/msg/{n}" for n in NAMES)
    for name in NAMES:
        fields = ts_mod.field_names(f"flight_fdi_msgs/msg/{name}")
        # the .msg file is the one source of truth ...
        assert fields == msg_file_fields(REPO / "msg_defs" / "msg" / f"{name}.msg")
        # ... and it carries the content the issue requires
        missing = [f for f in REQUIRED_FIELDS[name] if f not in fields]
        assert not missing, f"{name} lacks {missing}"
        assert f"flight_fdi_msgs/msg/{name}" in store.types


def test_required_field_list_is_the_issue_list():
    # spelled out here as well, so that an edit of msg_contract alone cannot weaken the check
    assert REQUIRED_FIELDS["FilterState"] == ["header", "channel", "state_names", "x", "p", "z",
                                              "r", "h", "dt", "fused", "gated"]
    assert REQUIRED_FIELDS["VoteStatus"] == ["epsilon", "epsilon_sum", "isolated_imu",
                                             "selected_imu"]
    assert "glr_hypothesis" in REQUIRED_FIELDS["FaultLocalization"]
    assert "row_excluded" in REQUIRED_FIELDS["Innovation"]
    assert "delta_d" in REQUIRED_FIELDS["SmoothedState"]
    assert "qc" in REQUIRED_FIELDS["ModelInfo"]


def test_constants_are_registered():
    store = get_typestore()
    assert store.types["flight_fdi_msgs/msg/Innovation"].ALARM_RAISED == 1
    assert store.types["flight_fdi_msgs/msg/FaultLocalization"].VERDICT_FAILURE == 2
    assert store.types["flight_fdi_msgs/msg/VoteStatus"].MULTIPLE_FAULT == 3


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_every_field_round_trips_through_a_bag(tmp_path, storage):
    store = get_typestore()
    sent = {}
    with open_writer(tmp_path / "bag", storage=storage) as bag:
        for i, name in enumerate(NAMES):
            msgtype = f"flight_fdi_msgs/msg/{name}"
            msg = fill(store, msgtype, k=i)
            sent[f"/{name.lower()}"] = msg
            bag.write(f"/{name.lower()}", msgtype, msg, 1_000 + i)
    got = {topic: (mt, t, msg) for topic, mt, t, msg in read_messages(tmp_path / "bag")}
    assert set(got) == set(sent)
    for i, name in enumerate(NAMES):
        topic = f"/{name.lower()}"
        mt, t, msg = got[topic]
        assert mt == f"flight_fdi_msgs/msg/{name}" and t == 1_000 + i
        assert same(sent[topic], msg), name
        assert_no_defaults(msg, name)


def assert_no_defaults(msg, path: str) -> None:
    """Every leaf differs from its default (0, "", False, empty), so each field is exercised."""
    for f in _names(msg):
        val = getattr(msg, f)
        where = f"{path}.{f}"
        if hasattr(val, "__dataclass_fields__"):
            assert_no_defaults(val, where)
        elif isinstance(val, (list, np.ndarray)):
            assert len(val) > 0, where
        else:
            assert val not in (0, "", False), where


def test_bag_stores_the_definitions(tmp_path):
    store = get_typestore()
    with open_writer(tmp_path / "bag") as bag:
        bag.write("/s", "flight_fdi_msgs/msg/SmoothedState",
                  fill(store, "flight_fdi_msgs/msg/SmoothedState"), 5)
    from rosbags.rosbag2 import Reader

    with Reader(tmp_path / "bag") as reader:
        (conn,) = reader.connections
        text, rihs = msg_definition("flight_fdi_msgs/msg/SmoothedState")
        assert conn.msgdef.data == text and "float64[] v_tilde" in text
        assert conn.digest == rihs and rihs.startswith("RIHS01_")


def test_unknown_type_is_a_bag_error():
    with pytest.raises(BagError, match="unknown message type"):
        msg_definition("flight_fdi_msgs/msg/Nope")


def test_msg_dir_missing_is_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setattr(ts_mod, "msg_search_dirs", lambda: [tmp_path / "none"])
    with pytest.raises(BagError, match="message definitions .* not found"):
        ts_mod.find_msg_dir()


def test_installed_share_dir_is_found(monkeypatch, tmp_path):
    share = tmp_path / "share" / "flight_fdi_msgs" / "msg"
    share.mkdir(parents=True)
    (share / "FilterState.msg").write_text("float64 x\n")
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path))
    dirs = ts_mod.msg_search_dirs()
    assert share in dirs and dirs.index(share) > 0  # after the source tree
