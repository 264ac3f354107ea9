"""bagio.recording.read_recording on a recording written like recorder_node writes it
(RecordingBag, the filter node's own FilterState encoding, ModelInfo from rclpy), without a ROS
graph: every array equals what was recorded (and what rosbags' deserializer reads), resets
keep the longest segment, stacked rows merge, damaged messages are clear errors."""
from __future__ import annotations

import numpy as np
import pytest

from flight_fdi.bagio import BagError, read_messages
from flight_fdi.bagio.recording import read_recording
from flight_fdi.bagio.writer import RecordingBag, qos_dict
from flight_fdi.core.kalman import GateConfig
from flight_fdi.core.models import get_model
from flight_fdi.nodes import convert

NS = 10**9
T0 = 1_700_000_000 * NS
STATE, MODEL = "flight_fdi_msgs/msg/FilterState", "flight_fdi_msgs/msg/ModelInfo"


def _model_bytes(channel, model, gate):
    """The filter node's ModelInfo (convert.model_info_msg) serialized exactly, as it is on
    the wire (rosbags' serializer: rclpy's in-process buffer may carry spare bytes)."""
    from flight_fdi.bagio import get_typestore

    msg = convert.model_info_msg(convert.s_to_stamp(T0 / NS), channel, model, gate,
                                 frame_id="enu")
    store = get_typestore()
    T = store.types
    fields = {}
    for name, kind in msg.get_fields_and_field_types().items():
        value = getattr(msg, name)
        if name == "header":
            value = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
                sec=value.stamp.sec, nanosec=value.stamp.nanosec), frame_id=value.frame_id)
        elif kind.startswith("sequence<double"):
            value = np.array(value, dtype=float)
        elif kind.startswith("sequence<string"):
            value = list(value)
        fields[name] = value
    return bytes(store.serialize_cdr(T[MODEL](**fields), MODEL))


