"""``bagio.recording3d.read_recording3d`` (raw CDR, ``cdr.decode_filter_state_columns``) reads a
recording of a real ``flight-fdi run --model ins3d`` exactly as the per-message rosbags decoding
it replaced (kept here as the reference), from both storages the recorder writes; a bag that is
not a usable ins3d recording gives one BagError line."""
from __future__ import annotations

import dataclasses
import shutil

import numpy as np
import pytest

from flight_fdi.bagio.errors import BagError
from flight_fdi.bagio.reader import read_topics_raw
from flight_fdi.bagio.recording3d import read_recording3d
from flight_fdi.bagio.typestore import get_typestore
from flight_fdi.bagio.writer import RecordingBag
from flight_fdi.cli.main import main
from flight_fdi.nodes import ins3d_recording

STATE, MODEL = "/fdi/state", "/fdi/model"
FS, MI = "flight_fdi_msgs/msg/FilterState", "flight_fdi_msgs/msg/ModelInfo"


def _rosbags_reference(path) -> dict:
    """The reader this one replaced: every message deserialised by rosbags."""
    from flight_fdi.bagio.reader import read_messages
    from flight_fdi.core.gate import GateConfig
    from flight_fdi.core.ins3d.data import NavSteps, RefRows

    info, states = None, []
    for topic, _, _, msg in read_messages(path, [MODEL, STATE]):
        if msg.channel == "ins3d":
            info, states = (msg, states) if topic == MODEL else (info, states + [msg])
    params = dict(zip(info.param_names, info.param_values))
    t0_ns = int(params["t0_sec"]) * 10**9 + int(params["t0_nanosec"])
    rel = lambda m: (m.header.stamp.sec * 10**9 + m.header.stamp.nanosec - t0_ns) * 1e-9
    states = states[[i for i, m in enumerate(states) if m.reset][-1]:]
    t, u, t_ref, z, r, a, step = [rel(states[0])], [], [], [], [], [], []
    for m in states[1:]:
        if m.dt > 0.0:
            t.append(rel(m))
            u.append(np.asarray(m.u, dtype=float))
        elif len(m.z):
            t_ref.append(rel(m))
            z.append(np.asarray(m.z, dtype=float))
            r.append(np.diag(np.asarray(m.r, dtype=float).reshape(3, 3)))
            a.append(np.asarray(m.u, dtype=float))
            step.append(len(t) - 1)
    t, U = np.array(t), np.vstack(u)
    steps = NavSteps(t, np.diff(t), np.ascontiguousarray(U[:, :9].reshape(-1, 3, 3)),
                     U[:, 9:12].copy(), U[:, 12:15].copy(), U[:, 15:18].copy(), U[:, 18].copy(),
                     U[:, 19].copy())
    refs = RefRows(np.array(t_ref), np.array(z).reshape(-1, 3),
                   np.ascontiguousarray(np.array(r).reshape(-1, 3)),
                   np.array(step, dtype=np.int64), np.array(a).reshape(-1, 3))
    gate = GateConfig(rule=info.gate_rule, probability=info.gate_probability,
                      alarm_m=info.alarm_m, alarm_n=info.alarm_n, action=info.gate_action)
    return {"grade": ins3d_recording.recorded_grade(info.model_name, params),
            "rows": int(params["rows"]), "options": ins3d_recording.recorded_options(params),
            "gate": gate, "t0_ns": t0_ns, "steps": steps, "refs": refs,
            "x_last": np.asarray(states[-1].x, dtype=float), "frame_id": info.header.frame_id}


def _same_array(a: np.ndarray, b: np.ndarray) -> bool:
    return (a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
            and a.flags.c_contiguous == b.flags.c_contiguous)


def _assert_identical(got: dict, ref: dict) -> None:
    assert got.keys() == ref.keys()
    for key in ref:
        if key in ("steps", "refs"):
            for f in dataclasses.fields(ref[key]):
                assert _same_array(getattr(got[key], f.name), getattr(ref[key], f.name)), f.name
        elif key == "x_last":
            assert _same_array(got[key], ref[key])
        else:
            assert got[key] == ref[key], key


