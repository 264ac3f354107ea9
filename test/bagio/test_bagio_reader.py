"""read_flight: values, problem counts and clear errors; read_messages; the writer's options."""
from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from flight_fdi.bagio import BagError, cdr, get_typestore, open_writer, read_flight, read_messages
from flight_fdi.bagio import mcapscan

NS = 10**9
T0 = 1_700_000_000 * NS


def _write_crafted(path: Path, storage: str = "mcap", compression: str = "zstd") -> None:
    """INS and reference messages with NaNs, duplicate and out-of-order stamps, bad covariances.

    Bag receive times increase with the list position, so the bag order is the list order.
    """
    ins_s = [0, 1, 2, 2, 1.5, 3, 4, 5, 4.5]
    ins_v = [0.0, 1.0, 2.0, 2.5, 1.5, 3.0, np.nan, 5.0, 4.5]
    ref_s = [0, 1, 1, 2, 3, 4, 5]
    ref_v = [10.0, 11.0, 11.5, 12.0, 13.0, 14.0, np.inf]
    ref_rx = [0.01, 0.02, 0.03, np.nan, 0.0, -1.0, 0.01]
    ins_stamp = T0 + (np.array(ins_s) * NS).astype(np.int64)
    ref_stamp = T0 + (np.array(ref_s) * NS).astype(np.int64)
    tw = np.zeros((len(ins_s), 6))
    tw[:, 0] = ins_v
    tw[:, 1] = -np.arange(len(ins_s))  # channel y: all valid
    twr = np.zeros((len(ref_s), 6))
    twr[:, 0] = ref_v
    twr[:, 1] = 100.0 + np.arange(len(ref_s))
    cov = np.zeros((len(ref_s), 36))
    cov[:, 0] = ref_rx
    cov[:, 7] = 0.5  # channel y: all valid
    ins = cdr.encode(cdr.TWIST_STAMPED, ins_stamp, "ins", tw)
    ref = cdr.encode(cdr.TWIST_COV_STAMPED, ref_stamp, "gnss", twr, cov)
    with open_writer(path, storage=storage, compression=compression) as bag:
        for i, data in enumerate(ins):
            bag.write_raw("/ins/velocity", cdr.TWIST_STAMPED, data, T0 + 10 * i)
        for i, data in enumerate(ref):
            bag.write_raw("/reference/velocity", cdr.TWIST_COV_STAMPED, data, T0 + 10 * i + 5)


