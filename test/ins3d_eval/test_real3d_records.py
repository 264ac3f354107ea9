"""The real-data records (``real3d.record``, tools/ins3d_real_eval.py) say whether the run was
relinearised (``post_flight.relinearization``) and whether the model stayed valid
(``post_flight.model_validity``), consistently with the result; the tool's markdown counts
them. Before: neither was in a record."""
from __future__ import annotations

import json
import math
import sys

import pytest

from flight_fdi.eval import real3d as R
from repo_scripts import load_script

from .conftest import EXCERPT


def consistent(out: dict, analysis) -> None:
    pf = analysis.post_flight_dict()
    rel, val = pf["relinearization"], pf["model_validity"]
    assert out["relinearisation_tried"] is (rel is not None)
    assert out["relinearised"] is (rel is not None and rel["passes"] > 0)
    assert out["relinearisation_passes"] == (rel["passes"] if rel else 0)
    assert out["model_valid"] is val["valid"]
    assert out["attitude_error_max_deg"] == val["attitude_error_max_deg"]
    json.dumps(out, allow_nan=False)                # a records line


@pytest.mark.timeout(300)
def test_records_say_relinearised_and_valid_as_the_result(rec, cal):
    nominal = R.analyze(rec, *cal)
    out = R.record(nominal)
    consistent(out, nominal)
    # the calibrated unit, no fault: small angles, never relinearised, the model valid
    assert out["relinearised"] is False and out["relinearisation_passes"] == 0
    assert out["relinearisation_tried"] is False
    assert out["model_valid"] is True and 0 < out["attitude_error_max_deg"] < 5
    # a 20 deg/s gyro z step at 3 s: the smoothed attitude leaves small angles (measured 16
    # deg), passes about it are kept (2) and leave the model valid (1 deg)
    big = R.analyze(R.Fault("gyro", "z", math.radians(20.0), 3.0).apply(rec), *cal)
    out = R.record(big)
    consistent(out, big)
    assert out["relinearised"] is True and out["relinearisation_passes"] >= 1
    assert out["relinearisation_tried"] is True
    assert big.relinearization.passes == out["relinearisation_passes"]
    assert out["model_valid"] is True


def _tool():
    return load_script("tools/ins3d_real_eval.py")


def test_validity_line_counts_the_records():
    line = _tool().validity_line([
        {"relinearised": True, "relinearisation_passes": 2, "model_valid": True,
         "attitude_error_max_deg": 7.5},
        {"relinearised": False, "relinearisation_passes": 0, "model_valid": False,
         "attitude_error_max_deg": 20.25},
        {"relinearised": False, "relinearisation_passes": 0, "model_valid": None,
         "attitude_error_max_deg": None}])
    assert line == ("Relinearised: 1 of 3 runs (2 passes kept); model valid (smoothed attitude "
                    "error within the small-angle limit): 1 of 3, largest attitude error "
                    "20.25 deg.")


@pytest.mark.timeout(300)
def test_tool_markdown_and_records_file(tmp_path, monkeypatch):
    # a one-recording data set: the excerpt as straight/path_2 (no other recording of its day:
    # no calibration, the raw unit)
    data = tmp_path / "mimu"
    (data / "straight").mkdir(parents=True)
    (data / "straight" / "path_2").symlink_to(EXCERPT.resolve(), target_is_directory=True)
    md, records = tmp_path / "out.md", tmp_path / "records.jsonl"
    monkeypatch.setattr(sys, "path", list(sys.path))        # the tool inserts the repo root
    assert _tool().main(["--data", str(data), "--units", "1", "--settings", "d",
                         "--no-faults", "--out", str(md), "--records", str(records)]) == 0
    lines = [json.loads(x) for x in records.read_text().splitlines()]
    assert len(lines) == 1
    r = lines[0]["record"]
    for key in ("relinearised", "relinearisation_passes", "model_valid",
                "attitude_error_max_deg"):
        assert key in r
    text = md.read_text()
    expect = (f"Relinearised: {int(r['relinearised'])} of 1 runs "
              f"({r['relinearisation_passes']} passes kept); model valid (smoothed attitude "
              f"error within the small-angle limit): {int(r['model_valid'] is True)} of 1, "
              f"largest attitude error {r['attitude_error_max_deg']:.2f} deg.")
    assert expect in text.splitlines()
