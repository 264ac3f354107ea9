"""The failures the fuzzers found, as regular tests (each failed before its fix).

1. A finite but huge velocity (1e200 m/s, 1.8e308 m/s) made beta2 = nu^2 / S overflow: the
   filter published ``beta2 = inf`` and carried a state of ~1e200 into the next steps. Fix: the
   core's update refuses an update whose result is not finite (CoreError, filter unchanged);
   the node counts it as ``dropped_core_error``.
2. With redundant references such an innovation raised a Python ``OverflowError`` (not a
   CoreError) in the reference monitor, which escaped the callback and stopped the node. Fix:
   the monitor refuses it (CoreError) and compares without squaring.
3. A stamp before 1970 (``sec < 0``, valid on the wire: int32) stopped the node: the output
   stamp conversion raised ValueError. Fix: negative stamps convert.
4. ``sec = 2^31 - 1`` with ``nanosec >= 1e9`` (valid on the wire: uint32) is a time no output
   stamp can hold: the conversion raised. Fix: such input is dropped and counted
   (``dropped_<input>_invalid_stamp``).
5. Attitude mode with the rate missing (angle-only update): when the update was refused, the
   prediction had already been applied, so the next step predicted over the interval a second
   time. Fix: the state is restored; the next step equals that of a stream without the sample.
6. Voter: two huge but finite gyro values (1.8e308 rad/s) in one window made the running window
   sum overflow: ``fdi/vote`` carried ``pair_mean = inf`` (then NaN, inf - inf). Fix: values
   beyond max float / (4 N) are dropped and counted (``dropped_imuK_out_of_range``).
7. Bag reading: a damaged sqlite3 record whose receive time is a blob raised ValueError (the
   integer conversion sat outside the error wrapping); a chunk of an mcap file whose
   compression name is not UTF-8 raised UnicodeDecodeError in the fast mcap scanner. Fix: both
   are BagError ("... is corrupt").
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from flight_fdi.core.errors import CoreError
from hardening import fuzzlib as fz
from hardening import test_fuzz_attitude_mode as att
from hardening import test_fuzz_filter_node as flt

T0 = 1_700_000_000 * fz.NS


def _ref_index(msgs, k):
    """Index in ``msgs`` of the k-th reference message."""
    return [i for i, m in enumerate(msgs) if m["type"] == flt.TWIST_COV][k]


def _by_stamp(states, channel):
    return {(m.header.stamp.sec, m.header.stamp.nanosec): m for m in states
            if m.channel == channel}


# ------------------------------------------------------------------------------ core level

def test_kalman_update_that_overflows_is_refused_and_leaves_the_filter_unchanged():
    from flight_fdi.core.kalman import KalmanFilter
    from flight_fdi.core.models import ins_channel

    kf = KalmanFilter(ins_channel())
    kf.step(0.0, [0.1], [[0.01]])
    x, P = kf.x.copy(), kf.P.copy()
    for z in (1e200, -1.7976931348623157e308):
        with pytest.raises(CoreError, match="overflows"):
            kf.step(0.1, [z], [[0.01]])
        with pytest.raises(CoreError, match="overflows"):
            kf.update([z], [[0.01]])
        np.testing.assert_array_equal(kf.x, x)
        np.testing.assert_array_equal(kf.P, P)
    # a large but representable innovation is still an ordinary (gated) update
    res = kf.step(0.1, [1e100], [[0.01]])
    assert res.exceeded and math.isfinite(res.beta2) and np.all(np.isfinite(kf.x))


def test_reference_monitor_refuses_an_overflowing_row_instead_of_raising_overflowerror():
    from flight_fdi.core.kalman import GateConfig
    from flight_fdi.core.models import ins_channel
    from flight_fdi.core.references import RedundantFilter

    rf = RedundantFilter(ins_channel(), ["a", "b"], GateConfig())
    rf.step(0.0, 0.0, [0.1, 0.1], [0.01, 0.01])
    x = rf.kf.x.copy()
    for nu in (2.17e276, 1e154):  # the first raised OverflowError before the fix
        with pytest.raises(CoreError, match="overflows"):
            rf.step(0.1, 0.1, [nu, 0.12], [0.01, 0.01])
        np.testing.assert_array_equal(rf.kf.x, x)
    out = rf.step(0.1, 0.1, [1e150, 0.12], [0.01, 0.01])  # huge but representable
    assert np.all(np.isfinite(rf.kf.x)) and out.row_excluded[0]  # a suspect row


def test_stamps_convert_before_1970_and_refuse_what_no_stamp_holds():
    from flight_fdi.nodes import convert

    st = convert.s_to_stamp(-99.896)
    assert (st.sec, st.nanosec) == (-100, 104_000_000)
    assert convert.stamp_to_s(st) == pytest.approx(-99.896, abs=1e-12)
    st = convert.s_to_stamp(-(2.0**31))
    assert (st.sec, st.nanosec) == (-(2**31), 0)
    # (float seconds resolve ~0.24 us near 2^31 s: the last 0.24 us of int32 time round up)
    assert convert.stamp_fits((2**31 - 1) + 0.999)
    assert not convert.stamp_fits((2**31 - 1) + 4294967295 * 1e-9)
    assert not convert.stamp_fits(-(2.0**31) - 1e-6) and not convert.stamp_fits(math.nan)
    # a time so large that t * 1e9 overflows: False, not OverflowError (a corrupt bag's
    # garbage killed the 3-D filter node this way)
    assert not convert.stamp_fits(1e300) and not convert.stamp_fits(-1e300)
    with pytest.raises(ValueError):
        convert.s_to_stamp(1e300)
    with pytest.raises(ValueError):
        convert.s_to_stamp(2.0**31 + 3)


# ------------------------------------------------------------------------------ node level

def _channel(fuzz, ch):
    return fuzz.values[f"filter_node: channel {ch}"]


def _inputs(fuzz):
    return fuzz.values["filter_node: inputs"]


def test_huge_reference_velocity_is_counted_and_leaves_the_filter_as_without_it(ros):
    fuzz = flt.FilterFuzz(ros)
    try:
        clean = flt.skeleton(T0, 1, fuzz.ref_topics)
        k = _ref_index(clean, 4)
        without = clean[:k] + clean[k + 1:]
        fuzz.run(without)
        want = _by_stamp(fuzz.states, "x")
        for value in (1e200, -1.7976931348623157e308):
            bad = [dict(m) for m in clean]
            bad[k]["twist.twist.linear.x"] = value  # beta2 overflows on channel x
            fuzz.run(bad)  # (run checks: no exception, finite outputs, every input counted)
            assert _channel(fuzz, "x")["dropped_core_error"] == "1"
            assert _channel(fuzz, "y").get("dropped_core_error", "0") == "0"
            got = _by_stamp(fuzz.states, "x")
            assert len(got) == len(want) == 8  # 9 references, one refused on x
            for key, m in want.items():  # the refused sample left no trace
                np.testing.assert_array_equal(got[key].x, m.x)
                np.testing.assert_array_equal(got[key].p, m.p)
    finally:
        fuzz.close()


def test_huge_row_of_a_redundant_reference_is_counted_not_fatal(ros):
    fuzz = flt.FilterFuzz(ros, ref_topics=("/gnss/velocity", "/doppler/velocity"))
    try:
        msgs = flt.skeleton(T0, 754, fuzz.ref_topics)
        for value in (2.1717702631989981e276, 1e154):
            bad = [dict(m) for m in msgs]
            bad[_ref_index(bad, 6)]["twist.twist.linear.x"] = value
            fuzz.run(bad)
            assert fuzz.total_states > 0
        assert int(_channel(fuzz, "x").get("dropped_core_error", 0)) <= 1
    finally:
        fuzz.close()


def test_a_flight_before_1970_is_filtered_with_negative_stamps(ros):
    fuzz = flt.FilterFuzz(ros)
    try:
        fuzz.run(flt.skeleton(-100 * fz.NS, 0, fuzz.ref_topics))
    finally:
        fuzz.close()
    x = [m for m in fuzz.states if m.channel == "x"]
    assert len(x) == 9 and x[0].header.stamp.sec == -100
    assert x[0].header.stamp.nanosec == 4_000_000  # -99.996 s
    assert "dropped_ins_invalid_stamp" not in _inputs(fuzz)


def test_stamps_after_the_last_representable_time_are_dropped_and_counted(ros):
    fuzz = flt.FilterFuzz(ros)
    try:
        msgs = flt.skeleton((2**31 - 1) * fz.NS, 0, fuzz.ref_topics)
        late = [dict(m) for m in msgs]
        for m in late[-12:]:  # the last 0.2 s: sec stays 2^31 - 1, nanosec >= 1e9
            m["header.stamp.sec"] = 2**31 - 1
            m["header.stamp.nanosec"] = fz.NS + m["header.stamp.nanosec"]
        fuzz.run(late)
    finally:
        fuzz.close()
    inputs = _inputs(fuzz)
    n_ins = sum(1 for m in late[-12:] if m["topic"] == flt.INS_TOPIC)
    assert inputs["dropped_ins_invalid_stamp"] == str(n_ins)
    assert inputs["dropped_reference_invalid_stamp"] == str(12 - n_ins)
    assert all(0 <= m.header.stamp.sec <= 2**31 - 1 for m in fuzz.states)


def test_attitude_update_refused_after_the_prediction_leaves_no_trace(ros):
    """Angle-only update (rate NaN on x) with a huge angle: the next state must equal that of
    the stream without the sample (before the fix the interval was predicted twice)."""
    clean = att.skeleton(T0, 3)
    angles = [i for i, m in enumerate(clean) if m["topic"] == att.TOPICS["angle"]]
    rates = [i for i, m in enumerate(clean) if m["topic"] == att.TOPICS["rate"]]
    bad = [dict(m) for m in clean]
    bad[rates[8]]["vector.x"] = math.nan       # angle-only update on x ...
    bad[angles[8]]["vector.x"] = 1e200         # ... which the core refuses
    without = [dict(m) for m in clean]
    without[angles[8]]["vector.x"] = math.nan  # the sample skipped on x (counted as non-finite)
    without[rates[8]]["vector.x"] = math.nan
    fuzz = att.AttitudeFuzz(ros)
    try:
        fuzz.run(without)
        want = _by_stamp(fuzz.states, "x")
        fuzz.run(bad)
        got = _by_stamp(fuzz.states, "x")
    finally:
        fuzz.close()
    assert fuzz.values["filter_node: channel x"]["dropped_core_error"] == "1"
    assert len(got) == len(want) > 10 and got.keys() == want.keys()
    for key, m in want.items():
        np.testing.assert_array_equal(got[key].x, m.x)
        np.testing.assert_array_equal(got[key].p, m.p)


def test_voter_drops_values_that_would_overflow_the_window_statistic(ros, tmp_path):
    from flight_fdi.core.voting import PAIRS, QUANTITIES, ThresholdTable, save_table
    from hardening import test_fuzz_voter_node as vot

    entries = {q: {p: ([0.0], [-0.01], [0.01]) for p in PAIRS} for q in QUANTITIES}
    save_table(ThresholdTable(QUANTITIES, vot.WINDOW, 100.0, 0.001, 10.0, entries),
               tmp_path / "t.json")
    rig = vot.VoterRig(ros, tmp_path / "t.json")
    msgs = vot.skeleton(T0, 0)
    huge = 1.7976931348623157e308
    for k in (4, 5):  # IMU1 at ticks 4 and 5
        msgs[3 * k]["angular_velocity.x"] = huge
    msgs[3 * 7 + 1]["linear_acceleration.z"] = -huge / 2  # IMU2, tick 7
    msgs[3 * 12]["angular_velocity.y"] = 1e300             # inside the limit: voted
    try:
        rig.run(msgs)  # (run checks: finite VoteStatus, every input counted)
        inputs = rig.under_test.diag.read(rig.node)["voter_node: inputs"]
    finally:
        rig.close()
    assert inputs["dropped_imu1_out_of_range"] == "2" and inputs["dropped_imu2_out_of_range"] == "1"
    assert inputs["dropped_imu1_nonfinite"] == "0"
    assert inputs["matched_triples"] == str(40 - 3)  # ticks 4, 5, 7 lost one IMU each


# ------------------------------------------------------------------------------ bag reading

def _simulated(tmp_path, storage, compression):
    from flight_fdi.cli.main import main

    path = tmp_path / f"{storage}_{compression}"
    assert main(["simulate", str(path), "--duration", "10", "--ins-rate", "10", "--ref-rate",
                 "2", "--storage", storage, "--compression", compression]) == 0
    return path, next(p for p in path.iterdir() if p.suffix in (".mcap", ".db3"))


def test_sqlite3_record_with_a_blob_receive_time_is_a_bag_error(tmp_path):
    import sqlite3

    from flight_fdi.bagio import BagError, read_flight, read_messages

    bag, db = _simulated(tmp_path, "sqlite3", "none")
    con = sqlite3.connect(db)
    con.execute("UPDATE messages SET timestamp = x'' WHERE id = 5")  # what a damaged page holds
    con.commit()
    con.close()
    with pytest.raises(BagError, match="is corrupt"):
        read_flight(bag)
    with pytest.raises(BagError, match="is corrupt.*not an integer"):
        list(read_messages(bag))


def test_mcap_chunk_with_a_non_utf8_compression_name_is_a_bag_error(tmp_path):
    import struct

    from flight_fdi.bagio import BagError, read_flight

    bag, path = _simulated(tmp_path, "mcap", "zstd")
    blob = bytearray(path.read_bytes())
    pos = 8
    while blob[pos] != 0x06:  # the first chunk record
        pos += 9 + struct.unpack_from("<Q", blob, pos + 1)[0]
    name = pos + 9 + 28  # u64 start, end, uncompressed size, u32 crc, then the string
    assert blob[name:name + 8] == struct.pack("<I", 4) + b"zstd"
    blob[name + 4] = 0xB5  # not UTF-8; the summary (what rosbags opens with) is intact
    path.write_bytes(bytes(blob))
    with pytest.raises(BagError, match="truncated or corrupt"):
        read_flight(bag)
