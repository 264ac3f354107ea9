"""The ``input`` section of ``flight-fdi run --model ins3d`` (the node pipeline's count of what its
filter received and dropped, ``nodes.ins3d_pipeline.input_section_of_run``) is that of
``analyze --model ins3d`` on the same bag, and the 3-D text table warns of every dropped input as
the single-axis table does (``bagio.inputs.warnings``, one copy)."""
from __future__ import annotations

import json
from types import SimpleNamespace

import pytest

from flight_fdi.cli.main import main
from flight_fdi.schema import validate_result

REF = "/reference/velocity"
WARN_OUTSIDE = (f"warning: {REF}: 1 of 301 messages: outside the IMU record (no step for it; "
                "not used)")


@pytest.fixture(scope="module")
def short3d(tmp_path_factory):
    """A 30-s 3-D flight (test/campaign/test_dropped3d.py): 600 IMU messages from 0.05 s, 301
    references from 0 s -- the first one is outside the IMU record."""
    path = tmp_path_factory.mktemp("input3d") / "flight"
    assert main(["simulate", str(path), "--model", "ins3d", "--duration", "30", "--seed",
                 "3"]) == 0
    return path


def test_analyze_text_warns_of_the_dropped_reference(short3d, capfd):
    assert main(["analyze", str(short3d), "--model", "ins3d"]) == 0
    lines = capfd.readouterr().out.splitlines()
    assert lines.count(WARN_OUTSIDE) == 1
    # after the input lines, before the in-flight summary (as in the single-axis table)
    assert lines.index(WARN_OUTSIDE) < next(i for i, s in enumerate(lines)
                                            if s.startswith("in flight:"))
    assert sum(s.startswith("warning:") for s in lines) == 1   # nothing else was dropped


@pytest.mark.timeout(300)
def test_run_has_the_input_section_of_analyze_and_warns(short3d, tmp_path, capfd):
    assert main(["analyze", str(short3d), "--model", "ins3d", "--json"]) == 0
    ref = json.loads(capfd.readouterr().out)
    out = tmp_path / "run"
    assert main(["run", str(short3d), "--model", "ins3d", "--out", str(out), "--no-report",
                 "--no-progress"]) == 0
    text = capfd.readouterr().out.splitlines()
    res = json.loads((out / "result.json").read_text())
    validate_result(res)
    assert res["input"] == ref["input"]
    assert res["input"][REF]["dropped"] == {"outside_imu_record": 1}
    assert res["input"][REF]["used"] == res["samples"] == ref["samples"] == 300
    assert text.count(WARN_OUTSIDE) == 1


def _mode(counters: dict, outside: int, late: int, received: dict):
    names = {"ins_velocity": "/ins/velocity", "ins_imu": "/ins/imu", "ins_fix": "/ins/fix",
             "ref_velocity": REF}
    resolved = {k: "/ns" + v for k, v in names.items()}   # the node's resolved names
    return names, SimpleNamespace(
        counters=SimpleNamespace(items=lambda: list(counters.items())),
        asm=SimpleNamespace(outside=outside, late=late), names=resolved,
        inputs=SimpleNamespace(count=lambda n: received[n[3:]]))


def test_the_run_section_counts_every_drop_of_the_filter():
    """Drops only the node's filter makes (late references, non-finite values, ...) are in the
    run's section, by topic and reason, and its ``used`` is what is left; the table warns of
    each in words."""
    from flight_fdi.bagio.ins3d_input import DROP_REASONS3D
    from flight_fdi.bagio.inputs import DROP_REASONS
    from flight_fdi.cli.ins3d import format_result
    from flight_fdi.nodes.ins3d_pipeline import input_section_of_run

    counters = {"received_ins": 1400, "dropped_ins_imu_non_finite": 2,
                "dropped_ins_velocity_out_of_order": 0, "dropped_ins_fix_duplicate_stamp": 1,
                "dropped_ref_velocity_invalid_covariance": 3, "dropped_ins_imu_core_error": 1}
    received = {"/ins/imu": 600, "/ins/velocity": 600, "/ins/fix": 150, REF: 301}
    names, mode = _mode(counters, outside=2, late=4, received=received)
    section = input_section_of_run(mode, names)
    assert section["/ins/imu"]["dropped"] == {"non_finite": 2, "core_error": 1}
    assert section["/ins/imu"]["used"] == 597
    assert section["/ins/velocity"]["dropped"] == {} and section["/ins/velocity"]["used"] == 600
    assert section["/ins/fix"]["dropped"] == {"duplicate_stamp": 1}
    assert section[REF]["dropped"] == {"invalid_covariance": 3, "outside_imu_record": 2,
                                       "late": 4}
    assert section[REF]["used"] == 301 - 9 and section[REF]["type"].endswith("CovarianceStamped")
    reasons = {k for e in section.values() for k in e["dropped"]}
    assert reasons <= {*DROP_REASONS, *DROP_REASONS3D}
    res = json.loads(json.dumps({"input": section}))
    lines = [s for s in format_result(_result3d(res)).splitlines() if s.startswith("warning:")]
    assert lines == [
        "warning: /ins/imu: 2 of 600 messages: non-finite value (dropped)",
        "warning: /ins/imu: 1 of 600 messages: refused by the filter (dropped)",
        "warning: /ins/fix: 1 of 150 messages: repeated header stamp (dropped; the first kept)",
        f"warning: {REF}: 3 of 301 messages: a variance not > 0 (dropped)",
        f"warning: {REF}: 2 of 301 messages: outside the IMU record (no step for it; not used)",
        f"warning: {REF}: 4 of 301 messages: came after its step was taken (waited longer "
        "than ins3d_wait_s; not used)"]
    # no reference left out: the section still says so (0, as analyze), no warning
    names, mode = _mode({}, outside=0, late=0, received=received)
    section = input_section_of_run(mode, names)
    assert section[REF]["dropped"] == {"outside_imu_record": 0}
    assert not [s for s in format_result(_result3d({"input": section})).splitlines()
                if s.startswith("warning:")]


def test_the_single_axis_words_stay_and_an_unknown_reason_is_named():
    from flight_fdi.bagio.inputs import warnings

    section = {"/a": {"messages": 5, "dropped": {"out_of_order": 1, "something_new": 2},
                      "reordered": 1}}
    assert warnings(section) == [
        "warning: /a: 1 of 5 messages: header stamp older than the reorder window (dropped; a "
        "clock jumping back? raise reorder_window_s to sort them)",
        "warning: /a: 2 of 5 messages: something new",
        "warning: /a: 1 messages arrived out of header-stamp order and were sorted by header "
        "stamp"]


def _result3d(extra: dict) -> dict:
    """The least of a 3-D result that ``format_result`` prints."""
    return {"post_flight": {"verdict": "no_fault", "headline": "no fault", "fault": None,
                            "candidates": [], "glr": None, "seed_method": None},
            "in_flight": {"gate_threshold": 16.3, "exceed_fraction": 0.0, "alarms": [],
                          "first_alarm_s": None},
            "ins3d": {"grade": "navigation", "states": ["a"], "beta2_row_mean": {"east": 1.0},
                      "beta2_mean": 1.0, "manoeuvres": []},
            "bag": "b", "channel": "enu", "duration_s": 30.0, "samples": 300, **extra}
