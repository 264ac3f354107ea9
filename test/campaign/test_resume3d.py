"""The 3-D study (``montecarlo --model ins3d``) streams its records and resumes from them exactly
like the single-axis one (same records module): an interrupted study, run again, runs only the
flights it lacks and gives the records and metrics of an uninterrupted run -- in this process and
on 2 Dask workers; another study's file (the single-axis study's too) is refused and kept;
--restart starts anew. Short flights (60 s, about a second each)."""
from __future__ import annotations

import json
from functools import partial

import pytest

from flight_fdi.cli.main import main
from flight_fdi.eval.errors import EvalError
from flight_fdi.eval.montecarlo3d import Study3DConfig, run_study, study_settings
from flight_fdi.eval.records import FORMAT, RecordsFile

from resume_helpers import interrupted_file as interrupted
from resume_helpers import lines

STUDY = Study3DConfig(nominal=2, per_scenario=1, scenarios=("gyro_step", "accel_step",
                                                            "ref_jump"),
                      duration_s=60.0, profile="cruise_turns", seed=4, single_axis=False)
CLI = ["montecarlo", "--model", "ins3d", "--nominal", "2", "--per-fault", "1",
       "--scenarios", "gyro_step,accel_step,ref_jump", "--duration", "60",
       "--profile", "cruise_turns", "--seed", "4", "--no-single-axis", "--no-progress"]
N = 5


@pytest.fixture(scope="module")
def uninterrupted():
    return run_study(STUDY, jobs=1)


def interrupted_file(path, after: int) -> list[int]:
    return interrupted(path, study_settings(STUDY), partial(run_study, STUDY, jobs=1), after)


def test_cli_resume_runs_only_the_missing_flights_and_equals_an_uninterrupted_run(
        tmp_path, capsys, uninterrupted):
    path = tmp_path / "study3d.jsonl"
    first = interrupted_file(path, 2)
    with path.open("a") as f:  # cut while a record was being written
        f.write('{"index": 3, "scenario": "acc')
    out = tmp_path / "study3d.json"
    assert main(CLI + ["--jobs", "1", "--records", str(path), "--out", str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["resumed"] == 2 and doc["model"] == "ins3d"
    assert doc["metrics"] == uninterrupted.metrics
    assert json.loads(out.read_text())["flights"] == uninterrupted.records
    header, *recs = lines(path)  # the cut line is gone, each flight once
    assert header == {"records": FORMAT, "study": json.loads(json.dumps(study_settings(STUDY)))}
    assert [r["index"] for r in recs[:2]] == first
    assert sorted(recs, key=lambda r: r["index"]) == uninterrupted.records
    assert main(CLI + ["--jobs", "1", "--records", str(path), "--json"]) == 0  # nothing left
    assert json.loads(capsys.readouterr().out)["resumed"] == N
    assert len(lines(path)) == N + 1
    # ... and its table's last line says so (it named an empty engine: "on  (5 resumed")
    assert main(CLI + ["--jobs", "1", "--records", str(path)]) == 0
    assert f"(no flight left to run) ({N} resumed from" in capsys.readouterr().out


@pytest.mark.slow
def test_resume_on_two_workers_equals_an_uninterrupted_run(tmp_path, dask_cluster,
                                                           uninterrupted):
    path = tmp_path / "study3d.jsonl"
    interrupted_file(path, 2)
    with RecordsFile(path, study_settings(STUDY)) as rec:
        res = run_study(STUDY, on_record=rec.write, done=rec.done, scheduler=dask_cluster)
    assert res.jobs == 2 and res.resumed == 2
    assert res.records == uninterrupted.records and res.metrics == uninterrupted.metrics
    assert sorted(r["index"] for r in lines(path)[1:]) == list(range(N))


def test_another_studys_file_is_refused_and_kept_and_restart_starts_anew(tmp_path, capsys):
    path = tmp_path / "study.jsonl"
    with RecordsFile(path, study_settings(STUDY)) as rec:
        rec.write({"index": 0, "scenario": "nominal"})
    before = path.read_text()
    other = [a if a != "4" else "5" for a in CLI]  # --seed 5
    assert main(other + ["--jobs", "1", "--records", str(path)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "another study (differs in seed)" in err
    assert path.read_text() == before  # nothing lost
    # the single-axis study's file: refused, naming the model first
    single = ["montecarlo", "--nominal", "1", "--per-fault", "0", "--no-progress", "--jobs", "1"]
    assert main(single + ["--records", str(path)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "differs in model (ins3d, not channel)" in err
    assert path.read_text() == before
    # a record that is not a flight of this plan: an error, not a wrong result
    with pytest.raises(EvalError, match="recorded flight 0 is not a flight of this study"):
        run_study(STUDY, done={0: {"index": 0, "scenario": "nominal", "sim_seed": 1,
                                   "traj_seed": 2}})
    # --restart: the file anew (here: with the other study's header and records)
    assert main(other + ["--jobs", "1", "--records", str(path), "--restart", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["resumed"] == 0
    header, *recs = lines(path)
    assert header["study"]["seed"] == 5 and len(recs) == N


def test_records_do_not_go_with_the_ladder(tmp_path, capsys):
    assert main(CLI + ["--ladder", "--records", str(tmp_path / "r.jsonl")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--ladder" in err
    assert not (tmp_path / "r.jsonl").exists()