@pytest.fixture(scope="module")
def crafted(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("bags") / "crafted"
    _write_crafted(path)
    return path


def test_problem_counts_and_kept_values(crafted):
    d = read_flight(crafted)
    # the shuffled INS stamps (1.5 after 2, 4.5 after 5) are sorted, not dropped
    assert d.problems == {
        "ins_nonfinite_velocity": 1, "ins_duplicate_stamp": 1, "ins_out_of_order_stamp": 0,
        "ref_nonfinite_velocity": 1, "ref_duplicate_stamp": 1, "ref_out_of_order_stamp": 0,
        "ref_invalid_covariance": 3}
    ins = d.series[0]
    assert ins.dropped == {"non_finite": 1, "zero_stamp": 0, "duplicate_stamp": 1,
                           "out_of_order": 0}
    assert ins.reordered > 0 and ins.messages == 9
    assert d.stamp_ins_ns.tolist() == [T0 + int(k * NS) for k in (0, 1, 1.5, 2, 3, 4.5, 5)]
    assert d.v_ins.tolist() == [0.0, 1.0, 1.5, 2.0, 3.0, 4.5, 5.0]
    # with no reorder window the late ones are dropped as out of order instead
    from flight_fdi.bagio.inputs import InputSpec

    d0 = read_flight(crafted, spec=InputSpec(reorder_window_s=0.0))
    assert d0.series[0].dropped["out_of_order"] == 2 and d0.series[0].reordered == 0
    assert d0.v_ins.tolist() == [0.0, 1.0, 2.0, 3.0, 5.0]
    assert d.stamp_ref_ns.tolist() == [T0 + k * NS for k in (0, 1, 2, 3, 4)]
    assert d.v_ref.tolist() == [10.0, 11.0, 12.0, 13.0, 14.0]
    assert d.r_ref[:2].tolist() == [0.01, 0.02] and np.all(np.isnan(d.r_ref[2:]))
    assert d.t0_ns == T0 and d.t0 == T0 / NS
    assert np.allclose(d.t_ins - d.t0, [0, 1, 1.5, 2, 3, 4.5, 5], atol=1e-6)
    assert d.ins_rel_s.tolist() == [0.0, 1.0, 1.5, 2.0, 3.0, 4.5, 5.0]
    assert d.x_truth is None and d.fault is None and d.faults == []
    assert "1 ins duplicate stamp" in d.problem_summary()


def test_channel_y_uses_covariance_index_7(crafted):
    d = read_flight(crafted, channel="y")
    assert d.problems["ins_nonfinite_velocity"] == 0 and d.problems["ref_invalid_covariance"] == 0
    assert d.v_ins.tolist() == [0.0, -1.0, -4.0, -2.0, -5.0, -6.0, -8.0, -7.0]  # NaN on x only
    assert np.all(d.r_ref == 0.5)
    assert d.v_ref.tolist() == [100.0, 101.0, 103.0, 104.0, 105.0, 106.0]


@pytest.mark.parametrize("storage,compression", [("sqlite3", "none"), ("sqlite3", "zstd"),
                                                 ("mcap", "none")])
def test_storages_read_alike(crafted, tmp_path, storage, compression):
    _write_crafted(tmp_path / "b", storage, compression)
    a, b = read_flight(crafted), read_flight(tmp_path / "b")
    assert a.problems == b.problems
    for f in ("stamp_ins_ns", "v_ins", "stamp_ref_ns", "v_ref", "r_ref"):
        assert np.array_equal(getattr(a, f), getattr(b, f), equal_nan=True), f


def test_reading_a_single_mcap_file(crafted):
    (mcap_file,) = crafted.glob("*.mcap")
    d = read_flight(mcap_file)
    assert d.v_ins.tolist() == [0.0, 1.0, 1.5, 2.0, 3.0, 4.5, 5.0]


def test_missing_and_non_bags(tmp_path):
    with pytest.raises(BagError, match="does not exist"):
        read_flight(tmp_path / "nope")
    (tmp_path / "empty_dir").mkdir()
    with pytest.raises(BagError, match="not a rosbag2 bag"):
        read_flight(tmp_path / "empty_dir")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(BagError, match="not a rosbag2 bag"):
        read_flight(tmp_path / "notes.txt")
    bad = tmp_path / "bad_yaml"
    bad.mkdir()
    (bad / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
    with pytest.raises(BagError, match="cannot be opened"):
        read_flight(bad)


def test_corrupt_bags(crafted, tmp_path):
    trunc = tmp_path / "trunc"
    shutil.copytree(crafted, trunc)
    (f,) = trunc.glob("*.mcap")
    f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
    with pytest.raises(BagError, match="trunc"):
        read_flight(trunc)
    garbled = tmp_path / "garbled"
    shutil.copytree(crafted, garbled)
    (g,) = garbled.glob("*.mcap")
    data = bytearray(g.read_bytes())
    start = data.index(b"zstd") + 4 + 8 + 8  # compressed bytes of the first chunk
    data[start:start + 40] = b"\xff" * 40
    g.write_bytes(bytes(data))
    with pytest.raises(BagError, match="garbled"):
        read_flight(garbled)


def test_missing_empty_and_mistyped_topics(tmp_path):
    store = get_typestore()
    with open_writer(tmp_path / "other") as bag:
        bag.write("/other", "std_msgs/msg/String", store.types["std_msgs/msg/String"](data="x"), 1)
    with pytest.raises(BagError, match=r"no messages on /ins/velocity \(topics: /other; name the inputs with --ins-topic"):
        read_flight(tmp_path / "other")

    ins = cdr.encode(cdr.TWIST_STAMPED, np.array([T0]), "ins", np.zeros((1, 6)))
    with open_writer(tmp_path / "no_ref") as bag:
        bag.write_raw("/ins/velocity", cdr.TWIST_STAMPED, ins[0], T0)
        bag.add_topic("/reference/velocity", cdr.TWIST_COV_STAMPED)  # connection, no messages
    with pytest.raises(BagError, match="no messages on /reference/velocity"):
        read_flight(tmp_path / "no_ref")

    with open_writer(tmp_path / "mistyped") as bag:
        bag.write_raw("/ins/velocity", cdr.TWIST_STAMPED, ins[0], T0)
        bag.write_raw("/reference/velocity", "std_msgs/msg/String",
                      b"\x00\x01\x00\x00\x03\x00\x00\x00hi\x00", T0)
    with pytest.raises(BagError, match="carries std_msgs/msg/String, expected one of"):
        read_flight(tmp_path / "mistyped")

    nan_ins = cdr.encode(cdr.TWIST_STAMPED, np.array([T0, T0 + 1]), "ins",
                         np.full((2, 6), np.nan))
    ref = cdr.encode(cdr.TWIST_COV_STAMPED, np.array([T0]), "r", np.zeros((1, 6)), np.ones(36))
    with open_writer(tmp_path / "all_nan") as bag:
        for i, d in enumerate(nan_ins):
            bag.write_raw("/ins/velocity", cdr.TWIST_STAMPED, d, T0 + i)
        bag.write_raw("/reference/velocity", cdr.TWIST_COV_STAMPED, ref[0], T0)
    with pytest.raises(BagError, match="/ins/velocity: no usable samples .0 of 2 messages usable; 2 non_finite"):
        read_flight(tmp_path / "all_nan")
    with pytest.raises(BagError, match="channel must be one of"):
        read_flight(tmp_path / "all_nan", channel="q")


def test_read_messages_decodes_and_filters(crafted):
    got = list(read_messages(crafted, topics=["/reference/velocity"]))
    assert len(got) == 7
    topic, msgtype, t_ns, msg = got[0]
    assert (topic, msgtype, t_ns) == ("/reference/velocity", cdr.TWIST_COV_STAMPED, T0 + 5)
    assert msg.twist.twist.linear.x == 10.0 and msg.header.frame_id == "gnss"
    assert [m[2] for m in got] == sorted(m[2] for m in got)
    assert len(list(read_messages(crafted))) == 16
    with pytest.raises(BagError, match="no topic /nope"):
        list(read_messages(crafted, topics=["/nope"]))


def test_writer_qos_series_order_and_overwrite(tmp_path):
    store = get_typestore()
    String = store.types["std_msgs/msg/String"]
    path = tmp_path / "w"
    with open_writer(path) as bag:
        bag.add_topic("/latched", "std_msgs/msg/String", qos="transient_local")
        bag.write_series([
            ("/latched", "std_msgs/msg/String", np.array([5]),
             [bytes(store.serialize_cdr(String(data="L"), "std_msgs/msg/String"))]),
            ("/a", "std_msgs/msg/String", np.array([5, 1]),
             [bytes(store.serialize_cdr(String(data=s), "std_msgs/msg/String")) for s in "pq"]),
        ])
        bag.set_metadata("key", "value")
    meta = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["version"] == 9 and meta["storage_identifier"] == "mcap"
    assert meta["custom_data"] == {"key": "value"}
    qos = {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
           for t in meta["topics_with_message_count"]}
    assert qos["/latched"][0]["durability"] == "transient_local"
    assert qos["/latched"][0]["reliability"] == "reliable" and qos["/latched"][0]["depth"] == 1
    assert qos["/a"][0]["durability"] == "volatile"
    # time order, ties in the order of the series
    assert [(t, m.data) for _, _, t, m in read_messages(path)] == [(1, "q"), (5, "L"), (5, "p")]

    with pytest.raises(BagError, match="exists already"):
        with open_writer(path):
            pass
    with open_writer(path, overwrite=True) as bag:
        bag.write("/b", "std_msgs/msg/String", String(data="new"), 3)
    assert [m.data for *_, m in read_messages(path)] == ["new"]
    other = tmp_path / "precious"
    other.mkdir()
    (other / "thesis.tex").write_text("x")
    with pytest.raises(BagError, match="not a bag; not overwriting"):
        with open_writer(other, overwrite=True):
            pass
    assert (other / "thesis.tex").exists()


def test_writer_errors_remove_the_partial_bag(tmp_path):
    path = tmp_path / "partial"
    with pytest.raises(RuntimeError, match="boom"):
        with open_writer(path) as bag:
            bag.write_raw("/x", cdr.TWIST_STAMPED,
                          cdr.encode(cdr.TWIST_STAMPED, np.array([1]), "", np.zeros((1, 6)))[0], 1)
            raise RuntimeError("boom")
    assert not path.exists()
    with pytest.raises(BagError, match="unknown storage"):
        with open_writer(tmp_path / "s", storage="rosbag1"):
            pass
    with pytest.raises(BagError, match="directory .* does not exist"):
        with open_writer(tmp_path / "no" / "such" / "dir"):
            pass
    with open_writer(tmp_path / "t") as bag:
        with pytest.raises(BagError, match="already carries"):
            bag.write_raw("/x", cdr.TWIST_STAMPED, b"\x00\x01\x00\x00" + bytes(60), 1)
            bag.write_raw("/x", cdr.TWIST_COV_STAMPED, b"", 2)
        with pytest.raises(BagError, match="absolute name"):
            bag.add_topic("relative", cdr.TWIST_STAMPED)


def _mcap_file(path: Path, indexed: bool) -> None:
    """An MCAP file written by the independent `mcap` library, with or without message indexes."""
    from mcap.writer import IndexType, Writer

    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=2000,
                   index_types=IndexType.ALL if indexed else IndexType.NONE)
        w.start(profile="ros2", library="test")
        sid = w.register_schema(name=cdr.TWIST_STAMPED, encoding="ros2msg", data=b"")
        ca = w.register_channel(topic="/a", message_encoding="cdr", schema_id=sid)
        cb = w.register_channel(topic="/b", message_encoding="cdr", schema_id=sid)
        for i in range(300):
            data = cdr.encode(cdr.TWIST_STAMPED, np.array([i]), "f" * (i % 5),
                              np.full((1, 6), float(i)))[0]
            w.add_message(channel_id=ca if i % 3 else cb, log_time=1000 + i, publish_time=0,
                          data=data, sequence=i)
        w.finish()


@pytest.mark.parametrize("indexed", [True, False])
def test_mcap_scanner_against_the_mcap_library(tmp_path, indexed):
    from mcap.reader import make_reader

    path = tmp_path / "f.mcap"
    _mcap_file(path, indexed)
    got = mcapscan.scan(str(path), {"/a", "/b", "/absent"}, "f")
    with open(path, "rb") as fh:
        want: dict[str, list] = {"/a": [], "/b": []}
        for _, channel, message in make_reader(fh).iter_messages(log_time_order=True):
            want[channel.topic].append((message.log_time, message.data))
    for topic in ("/a", "/b"):
        assert got[topic].log_ns.tolist() == [t for t, _ in want[topic]]
        assert [got[topic].payloads[i] for i in range(len(want[topic]))] == \
            [d for _, d in want[topic]]
    assert len(got["/absent"].payloads) == 0


def test_sample_bag_is_a_valid_mcap_for_other_tools(repo_root):
    from mcap.reader import make_reader

    (path,) = (repo_root / "bags" / "accel_fault_500s").glob("*.mcap")
    counts: dict[str, int] = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        for ch in summary.channels.values():
            schema = summary.schemas[ch.schema_id]
            assert schema.encoding == "ros2msg" and ch.message_encoding == "cdr"
            assert b"std_msgs/Header header" in schema.data or schema.name == "std_msgs/msg/String"
            assert "offered_qos_profiles" in ch.metadata
        for _, channel, _ in reader.iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    assert counts == {"/ins/velocity": 50000, "/reference/velocity": 10000, "/sim/truth": 2000,
                      "/sim/fault": 1}
    assert math.isclose(sum(counts.values()), 62001)


def test_read_messages_uses_definitions_stored_in_the_bag(tmp_path):
    """A type the project does not know is decoded from the definition the bag carries."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_types_from_msg
    from rosbags.typesys import get_typestore as rosbags_store

    other = rosbags_store(Stores.EMPTY)
    other.register(get_types_from_msg("float64 a\nstring b\nint32[] c", "test_pkg/msg/Foo"))
    Foo = other.types["test_pkg/msg/Foo"]
    with Writer(tmp_path / "foreign", version=9) as w:
        conn = w.add_connection("/foo", "test_pkg/msg/Foo", typestore=other)
        w.write(conn, 42, other.serialize_cdr(Foo(a=1.5, b="hi", c=np.array([3, 4], np.int32)),
                                              "test_pkg/msg/Foo"))
    ((topic, msgtype, t_ns, msg),) = list(read_messages(tmp_path / "foreign"))
    assert (topic, msgtype, t_ns, msg.a, msg.b, msg.c.tolist()) == (
        "/foo", "test_pkg/msg/Foo", 42, 1.5, "hi", [3, 4])
