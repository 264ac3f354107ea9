"""flight-fdi batch --model ins3d: each flight's result is what ``analyze --model ins3d --json``
prints with the same options; summary rows name sensor, body axis, kind, onset and magnitude; a
second run is up to date, a changed 3-D option analyses again; bad 3-D values and 3-D options
with the single-axis model are one line and a non-zero exit, as in analyze."""
from __future__ import annotations

import csv
import json
import pathlib

import pytest

from flight_fdi.campaign.batch import Batch, option_flags
from flight_fdi.campaign.engine import Engine, EngineSpec
from flight_fdi.cli.main import build_parser, main

#: two 100-s 3-D flights: name -> simulate options
FLIGHTS3D = {
    "nominal": ["--seed", "1"],
    "accel_z": ["--seed", "2", "--fault", "accel:step:t=40,mag=0.02,axis=z"],
}


@pytest.fixture(scope="session")
def bags3d(tmp_path_factory) -> dict[str, pathlib.Path]:
    root = tmp_path_factory.mktemp("bags3d")
    out = {}
    for name, opts in FLIGHTS3D.items():
        assert main(["simulate", str(root / name), "--model", "ins3d", "--duration", "100",
                     *opts]) == 0
        out[name] = root / name
    return out


def batch_cli(bags3d, out, *opts, capsys) -> tuple[int, dict | None, str]:
    """``flight-fdi batch`` in this process (--workers 1): (status, its --json, stderr)."""
    capsys.readouterr()
    code = main(["batch", *(str(b) for b in bags3d.values()), "--out", str(out),
                 "--workers", "1", "--no-progress", "--json", *opts])
    cap = capsys.readouterr()
    return code, json.loads(cap.out) if cap.out.strip() else None, cap.err


def analyze_json(bag, *opts, capsys) -> dict:
    capsys.readouterr()
    assert main(["analyze", str(bag), "--model", "ins3d", "--json", "--jobs", "1", *opts]) == 0
    return json.loads(capsys.readouterr().out)


def test_batch_ins3d_equals_analyze_resumes_and_follows_the_3d_options(bags3d, tmp_path,
                                                                         capsys):
    out = tmp_path / "out"
    code, doc, err = batch_cli(bags3d, out, "--model", "ins3d", capsys=capsys)
    assert code == 0, err
    assert (doc["analysed"], doc["skipped"], doc["failed"]) == (2, 0, 0)
    for name, bag in bags3d.items():
        result = json.loads((out / "flights" / f"{name}.json").read_text())
        assert result == analyze_json(bag.resolve(), capsys=capsys)
        assert result["model"] == "ins3d"
    with open(out / "summary.csv", newline="") as f:
        rows = {r["flight"]: r for r in csv.DictReader(f)}
    fault = rows["accel_z"]
    assert (fault["verdict"], fault["sensor"], fault["axis"], fault["kind"], fault["unit"]) == \
        ("failure", "accelerometer", "z", "step", "m/s^2")
    assert float(fault["onset_s"]) == pytest.approx(40, abs=2)
    assert float(fault["magnitude"]) == pytest.approx(0.02, rel=0.2)
    assert rows["nominal"]["verdict"] == "no_fault" and rows["nominal"]["sensor"] == ""
    assert not any(r["error"] for r in rows.values())

    # a second run: up to date
    code, doc, _ = batch_cli(bags3d, out, "--model", "ins3d", capsys=capsys)
    assert (code, doc["analysed"], doc["skipped"]) == (0, 0, 2)
    # a 3-D option changed: every flight again, as analyze gives it with that option
    code, doc, _ = batch_cli(bags3d, out, "--model", "ins3d", "--vertical", "damped",
                             "--no-latency", capsys=capsys)
    assert (code, doc["analysed"], doc["skipped"]) == (0, 2, 0)
    options = json.loads((out / "batch.json").read_text())["options"]
    assert (options["vertical"], options["latency"]) == ("damped", False)
    result = json.loads((out / "flights" / "accel_z.json").read_text())
    assert result == analyze_json(bags3d["accel_z"].resolve(), "--vertical", "damped",
                                  "--no-latency", capsys=capsys)
    assert result["source"]["error_model_overrides"] == ["vertical", "latency"]
    # the fleet page's report command carries the options as given
    assert "--model ins3d --vertical damped --no-latency" in (out / "index.html").read_text()
    code, doc, _ = batch_cli(bags3d, out, "--model", "ins3d", "--vertical", "damped",
                             "--no-latency", capsys=capsys)
    assert (doc["analysed"], doc["skipped"]) == (0, 2)


def test_option_flags_of_the_3d_options():
    args = build_parser("batch").parse_args(
        ["batch", "IN", "--out", "O", "--model", "ins3d", "--latency", "--rows", "2",
         "--reference-markov", "none"])
    assert option_flags(args) == ["--model", "ins3d", "--rows", "2", "--latency",
                                  "--reference-markov", "none"]


