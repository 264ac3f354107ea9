"""The 3-D report's inputs part: per contract topic the role, messages received, used and
dropped by reason (``input_section3d``), from the result alone -- for a report of a bundled
bag's RESULT.json and of a ``run --model ins3d`` folder (its result.json the record). Before:
no inputs part."""
from __future__ import annotations

import json
import shutil

import pytest

from flight_fdi.cli.main import main
from report_tables import agrees, table_rows

BAG = "bags/ins3d_accel_y_step"


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_report_of_a_bundled_bags_result_json(tmp_path, capsys):
    assert main(["analyze", BAG, "--model", "ins3d", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    section = res["input"]
    assert set(e["role"] for e in section.values()) == {"ins_velocity", "ins_imu", "ins_fix",
                                                        "ref_velocity"}
    (tmp_path / "res.json").write_text(json.dumps(res))
    assert main(["report", str(tmp_path / "res.json"), "--out", str(tmp_path / "rep")]) == 0
    rows = table_rows((tmp_path / "rep" / "index.html").read_text())
    agrees(rows, section)
    # the simulator's first reference (at 0 s) is before the first IMU message: one dropped,
    # in the text output's words
    assert section["/reference/velocity"]["dropped"] == {"outside_imu_record": 1}
    assert rows["/reference/velocity"][3] == "1 outside the IMU record (no step for it; not used)"
    assert rows["/ins/imu"][3] == "none"


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_report_of_a_run_folder_shows_the_runs_record(run3d, tmp_path, capfd):
    """(``run3d``: ``run BAG --model ins3d --json --fail-on-fault``, conftest.py, copied: this
    test changes its result.json)"""
    out = tmp_path / "run"
    shutil.copytree(run3d.folder, out)
    doc = json.loads(run3d.stdout)
    assert run3d.rc == (3 if doc["post_flight"]["verdict"] != "no_fault" else 0)
    agrees(table_rows((out / "report" / "index.html").read_text()), doc["input"])
    # the record is what is shown: a drop written into result.json appears
    doc["input"]["/ins/imu"]["dropped"] = {"late": 2}
    (out / "result.json").write_text(json.dumps(doc))
    assert main(["report", str(out), "--out", str(tmp_path / "rep")]) == 0
    rows = table_rows((tmp_path / "rep" / "index.html").read_text())
    agrees(rows, doc["input"])
    assert rows["/ins/imu"][3].startswith("2 came after its step was taken")
    assert json.loads((tmp_path / "rep" / "summary.json").read_text())["input"] == doc["input"]
