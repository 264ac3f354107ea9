"""The one writer module (open_writer, RecordingBag) and the one reader (read_topics_raw,
read_raw / read_raw_generic, read_messages, BagStream): round trips in mcap and sqlite3, and
clear errors for damaged bags. Expected values are the messages that were written."""
from __future__ import annotations

import sqlite3

import numpy as np
import pytest

from flight_fdi.bagio import BagError, cdr, get_typestore, open_writer, read_messages
from flight_fdi.bagio.reader import (BagStream, open_bag, read_raw, read_raw_generic,
                                     read_topics_raw)
from flight_fdi.bagio.writer import RecordingBag, qos_dict

NS = 10**9
T0 = 1_700_000_000 * NS
TWIST = cdr.TWIST_STAMPED
STATE = cdr.FILTER_STATE
STRING = cdr.STRING


def _series(n=40, seed=0):
    """INS twists (every 20 ms) and FilterStates (every 100 ms) with known contents."""
    rng = np.random.default_rng(seed)
    t_ins = T0 + np.arange(n) * 20_000_000
    twist = rng.normal(size=(n, 6))
    ins = cdr.encode(TWIST, t_ins, "ins", twist)
    from flight_fdi.bagio.cdr import message

    t_st = T0 + np.arange(n // 5) * 100_000_000
    states = [message.encode_filter_state(int(t // NS), int(t % NS), "enu", "x", ["a", "b"],
                                          rng.normal(size=2).tolist(), rng.normal(size=4).tolist(),
                                          [0.5], [0.01], [1.0, 0.0], [], 0.1, True, False, False)
              for t in t_st]
    note = bytes(get_typestore().serialize_cdr(get_typestore().types[STRING](data="hello"),
                                               STRING))
    return (t_ins, ins), (t_st, states), note


def _write(path, storage, how, compression="none"):
    (t_ins, ins), (t_st, states), note = _series()
    if how == "open_writer":
        with open_writer(path, storage=storage, compression=compression) as bag:
            bag.add_topic("/note", STRING, qos="transient_local")
            bag.write_raw("/note", STRING, note, T0 - 1)
            bag.write_series([("/ins", TWIST, t_ins, ins), ("/state", STATE, t_st, states)])
    else:
        bag = RecordingBag(path, storage, compression)
        bag.add_topic("/note", STRING, [qos_dict(depth=1, durability="transient_local")])
        bag.add_topic("/ins", TWIST, [qos_dict()])
        bag.add_topic("/state", STATE, [qos_dict()])
        bag.write("/note", T0 - 1, note)
        merged = sorted([(t, "/ins", d) for t, d in zip(t_ins.tolist(), ins)]
                        + [(t, "/state", d) for t, d in zip(t_st.tolist(), states)],
                        key=lambda e: (e[0], e[1] != "/ins"))
        for k, (t, topic, data) in enumerate(merged):
            bag.write(topic, t, data)
            if k % 17 == 0:
                bag.flush()  # several chunks / transactions
        bag.close()
    return {"/ins": (t_ins, ins), "/state": (t_st, states), "/note": (np.array([T0 - 1]), [note])}


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
@pytest.mark.parametrize("how,compression", [("open_writer", "none"), ("open_writer", "zstd"),
                                             ("RecordingBag", "none"), ("RecordingBag", "zstd")])
def test_writers_round_trip_through_the_reader(tmp_path, storage, how, compression):
    bag = tmp_path / "bag"
    written = _write(bag, storage, how, compression)
    topics = ["/ins", "/state", "/note"]
    raw = read_topics_raw(bag, topics)
    reader = open_bag(bag)
    try:
        fast = read_raw(reader, bag, set(topics))
        generic = read_raw_generic(reader, bag, set(topics))
    finally:
        reader.close()
    for got in (raw, fast, generic):
        for t in topics:
            times, payloads = written[t]
            np.testing.assert_array_equal(got[t].log_ns, times)
            assert [got[t].payloads[i] for i in range(len(payloads))] == list(payloads)
    # decoded messages, in receive-time order across topics
    decoded = list(read_messages(bag, topics=["/ins", "/state"]))
    assert [m[2] for m in decoded] == sorted(m[2] for m in decoded)
    states = [m[3] for m in decoded if m[0] == "/state"]
    records = cdr.decode_filter_states(written["/state"][1])
    assert len(states) == len(records) == 8
    for m, r in zip(states, records):
        assert m.header.stamp.sec * NS + m.header.stamp.nanosec == r.stamp_ns
        np.testing.assert_array_equal(m.x, r.x)
        np.testing.assert_array_equal(m.p, r.p)
    # the player's stream: raw bytes in time order, the latched topic recognised
    stream = BagStream(bag, topics)
    try:
        assert stream.types == {"/ins": TWIST, "/state": STATE, "/note": STRING}
        assert stream.latched == {"/note"} and stream.count == 40 + 8 + 1
        played = list(stream.messages())
    finally:
        stream.close()
    assert played[0] == ("/note", T0 - 1, written["/note"][1][0])
    assert [p[1] for p in played] == sorted(p[1] for p in played)
    assert [p[2] for p in played if p[0] == "/ins"] == list(written["/ins"][1])


def test_read_topics_raw_checks_before_reading(tmp_path):
    bag = tmp_path / "bag"
    _write(bag, "mcap", "open_writer")
    with pytest.raises(BagError, match=r"no topic /missing \(topics: /ins, /note, /state\)"):
        read_topics_raw(bag, ["/ins", "/missing"])
    seen = []

    def refuse(available):
        seen.append(dict(available))
        raise BagError("refused")

    with pytest.raises(BagError, match="refused"):
        read_topics_raw(bag, ["/ins"], check=refuse)
    assert seen == [{"/ins": TWIST, "/note": STRING, "/state": STATE}]
    with pytest.raises(BagError, match="has no topic /missing"):
        BagStream(bag, ["/missing"])


def _mcap_file(bag):
    return next(bag.glob("*.mcap"))


def test_damaged_mcap_is_a_clear_error(tmp_path):
    bag = tmp_path / "bag"
    _write(bag, "mcap", "open_writer")
    f = _mcap_file(bag)
    data = f.read_bytes()
    f.write_bytes(data[:len(data) // 2])            # cut in the middle of a record
    with pytest.raises(BagError, match="truncated"):
        read_topics_raw(bag, ["/ins"])               # the numpy scanner (metadata fast path)
    with pytest.raises(BagError, match="cannot be opened"):
        BagStream(bag, ["/ins"])                     # rosbags: no footer
    f.write_bytes(b"not an mcap file at all" * 10)
    with pytest.raises(BagError, match="not an MCAP file"):
        read_topics_raw(bag, ["/ins"])


def test_damaged_sqlite3_is_a_clear_error(tmp_path):
    bag = tmp_path / "bag"
    _write(bag, "sqlite3", "RecordingBag")
    db = next(bag.glob("*.db3"))
    with sqlite3.connect(db) as con:  # a damaged record: text where the receive time belongs
        con.execute("UPDATE messages SET timestamp = 'garbage' WHERE id = (SELECT MAX(id) FROM "
                    "messages WHERE topic_id = (SELECT id FROM topics WHERE name = '/ins'))")
    with pytest.raises(BagError, match="corrupt"):
        list(read_messages(bag, topics=["/ins"]))
    db.write_bytes(b"\x00" * 4096)
    with pytest.raises(BagError, match=f"bag '{bag}'"):
        read_topics_raw(bag, ["/ins"])


def test_not_a_bag(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match="not a rosbag2 bag"):
        read_topics_raw(tmp_path / "empty", ["/ins"])
    with pytest.raises(BagError, match="does not exist"):
        BagStream(tmp_path / "missing", ["/ins"])