def _record(path, steps, close=True, extra=(), storage="mcap"):
    """A recording of channel x (and one y state, which must be ignored): ``steps`` is a list of
    dicts with t_ns, z, R, H, reset."""
    model, gate = get_model("ins_channel"), GateConfig(alarm_m=2, alarm_n=4)
    rng = np.random.default_rng(4)
    bag = RecordingBag(path, storage)
    bag.add_topic("/fdi/model", MODEL, [qos_dict(depth=1, durability="transient_local")])
    bag.add_topic("/fdi/state", STATE, [qos_dict()])
    bag.write("/fdi/model", T0, _model_bytes("x", model, gate))
    written = []
    for k, s in enumerate(steps):
        x, P = rng.normal(size=4), rng.normal(size=16)
        t = s["t_ns"]
        data = convert.filter_state_bytes((t // NS, t % NS), "x", model.state_names, x, P,
                                          z=s["z"], R=s["R"], H=s["H"], dt=s.get("dt", 0.1),
                                          fused=True, gated=bool(k % 3 == 0),
                                          reset=s.get("reset", False), frame_id="enu")
        bag.write("/fdi/state", T0 + k, data)
        written.append((x, P))
    bag.write("/fdi/state", T0 + len(steps), convert.filter_state_bytes(
        (T0 // NS, 0), "y", model.state_names, np.zeros(4), np.zeros(16), z=[0.0], R=[1.0],
        H=[1, 0, 0, 0]))
    for data in extra:
        bag.write("/fdi/state", T0 + len(steps) + 1, data)
    bag.flush()
    if close:
        bag.close()
    return model, gate, written


def _steps(n, t0=T0, reset_at=None):
    return [{"t_ns": t0 + k * 100_000_000, "z": [0.01 * k], "R": [0.04], "H": [1, 0, 0, 0],
             "reset": k == reset_at} for k in range(n)]


def test_every_array_is_what_was_recorded(tmp_path):
    steps = _steps(30)
    model, gate, written = _record(tmp_path / "rec", steps)
    rec = read_recording(tmp_path / "rec", "x")
    assert rec.model.name == model.name and rec.gate == gate
    np.testing.assert_array_equal(rec.model.A, model.A)
    np.testing.assert_array_equal(rec.t, [s["t_ns"] // NS + (s["t_ns"] % NS) * 1e-9
                                          for s in steps])
    np.testing.assert_allclose(rec.dt, [0.0] + [0.1] * 29)
    np.testing.assert_array_equal(rec.z[:, 0], [s["z"][0] for s in steps])
    np.testing.assert_array_equal(rec.x, [x for x, _ in written])
    np.testing.assert_array_equal(rec.P, [P.reshape(4, 4) for _, P in written])
    assert rec.fused.all() and list(rec.gated) == [k % 3 == 0 for k in range(30)]
    assert rec.frame_id == "enu" and rec.closed_cleanly is True and rec.gaps == []
    assert rec.problems == {"out_of_order_state": 0, "no_measurement": 0, "segments": 1}
    # the same numbers as rosbags' own deserialization of the bag
    states = [m for topic, _, _, m in read_messages(tmp_path / "rec", ["/fdi/state"])
              if m.channel == "x"]
    np.testing.assert_array_equal(rec.x, [m.x for m in states])
    np.testing.assert_array_equal(rec.t, [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
                                          for m in states])


def test_resets_out_of_order_and_stacked_rows(tmp_path):
    steps = _steps(10) + _steps(15, t0=T0 + 5 * NS, reset_at=0)
    steps[12] = dict(steps[12], t_ns=steps[11]["t_ns"])          # repeated stamp: dropped
    steps[20] = dict(steps[20], z=[0.1, 0.3], R=[0.04, 0.0, 0.0, 0.01],  # two stacked rows
                     H=[1, 0, 0, 0, 1, 0, 0, 0])
    _record(tmp_path / "rec", steps, close=False)
    rec = read_recording(tmp_path / "rec", "x")
    assert rec.problems["segments"] == 2 and rec.problems["out_of_order_state"] == 1
    assert rec.problems["merged_rows"] == 1 and rec.closed_cleanly is False
    assert len(rec.t) == 14 and rec.t[0] == pytest.approx((T0 + 5 * NS) / NS)
    w = np.array([1 / 0.04, 1 / 0.01])
    k = 20 - 10 - 1  # position in the kept segment (one dropped before it)
    assert rec.z[k, 0] == pytest.approx(w @ [0.1, 0.3] / w.sum())
    assert rec.R[k, 0, 0] == pytest.approx(1 / w.sum())
    assert rec.first_stamp_s == pytest.approx(T0 / NS)  # of the whole recording


def test_damaged_and_missing_content_are_clear_errors(tmp_path):
    good = convert.filter_state_bytes((T0 // NS, 0), "x", ["a"] * 4, np.zeros(4), np.zeros(16))
    _record(tmp_path / "bad", _steps(3), extra=[good[:40]])
    with pytest.raises(BagError, match=r"/fdi/state message #4: not a valid "
                                       r"flight_fdi_msgs/msg/FilterState"):
        read_recording(tmp_path / "bad", "x")
    _record(tmp_path / "ok", _steps(3))
    with pytest.raises(BagError, match="no ModelInfo for channel 'y'"):
        read_recording(tmp_path / "ok", "y")
    with pytest.raises(BagError, match="no topic /other"):
        read_recording(tmp_path / "ok", "x", state_topic="/other")


def test_an_mcap_recording_is_read_raw_and_sqlite3_gives_the_same(tmp_path, monkeypatch):
    """One reader for both recordings (``read_topics_raw``): an mcap recording is read without
    rosbags' Reader, a sqlite3 one through it, to the same arrays; a damaged file of either is
    one BagError line naming the bag."""
    import flight_fdi.bagio.reader as reader

    steps = _steps(20)
    _record(tmp_path / "mcap", steps)
    _record(tmp_path / "sqlite3", steps, storage="sqlite3")
    via_reader = read_recording(tmp_path / "sqlite3", "x")
    opened: list = []
    real = reader.open_bag
    monkeypatch.setattr(reader, "open_bag", lambda p: opened.append(p) or real(p))
    raw = read_recording(tmp_path / "mcap", "x")
    assert opened == []                           # the mcap file scanned, no rosbags' Reader
    for name in ("t", "dt", "z", "R", "H", "x", "P", "fused", "gated"):
        np.testing.assert_array_equal(getattr(raw, name), getattr(via_reader, name))
    assert raw.model.name == via_reader.model.name and raw.gate == via_reader.gate
    read_recording(tmp_path / "sqlite3", "x")
    assert opened == [tmp_path / "sqlite3"]
    for storage in ("mcap", "sqlite3"):
        (data,) = [f for f in (tmp_path / storage).iterdir() if f.suffix in (".mcap", ".db3")]
        data.write_bytes(data.read_bytes()[:data.stat().st_size // 2])
        with pytest.raises(BagError) as err:
            read_recording(tmp_path / storage, "x")
        assert f"bag '{tmp_path / storage}" in str(err.value) and "\n" not in str(err.value)
