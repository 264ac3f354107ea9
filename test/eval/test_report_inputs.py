"""The report's inputs part (single-axis model): per topic the role, messages received, used
and dropped by reason, from the result's ``input`` section alone -- for a report of a bag's
RESULT.json and of a ``run`` folder (whose result.json is the record). Before: no inputs part."""
from __future__ import annotations

import json
import shutil

import pytest

from flight_fdi.cli.main import main
from flight_fdi.report.inputs import inputs_part
from report_tables import agrees, table_rows

BAG = "bags/nominal"


def test_inputs_part_words_every_reason_and_says_when_nothing_is_recorded():
    section = {"/ins/velocity": {"role": "ins", "messages": 100, "used": 97,
                                 "dropped": {"non_finite": 2, "zero_stamp": 1,
                                             "duplicate_stamp": 0}, "reordered": 4},
               "/reference/velocity": {"role": "reference", "messages": 20, "used": 20,
                                       "dropped": {"outside_ins_record": 0}},
               "/ref/odd": {"role": "reference", "messages": 5, "used": 2,
                            "dropped": {"some_new_reason": 3}}}
    rows = table_rows(inputs_part(section))
    agrees(rows, section)
    assert rows["/ins/velocity"][3] == ("2 non-finite velocity (dropped); 1 header stamp 0 "
                                        "(dropped); 4 out of header-stamp order (sorted, kept)")
    assert rows["/reference/velocity"][3] == "none"
    assert rows["/ref/odd"][3] == "3 some new reason"       # a reason without words: its name
    for missing in (None, {}):
        assert "records no input section" in inputs_part(missing)


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_report_of_a_run_folder_and_of_its_result_json(tmp_path, capfd):
    run = tmp_path / "run"
    assert main(["run", BAG, "--out", str(run), "--no-progress", "--json"]) == 0
    capfd.readouterr()
    doc = json.loads((run / "result.json").read_text())
    assert doc["input"]["/ins/velocity"]["messages"] == 50000
    # the run's own report and the report of the run folder: the run's record
    agrees(table_rows((run / "report" / "index.html").read_text()), doc["input"])
    original = json.loads(json.dumps(doc["input"]))
    # the record is what is shown: a drop written into result.json appears (not re-read)
    doc["input"]["/reference/velocity"]["dropped"]["ins_gap"] = 7
    (run / "result.json").write_text(json.dumps(doc))
    assert main(["report", str(run), "--out", str(tmp_path / "rep_run")]) == 0
    rows = table_rows((tmp_path / "rep_run" / "index.html").read_text())
    agrees(rows, doc["input"])
    assert rows["/reference/velocity"][3] == "7 in an INS gap longer than max_gap_s (not used)"
    summary = json.loads((tmp_path / "rep_run" / "summary.json").read_text())
    assert summary["input"] == doc["input"]
    # a RESULT.json alone (no recording beside it): the bag it names analysed again, and the
    # page shows the input of that analysis's result
    res_json = tmp_path / "result_copy.json"
    shutil.copy(run / "result.json", res_json)
    assert main(["report", str(res_json), "--out", str(tmp_path / "rep_json")]) == 0
    summary = json.loads((tmp_path / "rep_json" / "summary.json").read_text())
    agrees(table_rows((tmp_path / "rep_json" / "index.html").read_text()), summary["input"])
    assert summary["input"] == original           # the bag's, as the run received it
