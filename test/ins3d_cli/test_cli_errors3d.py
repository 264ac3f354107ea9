"""``analyze`` / ``run`` / ``report`` (``--model ins3d`` and the options they share): every error
a user can make is one line and a non-zero exit, and no option is accepted and then ignored.

* a malformed command line (``--latency=yes``, an option without its value, ``--rows 4``, an
  unknown option, no BAG) is one line, exit 2 (before: argparse's 15-line usage text);
* ``report RUN_FOLDER`` refuses the options its recording fixes (grade, rows, topics, gate, error
  model; before: silently ignored), one line naming them;
* ``report`` honours ``--fail-on-fault`` (before: always exit 0);
* ``report --out`` that cannot be a folder is one line before any analysis (before: a
  FileExistsError traceback after it);
* ``report RESULT.json`` analyses the bag again with the result's gate (recorded in ``source``;
  before: the default gate, other alarms than the result's)."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from flight_fdi.cli.main import main


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    """A 150-s 3-D bag with a 30 deg/h gyro x step at 60 s (a fault verdict)."""
    out = tmp_path_factory.mktemp("cli_errors3d") / "gyro"
    assert main(["simulate", str(out), "--model", "ins3d", "--duration", "150", "--seed", "3",
                 "--fault", "gyro:step:t=60,mag=30deg/h,axis=x"]) == 0
    return out


def _one_line(err: str, cmd: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"flight-fdi {cmd}: error: "), lines
    assert "Traceback" not in err
    return lines[0]


@pytest.mark.parametrize("argv, needle", [
    (["--latency=yes"], "ignored explicit argument 'yes'"),
    (["--no-latency=no"], "ignored explicit argument 'no'"),
    (["--vertical"], "argument --vertical: expected one argument"),
    (["--reference-markov"], "argument --reference-markov: expected one argument"),
    (["--initial-attitude"], "argument --initial-attitude: expected one argument"),
    (["--grade"], "argument --grade: expected one argument"),
    (["--rows", "4"], "argument --rows: invalid choice: 4"),
    (["--gate-probability", "often"], "invalid float value: 'often'"),
    (["--bogus"], "unrecognized arguments: --bogus"),
])
@pytest.mark.parametrize("cmd", ["analyze", "run", "report"])
def test_a_malformed_command_line_is_one_line(cmd, argv, needle, capsys, tmp_path):
    extra = ["--out", str(tmp_path / "o")] if cmd == "report" else []
    with pytest.raises(SystemExit) as exc:
        main([cmd, "some_bag", "--model", "ins3d", *extra, *argv])
    assert exc.value.code == 2
    assert needle in _one_line(capsys.readouterr().err, cmd)
    assert not (tmp_path / "o").exists()


def test_a_missing_argument_is_one_line_and_help_still_helps(capsys):
    for argv, cmd, needle in ((["analyze"], "analyze", "required: bag"),
                              (["report", "x"], "report", "required: --out")):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
        assert needle in _one_line(capsys.readouterr().err, cmd)
    with pytest.raises(SystemExit) as exc:
        main(["analyze", "--help"])
    assert exc.value.code == 0 and "--latency, --no-latency" in capsys.readouterr().out


def test_the_command_line_itself_gets_one_line():
    """The installed entry point's way (a process: stderr and the exit status as a shell sees
    them)."""
    proc = subprocess.run([sys.executable, "-m", "flight_fdi.cli.main", "analyze", "some_bag",
                           "--model", "ins3d", "--latency=yes"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2 and proc.stdout == ""
    assert "--latency/--no-latency" in _one_line(proc.stderr, "analyze")


@pytest.mark.timeout(300)
def test_report_of_a_run_folder(bag, tmp_path, capfd):
    """Options its recording fixes are refused (one line naming them, nothing written); the
    others (--json, --fail-on-fault) are honoured."""
    run = tmp_path / "run"
    assert main(["run", str(bag), "--model", "ins3d", "--out", str(run), "--no-report",
                 "--no-progress", "--json"]) == 0
    verdict = json.loads(capfd.readouterr().out)["post_flight"]["verdict"]
    assert verdict in ("failure", "ambiguous")
    rep = tmp_path / "rep"
    for argv, named in ((["--grade", "tactical", "--rows", "2"], "--grade, --rows"),
                        (["--imu-topic", "/x"], "--imu-topic"),
                        (["--gate-rule", "seed", "--alarm", "2/4"], "--gate-rule, --alarm"),
                        (["--vertical", "free"], "--vertical")):
        for src in (run, run / "result.json"):
            assert main(["report", str(src), "--out", str(rep), *argv]) == 1
            line = _one_line(capfd.readouterr().err, "report")
            assert "is a run folder" in line and f"{named} cannot change it" in line
            assert f"report the bag {str(bag)!r}" in line
    assert not rep.exists()
    assert main(["report", str(run), "--out", str(rep), "--json", "--fail-on-fault"]) == 3
    assert json.loads(capfd.readouterr().out)["summary"]["post_flight"]["verdict"] == verdict
    assert main(["report", str(run), "--out", str(rep)]) == 0


def test_report_honours_fail_on_fault(bag, tmp_path, capsys):
    """A bag, a result JSON (3-D) and a single-axis bag: exit 3 with --fail-on-fault when the
    verdict declares a fault, 0 on a nominal flight."""
    assert main(["report", str(bag), "--model", "ins3d", "--out", str(tmp_path / "a"),
                 "--fail-on-fault"]) == 3
    capsys.readouterr()
    assert main(["analyze", str(bag), "--model", "ins3d", "--json"]) == 0
    doc = tmp_path / "res.json"
    doc.write_text(capsys.readouterr().out)
    assert main(["report", str(doc), "--out", str(tmp_path / "b"), "--fail-on-fault"]) == 3
    assert main(["report", "bags/accel_fault_500s", "--out", str(tmp_path / "c"),
                 "--fail-on-fault"]) == 3
    assert main(["report", "bags/nominal", "--out", str(tmp_path / "d"),
                 "--fail-on-fault"]) == 0


def test_report_out_must_be_a_folder(bag, tmp_path, capsys):
    """--out naming a file, or below one: one line, before the analysis."""
    afile = tmp_path / "afile"
    afile.write_text("x")
    doc = tmp_path / "res.json"
    doc.write_text(json.dumps({"post_flight": {}, "model": "ins3d", "bag": str(bag)}))
    for src, model in ((bag, ["--model", "ins3d"]), (doc, []), ("bags/nominal", [])):
        for out, why in ((afile, "a file of that name exists"),
                         (afile / "sub", f"{str(afile)!r} is not a folder")):
            assert main(["report", str(src), *model, "--out", str(out)]) == 1
            line = _one_line(capsys.readouterr().err, "report")
            assert line.endswith(f"--out {str(out)!r}: cannot make the report folder there "
                                 f"({why})")
    assert afile.read_text() == "x"


def test_report_of_a_result_takes_its_gate(bag, tmp_path, capsys):
    """The result records its gate (``source.gate``); ``report RESULT.json`` analyses the bag
    again with it -- the same in-flight section -- unless a gate option is given."""
    assert main(["analyze", str(bag), "--model", "ins3d", "--json", "--gate-rule", "seed",
                 "--alarm", "2/4"]) in (0, 3)
    res = json.loads(capsys.readouterr().out)
    assert res["source"]["gate"] == {"gate_rule": "seed", "gate_probability": 1e-3,
                                     "alarm": "2/4", "gate_action": "flag"}
    doc = tmp_path / "res.json"
    doc.write_text(json.dumps(res))
    assert main(["report", str(doc), "--out", str(tmp_path / "a"), "--json"]) == 0
    again = json.loads(capsys.readouterr().out)["summary"]
    assert again["in_flight"] == res["in_flight"] and again["source"] == res["source"]
    assert main(["report", str(doc), "--out", str(tmp_path / "b"), "--json",
                 "--alarm", "3/4"]) == 0
    mine = json.loads(capsys.readouterr().out)["summary"]
    assert mine["source"]["gate"] == {**res["source"]["gate"], "alarm": "3/4"}
    assert mine["in_flight"]["gate_threshold"] == res["in_flight"]["gate_threshold"]


def test_a_single_axis_run_folder_refuses_a_gate(tmp_path, capsys):
    """The single-axis models' run folder too: the recording holds the gate (before: a gate
    option was silently ignored). Refused before the recording is read (an empty one here)."""
    run = tmp_path / "run"
    (run / "recording").mkdir(parents=True)
    (run / "result.json").write_text(json.dumps({"post_flight": {}, "bag": "bags/nominal"}))
    for src in (run, run / "result.json"):
        assert main(["report", str(src), "--out", str(tmp_path / "rep"), "--gate-rule", "seed",
                     "--gate-action", "reject"]) == 1
        line = _one_line(capsys.readouterr().err, "report")
        assert "is a run folder" in line and "--gate-rule, --gate-action cannot change it" in line
    assert not (tmp_path / "rep").exists()


def test_a_malformed_result_is_one_line_naming_it(bag, tmp_path, capsys):
    """``report RESULT.json`` with a ``source`` of the wrong shape, or options in it that
    ``analyze`` refuses: one line naming the result, before the bag is read (before: an
    AttributeError traceback for the first two)."""
    good = {"post_flight": {}, "model": "ins3d", "bag": str(bag)}
    for source, needle in (
            ("junk", "its 'source' is not an object"),
            ({"gate": {"alarm": 7}}, "--alarm must look like M/N (e.g. 3/5), got 7"),
            ({"grade": str(tmp_path / "gone.yaml")}, "gone.yaml"),
            ({"error_model_overrides": ["reference_markov"],
              "error_model": {"reference_markov": ["a", 1, 2]}}, "--reference-markov")):
        doc = tmp_path / "res.json"
        doc.write_text(json.dumps({**good, "source": source}))
        assert main(["report", str(doc), "--out", str(tmp_path / "r")]) == 1
        line = _one_line(capsys.readouterr().err, "report")
        assert line.startswith(f"flight-fdi report: error: {doc}: ") and needle in line, line
    assert not (tmp_path / "r").exists()


def test_run_out_must_be_a_folder(bag, tmp_path, capfd):
    """``run --model ins3d --out FILE``: one line before any node (before: a FileExistsError
    traceback from the pipeline)."""
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert main(["run", str(bag), "--model", "ins3d", "--out", str(afile), "--no-progress"]) == 1
    line = _one_line(capfd.readouterr().err, "run")
    assert line.endswith(f"--out {str(afile)!r}: cannot make the output folder there (a file of "
                         "that name exists)")
    assert afile.read_text() == "x"
