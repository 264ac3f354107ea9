"""Monte Carlo resume from the --records file: an interrupted study, run again, runs only the
flights it lacks and gives exactly the records and metrics of an uninterrupted run (in this
process and on 2 Dask workers); the records file's header, a cut last line, another study's file."""
from __future__ import annotations

import json
from functools import partial

import pytest

from flight_fdi.cli.main import main
from flight_fdi.eval.errors import EvalError
from flight_fdi.eval.montecarlo import StudyConfig, run_study
from flight_fdi.eval.records import FORMAT, RecordsFile

from resume_helpers import interrupted_file as interrupted
from resume_helpers import lines

STUDY = StudyConfig(nominal=3, per_fault=3, accel_levels_mg=(2.0, 10.0),
                    gyro_levels_deg_h=(5.0, 30.0), duration_s=120.0, seed=11)
CLI = ["montecarlo", "--nominal", "3", "--per-fault", "3", "--accel-levels", "2,10",
       "--gyro-levels", "5,30", "--duration", "120", "--seed", "11", "--no-progress"]


@pytest.fixture(scope="module")
def uninterrupted():
    return run_study(STUDY, jobs=1)


def interrupted_file(path, after: int) -> list[int]:
    return interrupted(path, STUDY.describe(), partial(run_study, STUDY, jobs=1), after)


def test_cli_resume_runs_only_the_missing_flights_and_equals_an_uninterrupted_run(
        tmp_path, capsys, uninterrupted):
    path = tmp_path / "study.jsonl"
    first = interrupted_file(path, 4)
    # the study was cut while a record was being written: half a line at the end
    with path.open("a") as f:
        f.write('{"index": 5, "kind": "acc')
    out = tmp_path / "study.json"
    assert main(CLI + ["--jobs", "1", "--records", str(path), "--out", str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["resumed"] == 4
    assert doc["metrics"] == uninterrupted.metrics
    assert json.loads(out.read_text())["flights"] == uninterrupted.records
    header, *recs = lines(path)  # the cut line is gone, each flight once
    assert header == {"records": FORMAT, "study": json.loads(json.dumps(STUDY.describe()))}
    assert [r["index"] for r in recs[:4]] == first
    assert sorted(r["index"] for r in recs) == list(range(9))
    assert sorted(recs, key=lambda r: r["index"]) == uninterrupted.records
    # a third run has nothing left to do
    assert main(CLI + ["--jobs", "1", "--records", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["resumed"] == 9
    assert len(lines(path)) == 10


def test_resume_on_two_workers_equals_an_uninterrupted_run(tmp_path, dask_cluster,
                                                           uninterrupted):
    path = tmp_path / "study.jsonl"
    interrupted_file(path, 3)
    with RecordsFile(path, STUDY.describe()) as rec:
        assert sorted(rec.done) == [0, 1, 2]
        res = run_study(STUDY, on_record=rec.write, done=rec.done, scheduler=dask_cluster)
    assert res.jobs == 2 and res.resumed == 3
    assert res.records == uninterrupted.records and res.metrics == uninterrupted.metrics
    assert sorted(r["index"] for r in lines(path)[1:]) == list(range(9))


def test_a_records_file_of_another_study_is_refused_and_kept(tmp_path, capsys):
    path = tmp_path / "study.jsonl"
    with RecordsFile(path, STUDY.describe()) as rec:
        rec.write({"index": 0, "kind": "nominal"})
    before = path.read_text()
    other = CLI[:-3] + ["--seed", "12", "--no-progress", "--jobs", "1"]
    assert main(other + ["--records", str(path)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "another study (differs in seed)" in err
    assert path.read_text() == before  # nothing lost
    path.write_text('{"index": 0}\n')  # records without a header (an earlier version)
    with pytest.raises(EvalError, match="not a study records file"):
        RecordsFile(path, STUDY.describe()).open()
    path.write_text(before + "not json\n" + '{"index": 1}\n')  # damaged in the middle
    with pytest.raises(EvalError, match="line 3 .* is not JSON"):
        RecordsFile(path, STUDY.describe()).open()


def test_restart_starts_the_file_anew_and_foreign_records_are_refused(tmp_path):
    path = tmp_path / "study.jsonl"
    with RecordsFile(path, {"seed": 1}) as rec:
        rec.write({"index": 0, "kind": "nominal", "sim_seed": 5})
    with RecordsFile(path, {"seed": 2}, restart=True) as rec:
        assert rec.done == {}
    assert lines(path) == [{"records": FORMAT, "study": {"seed": 2}}]
    # a record whose flight is not the study's (another plan): an error, not a wrong result
    with pytest.raises(EvalError, match="recorded flight 0 is not a flight of this study"):
        run_study(STUDY, done={0: {"index": 0, "kind": "nominal", "sim_seed": 5}})