def _write(path, models: list[bytes], states: list[bytes], storage: str = "mcap"):
    """A recording as recorder_node writes it (its RecordingBag), messages 1 ms apart."""
    bag = RecordingBag(path, storage)
    bag.add_topic(MODEL, MI)
    bag.add_topic(STATE, FS)
    for k, data in enumerate(models):
        bag.write(MODEL, 1_000_000 * (k + 1), data)
    for k, data in enumerate(states):
        bag.write(STATE, 1_000_000 * (len(models) + k + 1), data)
    bag.close()
    return path


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """{"mcap": the recording of a real run (60-s simulated flight), "sqlite3": its messages
    rewritten by the recorder's writer in sqlite3, "models"/"states": its raw messages}."""
    root = tmp_path_factory.mktemp("rec3d")
    assert main(["simulate", str(root / "bag"), "--model", "ins3d", "--duration", "60",
                 "--seed", "4", "--fault", "gyro:step:t=20,mag=30deg/h,axis=x"]) == 0
    assert main(["run", str(root / "bag"), "--model", "ins3d", "--out", str(root / "run"),
                 "--no-progress", "--no-report"]) in (0, 3)
    rec = root / "run" / "recording"
    raw = read_topics_raw(rec, [MODEL, STATE])
    models = [raw[MODEL].payloads[i] for i in range(len(raw[MODEL].payloads))]
    states = [raw[STATE].payloads[i] for i in range(len(raw[STATE].payloads))]
    return {"mcap": rec, "sqlite3": _write(root / "sqlite", models, states, "sqlite3"),
            "models": models, "states": states, "root": root}


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_equals_the_rosbags_decoding(run, storage):
    got = read_recording3d(run[storage])
    _assert_identical(got, _rosbags_reference(run[storage]))
    assert got["steps"].t.size > 1000 and got["refs"].t.size > 500
    assert ins3d_recording.read_recording3d is read_recording3d    # the old name still works


def test_the_last_restart_of_the_filter_is_kept(run, tmp_path):
    s = run["states"]
    again = _write(tmp_path / "again", run["models"], s[:40] + s)
    _assert_identical(read_recording3d(again), _rosbags_reference(run["mcap"]))


def _edit(payload: bytes, **fields) -> bytes:
    store = get_typestore()
    msg = store.deserialize_cdr(payload, FS)
    for k, v in fields.items():
        setattr(msg, k, v)
    return bytes(store.serialize_cdr(msg, FS))


def _first(states: list[bytes], step: bool) -> int:
    """The number of the first step (``dt`` > 0) or update (z) after the reset."""
    store = get_typestore()
    msgs = (store.deserialize_cdr(d, FS) for d in states[1:])
    return 1 + next(i for i, m in enumerate(msgs) if (m.dt > 0 if step else len(m.z)))


def _edited(states: list[bytes], step: bool, **fields) -> list[bytes]:
    """The states up to the first step or update, which is edited."""
    k = _first(states, step)
    return states[:k] + [_edit(states[k], **fields)]


def _other_channel(models: list[bytes]) -> list[bytes]:
    store = get_typestore()
    msg = store.deserialize_cdr(models[-1], MI)
    msg.channel = "x"
    return [bytes(store.serialize_cdr(msg, MI))]


CASES = {
    "missing": (lambda r: [], "does not exist"),
    "not_ins3d": (lambda r: ([], r["states"]), "no topic /fdi/model"),
    "other_channel": (lambda r: (_other_channel(r["models"]), r["states"]),
                      "no ModelInfo of channel 'ins3d' on /fdi/model"),
    "no_reset": (lambda r: (r["models"], [_edit(r["states"][0], reset=False)]
                            + r["states"][1:50]), "no initial ins3d state (reset)"),
    "short_u": (lambda r: (r["models"], _edited(r["states"], True, u=np.zeros(19))),
                "an ins3d step state has 19 values in u, expected 20"),
    "no_step": (lambda r: (r["models"], r["states"][:1]), "has no propagation step"),
    "bad_r": (lambda r: (r["models"], _edited(r["states"], False, r=np.zeros(4))),
              "an ins3d update state has 4 values in r, expected 9"),
    "malformed": (lambda r: (r["models"], r["states"][:3] + [r["states"][3][:60]]),
                  "/fdi/state message #3: not a valid flight_fdi_msgs/msg/FilterState"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_bag_that_is_not_a_usable_ins3d_recording_is_one_line(run, tmp_path, case):
    make, needle = CASES[case]
    parts = make(run)
    path = tmp_path / "rec"
    if parts:
        models, states = parts
        bag = RecordingBag(path, "mcap")
        for topic, msgtype, msgs in ((MODEL, MI, models), (STATE, FS, states)):
            if msgs:
                bag.add_topic(topic, msgtype)
                for k, data in enumerate(msgs):
                    bag.write(topic, 1_000_000 * (k + 1), data)
        bag.close()
    with pytest.raises(BagError) as err:
        read_recording3d(path)
    assert needle in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_damaged_or_empty_recording_is_one_line(run, tmp_path, storage):
    bad = tmp_path / storage
    shutil.copytree(run[storage], bad)
    (data,) = [f for f in bad.iterdir() if f.suffix in (".mcap", ".db3")]
    data.write_bytes(data.read_bytes()[:data.stat().st_size // 2])
    empty = tmp_path / "empty"
    empty.mkdir()
    for path in (bad, empty):
        with pytest.raises(BagError) as err:
            read_recording3d(path)
        assert str(err.value).startswith(f"bag '{path}'") and "\n" not in str(err.value)