@pytest.mark.parametrize("opts, message", [
    (["--model", "ins3d", "--vertical", "bogus"],
     "--vertical 'bogus': must be one of damped, free, loop"),
    (["--model", "ins3d", "--reference-markov", "1,2"], "--reference-markov '1,2'"),
    (["--model", "ins3d", "--grade", "no_such_grade"], "--grade 'no_such_grade'"),
    (["--model", "ins3d", "--channel", "x"], "--channel applies to the single-axis models"),
    (["--grade", "tactical"], "--grade applies only to --model ins3d"),
    (["--rows", "2"], "--rows applies only to --model ins3d"),
    (["--imu-topic", "/imu"], "--imu-topic applies only to --model ins3d"),
    (["--no-latency"], "--latency/--no-latency applies only to --model ins3d"),
    (["--model", "ins_channel", "--initial-attitude", "independent"],
     "--initial-attitude applies only to --model ins3d"),
])
def test_bad_3d_options_are_refused_in_one_line_as_analyze_does(bags3d, tmp_path, capsys,
                                                                 opts, message):
    out = tmp_path / "out"
    code, doc, err = batch_cli(bags3d, out, *opts, capsys=capsys)
    assert code == 1 and doc is None
    assert err.strip().splitlines() == [f"flight-fdi batch: error: {err.split(': error: ')[1]}"
                                        .strip()]
    assert message in err and not out.exists()  # refused before anything ran
    assert main(["analyze", str(bags3d["nominal"]), "--jobs", "1", *opts]) == 1
    assert capsys.readouterr().err.split(": error: ")[1] == err.split(": error: ")[1]


@pytest.mark.parametrize("opts, message", [
    (["--alarm", "x"], "--alarm must look like M/N (e.g. 3/5), got 'x'"),
    (["--gate-probability", "2"], "GateConfig.probability must be a number in (0, 1)"),
    (["--model", "no_such_model"], "unknown model 'no_such_model'"),
])
def test_bad_single_axis_options_are_refused_in_one_line(tmp_path, capsys, opts, message):
    """The single-axis model's options are checked once, up front, as analyze checks them
    (before: every flight an error row and exit status 0)."""
    bag = pathlib.Path(__file__).resolve().parents[2] / "bags" / "nominal"
    out = tmp_path / "out"
    code, doc, err = batch_cli({"nominal": bag}, out, *opts, capsys=capsys)
    assert code == 1 and doc is None and not out.exists()
    assert len(err.strip().splitlines()) == 1 and message in err


def test_batch_ins3d_on_a_two_worker_cluster(bags3d, tmp_path, dask_cluster):
    out = tmp_path / "out"
    args = build_parser("batch").parse_args(
        ["batch", "IN", "--out", str(out), "--model", "ins3d", "--rows", "2"])
    with Engine(EngineSpec(scheduler=dask_cluster)) as engine:
        res = Batch([str(b) for b in bags3d.values()], out, args).run(engine)
    assert (res.analysed, res.failed) == (2, 0)
    inline = Batch([str(b) for b in bags3d.values()], tmp_path / "inline", args)
    with Engine(EngineSpec(workers=1)) as engine:
        assert inline.run(engine).analysed == 2
    for name in bags3d:
        result = json.loads((out / "flights" / f"{name}.json").read_text())
        assert result["source"]["rows"] == 2 and result["channel"] == "en"
        assert result == json.loads((tmp_path / "inline" / "flights" / f"{name}.json")
                                    .read_text())


def test_grade_file_relative_path_and_contents_decide_reanalysis(bags3d, tmp_path, capsys,
                                                                  monkeypatch):
    root = pathlib.Path(__file__).resolve().parents[2]
    grade = tmp_path / "grade.yaml"
    grade.write_text((root / "config" / "grades" / "navigation_as_file.yaml").read_text())
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    code, doc, err = batch_cli(bags3d, out, "--model", "ins3d", "--grade", "grade.yaml",
                               capsys=capsys)
    assert (code, doc["analysed"]) == (0, 2), err
    options = json.loads((out / "batch.json").read_text())["options"]
    assert options["grade"] == str(grade)  # the workers' path, wherever they run
    result = json.loads((out / "flights" / "accel_z.json").read_text())
    assert result == analyze_json(bags3d["accel_z"].resolve(), "--grade", "grade.yaml",
                                  capsys=capsys)
    code, doc, _ = batch_cli(bags3d, out, "--model", "ins3d", "--grade", str(grade),
                             capsys=capsys)
    assert (doc["analysed"], doc["skipped"]) == (0, 2)
    grade.write_text(grade.read_text().replace("accel_bias_ug: 30", "accel_bias_ug: 50"))
    code, doc, _ = batch_cli(bags3d, out, "--model", "ins3d", "--grade", "grade.yaml",
                             capsys=capsys)
    assert (code, doc["analysed"], doc["skipped"]) == (0, 2, 0)


def test_3d_reports_on_demand(bags3d, tmp_path, capsys):
    out = tmp_path / "out"
    code, doc, err = batch_cli(bags3d, out, "--model", "ins3d", "--reports", "faults",
                               capsys=capsys)
    assert code == 0 and "flight-fdi batch:" not in err, err
    assert (out / "reports" / "accel_z" / "index.html").is_file()
    assert not (out / "reports" / "nominal").exists()
    summary = json.loads((out / "reports" / "accel_z" / "summary.json").read_text())
    assert summary["post_flight"]["fault"]["axis"] == "z"
    assert 'href="reports/accel_z/index.html"' in (out / "index.html").read_text()
