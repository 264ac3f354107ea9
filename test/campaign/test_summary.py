"""The summary row reads both forms of the result JSON: the one before the schema (stored
outputs of ``flight-fdi analyze --json`` of that version, test/campaign/data/) and the
schema-versioned one with post_flight.fault and per-topic drop counts (made here by today's
analyze)."""
from __future__ import annotations

import argparse
import copy
import json
import pathlib

import pytest

from flight_fdi.campaign.summary import COLUMNS, summary_row
from flight_fdi.cli.analyze import add_analysis_options, analyze_bag

DATA = pathlib.Path(__file__).resolve().parent / "data"


def analyze_args(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_analysis_options(p)
    args = p.parse_args(list(argv))
    args.jobs = 1
    return args


@pytest.fixture(scope="module")
def results(short_bags) -> dict[str, dict]:
    return {k: analyze_bag(str(b), analyze_args()) for k, b in short_bags.items()}


def before_schema(name: str) -> dict:
    return json.loads((DATA / f"result_before_schema_{name}.json").read_text())


def test_result_before_the_schema_gives_sensor_axis_kind_unit():
    doc = before_schema("accel")
    assert "schema" not in doc and "fault" not in doc["post_flight"]
    accel = summary_row("a", doc)
    assert list(accel) == list(COLUMNS)
    assert (accel["verdict"], accel["sensor"], accel["axis"], accel["kind"], accel["unit"]) == \
        ("failure", "accelerometer", "x", "step", "m/s^2")
    post = doc["post_flight"]
    assert accel["onset_s"] == post["onset_s"] and accel["magnitude"] == post["magnitude"]
    assert accel["magnitude"] == pytest.approx(0.015, rel=0.1)
    assert accel["duration_s"] == doc["duration_s"]
    assert accel["dropped_samples"] == doc["input"]["dropped_unaligned"] == 0
    assert accel["confidence"] is None  # that form has no runner-up
    nominal = summary_row("n", before_schema("nominal"))
    assert nominal["verdict"] == "no_fault"
    assert nominal["sensor"] is None and nominal["magnitude"] is None and nominal["error"] is None
    doc["input"]["dropped_unaligned"] = 7
    assert summary_row("a", doc)["dropped_samples"] == 7


def test_schema_result_of_todays_analyze(results):
    doc = results["accel"]
    fault = doc["post_flight"]["fault"]
    assert "schema" in doc and fault is not None
    row = summary_row("accel", doc)
    assert (row["verdict"], row["sensor"], row["axis"], row["kind"], row["unit"]) == \
        ("failure", "accelerometer", "x", "step", "m/s^2")
    assert row["onset_s"] == fault["onset_s"] == pytest.approx(100.0, abs=2.0)
    assert row["magnitude"] == fault["magnitude"] == pytest.approx(0.015, rel=0.1)
    assert row["confidence"] == pytest.approx(
        1 - fault["runner_up"]["statistic"] / fault["statistic"])
    assert 0 < row["confidence"] <= 1
    assert row["dropped_samples"] == sum(n for t in doc["input"].values()
                                         if isinstance(t, dict) and "dropped" in t
                                         for n in t["dropped"].values()) == 0
    nominal = summary_row("n", results["nominal"])
    assert results["nominal"]["post_flight"]["fault"] is None
    assert nominal["verdict"] == "no_fault" and nominal["sensor"] is None
    assert nominal["confidence"] is None and nominal["dropped_samples"] == 0


def test_schema_result_ambiguous_names_every_candidate(results):
    # one velocity channel cannot tell a gyro drift step from an accelerometer bias ramp
    doc = results["gyro"]
    post = doc["post_flight"]
    assert post["verdict"] == "ambiguous" and post["fault"] is None
    row = summary_row("gyro", doc)
    sensors = [c["sensor"] for c in post["candidates"]]
    assert set(row["sensor"].split("|")) == set(sensors) and "gyro" in sensors
    assert row["axis"] == "x" and row["magnitude"] is None and row["unit"] is None
    assert row["onset_s"] == post["candidates"][0]["onset_s"]
    assert row["confidence"] == pytest.approx(0.0, abs=1e-6)  # a tie, said as such


def with_fault_and_drops(base: dict, fault: dict | None) -> dict:
    """``base`` with another fault and drops on two topics."""
    doc = copy.deepcopy(base)
    doc["post_flight"]["fault"] = fault
    doc["input"] = {
        "/ins/velocity": {"messages": 10000, "dropped": {"non_finite": 3, "duplicate_stamp": 2}},
        "/reference/velocity": {"messages": 2000,
                                "dropped": {"outside_ins_record": 1, "out_of_order": 0}},
    }
    return doc


def test_schema_form_reads_every_field_from_the_fault(results):
    fault = {"sensor": "gyro", "axis": "y", "kind": "ramp", "onset_s": 301.5, "end_s": None,
             "magnitude": 2.5e-8, "unit": "rad/s^2", "statistic": 400.0, "threshold": 28.75,
             "runner_up": {"hypothesis": "accel_bias_ramp", "statistic": 100.0}}
    # the base says accelerometer step on x: every field must come from 'fault'
    row = summary_row("f", with_fault_and_drops(results["accel"], fault))
    assert (row["sensor"], row["axis"], row["kind"], row["onset_s"], row["magnitude"],
            row["unit"]) == ("gyro", "y", "ramp", 301.5, 2.5e-8, "rad/s^2")
    assert row["confidence"] == pytest.approx(0.75)   # 1 - 100/400
    assert row["dropped_samples"] == 6
    tie = dict(fault, runner_up={"hypothesis": "accel_bias_step", "statistic": 400.0})
    assert summary_row("t", with_fault_and_drops(results["accel"], tie))["confidence"] == 0.0
    tie["confidence"] = 0.42  # a result's own confidence wins
    assert summary_row("t", with_fault_and_drops(results["accel"], tie))["confidence"] == 0.42


def test_error_row_has_only_name_bag_and_error():
    row = summary_row("bad", None, error="bag 'x' cannot be opened", bag="/data/x")
    assert row["error"] == "bag 'x' cannot be opened" and row["bag"] == "/data/x"
    assert all(row[c] is None for c in COLUMNS if c not in ("flight", "bag", "error"))
