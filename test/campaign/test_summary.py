"""The summary row reads both forms of the result JSON (today's and the schema-versioned one
with post_flight.fault and per-topic drop counts)."""
from __future__ import annotations

import argparse
import copy

import pytest

from flight_fdi.campaign.summary import COLUMNS, summary_row
from flight_fdi.cli.analyze import add_analysis_options, analyze_bag


def analyze_args(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_analysis_options(p)
    args = p.parse_args(list(argv))
    args.jobs = 1
    return args


@pytest.fixture(scope="module")
def results(short_bags) -> dict[str, dict]:
    return {k: analyze_bag(str(b), analyze_args()) for k, b in short_bags.items()}


def test_todays_result_gives_sensor_axis_kind_unit(results):
    accel = summary_row("a", results["accel"])
    assert list(accel) == list(COLUMNS)
    assert (accel["verdict"], accel["sensor"], accel["axis"], accel["kind"], accel["unit"]) == \
        ("failure", "accelerometer", "x", "step", "m/s^2")
    post = results["accel"]["post_flight"]
    assert accel["onset_s"] == post["onset_s"] and accel["magnitude"] == post["magnitude"]
    assert accel["magnitude"] == pytest.approx(0.015, rel=0.1)
    assert accel["duration_s"] == results["accel"]["duration_s"]
    assert accel["dropped_samples"] == results["accel"]["input"]["dropped_unaligned"] == 0
    assert accel["confidence"] is None  # today's result has no runner-up
    gyro = summary_row("g", results["gyro"])
    assert (gyro["sensor"], gyro["kind"], gyro["unit"]) == ("gyro", "step", "rad/s")
    nominal = summary_row("n", results["nominal"])
    assert nominal["verdict"] == "no_fault"
    assert nominal["sensor"] is None and nominal["magnitude"] is None and nominal["error"] is None


def test_dropped_unaligned_is_counted(results):
    doc = copy.deepcopy(results["nominal"])
    doc["input"]["dropped_unaligned"] = 7
    assert summary_row("n", doc)["dropped_samples"] == 7


def new_form(base: dict, fault: dict | None) -> dict:
    """``base`` turned into the schema-versioned result (issue 11's fields)."""
    doc = copy.deepcopy(base)
    doc["schema"] = "flight_fdi/result-v1"
    doc["post_flight"]["fault"] = fault
    doc["input"] = {
        "/ins/velocity": {"messages": 10000, "dropped": {"non_finite": 3, "duplicate_stamp": 2}},
        "/reference/velocity": {"messages": 2000,
                                "dropped": {"outside_ins_record": 1, "out_of_order": 0}},
    }
    return doc


def test_new_form_reads_the_fault_and_sums_drops_over_topics_and_reasons(results):
    fault = {"sensor": "gyro", "axis": "y", "kind": "ramp", "onset_s": 301.5, "end_s": None,
             "magnitude": 2.5e-8, "unit": "rad/s^2", "statistic": 400.0, "threshold": 28.75,
             "runner_up": {"hypothesis": "accel_bias_ramp", "statistic": 100.0}}
    # the base says accelerometer step on x: every field must come from the new 'fault'
    row = summary_row("f", new_form(results["accel"], fault))
    assert (row["sensor"], row["axis"], row["kind"], row["onset_s"], row["magnitude"],
            row["unit"]) == ("gyro", "y", "ramp", 301.5, 2.5e-8, "rad/s^2")
    assert row["confidence"] == pytest.approx(0.75)   # 1 - 100/400
    assert row["dropped_samples"] == 6
    assert row["verdict"] == "failure"


def test_new_form_without_fault_and_with_own_confidence(results):
    row = summary_row("n", new_form(results["nominal"], None))
    assert row["sensor"] is None and row["kind"] is None and row["confidence"] is None
    assert row["dropped_samples"] == 6
    tie = {"sensor": "reference", "axis": "x", "kind": "jump", "onset_s": 10.0, "end_s": 10.0,
           "magnitude": 0.5, "unit": "m/s", "statistic": 50.0, "threshold": 28.75,
           "runner_up": {"hypothesis": "accel_bias_step", "statistic": 50.0}}
    assert summary_row("t", new_form(results["nominal"], tie))["confidence"] == 0.0
    tie["confidence"] = 0.42
    assert summary_row("t", new_form(results["nominal"], tie))["confidence"] == 0.42


def test_error_row_has_only_name_bag_and_error():
    row = summary_row("bad", None, error="bag 'x' cannot be opened", bag="/data/x")
    assert row["error"] == "bag 'x' cannot be opened" and row["bag"] == "/data/x"
    assert all(row[c] is None for c in COLUMNS if c not in ("flight", "bag", "error"))
