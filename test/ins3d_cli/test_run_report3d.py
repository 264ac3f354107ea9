"""``flight-fdi run BAG --model ins3d`` (the node pipeline: filter in ins3d mode -> recorder ->
smoother) gives the result of ``analyze --model ins3d``; ``report --model ins3d`` draws the
per-axis figures from a bag or a run folder."""
from __future__ import annotations

import json

import pytest

from flight_fdi.cli.main import main
from flight_fdi.schema import validate_result


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_run_equals_analyze_and_reports(bag3d, run3d, tmp_path, capfd):
    """(``run3d``: ``run BAG --model ins3d --json --fail-on-fault``, conftest.py)"""
    out, rc = run3d.folder, run3d.rc
    assert main(["analyze", str(bag3d), "--model", "ins3d", "--json"]) == 0
    ref = json.loads(capfd.readouterr().out)
    res = json.loads(run3d.stdout)
    validate_result(res)
    assert rc == (3 if res["post_flight"]["verdict"] != "no_fault" else 0)
    # the smoother analysed the recorded inputs: the same numbers as analyze on the bag
    assert res["post_flight"] == ref["post_flight"]
    assert res["in_flight"] == ref["in_flight"] and res["ins3d"] == ref["ins3d"]
    assert res["samples"] == ref["samples"] and res["source"] == ref["source"]
    assert json.loads((out / "result.json").read_text()) == res
    index = out / "report" / "index.html"
    assert index.exists() and "Rebuilt from the recording" in index.read_text()
    for f in ("axis_x.png", "axis_y.png", "axis_z.png", "gate.png"):
        assert (out / "report" / f).stat().st_size > 10000
    # report of the run folder without --model: recognised from result.json
    assert main(["report", str(out), "--out", str(tmp_path / "rep2")]) == 0
    assert "report in" in capfd.readouterr().out


def test_report_from_the_bag_draws_the_truth(bag3d, tmp_path, capfd):
    rep = tmp_path / "rep"
    assert main(["report", str(bag3d), "--model", "ins3d", "--out", str(rep), "--json"]) == 0
    doc = json.loads(capfd.readouterr().out)
    validate_result(doc["summary"])
    page = (rep / "index.html").read_text()
    assert "no /sim/truth" not in page and "Observability" in page
    assert json.loads((rep / "summary.json").read_text())["model"] == "ins3d"


def test_run_refuses_bad_input_before_any_node(tmp_path, capfd):
    assert main(["run", "bags/nominal", "--model", "ins3d", "--out", str(tmp_path / "o")]) == 1
    err = capfd.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "single-axis bag?" in err[0]
    assert not (tmp_path / "o").exists()
