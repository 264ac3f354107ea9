"""``flight-fdi analyze BAG --model ins3d``: table, JSON (schema-valid, ``model`` key),
--fail-on-fault, options, and one-line errors for bad input."""
from __future__ import annotations

import json
import shutil

import pytest

from flight_fdi.cli.main import main
from flight_fdi.schema import validate_result


def _json(capsys, argv):
    rc = main(argv)
    out = capsys.readouterr()
    return rc, json.loads(out.out), out.err


def test_analyze_json_is_schema_valid_and_matches_the_core(bag3d, capsys):
    from flight_fdi.bagio.ins3d_input import read_ins3d
    from flight_fdi.core.ins3d.analysis import analyze_ins3d

    rc, res, _ = _json(capsys, ["analyze", str(bag3d), "--model", "ins3d", "--json"])
    assert rc == 0
    validate_result(res)
    assert res["model"] == "ins3d" and res["channel"] == "enu"      # 3 rows by default
    assert res["source"]["imu_topic"] == "/ins/imu" and res["source"]["grade"] == "navigation"
    inp = read_ins3d(bag3d)
    assert inp.vertical()["loop"].tau_s == 100.0          # the bag's baro loop (metadata)
    a = analyze_ins3d(inp.steps, inp.refs, grade="navigation", **inp.vertical())
    assert res["samples"] == a.forward.beta2.size
    assert res["ins3d"]["beta2_mean"] == pytest.approx(float(a.forward.beta2.mean()), rel=1e-12)
    assert res["ins3d"]["final_state"]["bg_x"] == pytest.approx(float(a.forward.x[-1, 9]),
                                                                  rel=1e-12)
    assert res["duration_s"] == pytest.approx(400.0, abs=0.2)
    # the turn (from ~303 s) is in the manoeuvres
    assert any(m[2].startswith("turn") and 290 < m[0] < 320 for m in res["ins3d"]["manoeuvres"])


def test_analyze_options_grade_rows_and_table(bag3d, capsys):
    rc, res, _ = _json(capsys, ["analyze", str(bag3d), "--model", "ins3d", "--json",
                                "--grade", "tactical", "--rows", "2"])
    assert rc == 0
    validate_result(res)
    assert res["channel"] == "en" and res["ins3d"]["grade"] == "tactical"
    assert set(res["ins3d"]["beta2_row_mean"]) == {"east", "north"}
    assert main(["analyze", str(bag3d), "--model", "ins3d"]) == 0
    text = capsys.readouterr().out
    assert "model ins3d (navigation grade" in text and "turns:" in text
    known = [ln for ln in text.splitlines() if ln.startswith("sensor bias known to half")]
    assert len(known) == 1                   # the observability report's line, six sensors
    assert all(f"{s} {a} " in known[0] for s in ("accelerometer", "gyro") for a in "xyz")


def test_fail_on_fault_follows_the_verdict(bag3d, capsys):
    rc, res, _ = _json(capsys, ["analyze", str(bag3d), "--model", "ins3d", "--json",
                                "--fail-on-fault"])
    assert rc == (3 if res["post_flight"]["verdict"] in ("failure", "glitch", "ambiguous")
                  else 0)
    # a gate that every sample exceeds: the verdict declares a fault, exit 3
    rc, res, _ = _json(capsys, ["analyze", str(bag3d), "--model", "ins3d", "--json",
                                "--fail-on-fault", "--gate-rule", "seed", "--alarm", "1/1",
                                "--gate-probability", "0.4"])
    assert res["in_flight"]["alarms"] and res["post_flight"]["verdict"] != "no_fault"
    assert rc == 3


def test_topic_names_are_options(bag3d, tmp_path, capsys):
    from flight_fdi.bagio.reader import read_messages
    from flight_fdi.bagio.writer import open_writer

    rename = {"/ins/imu": "/xsens/imu", "/ins/velocity": "/xsens/vel", "/ins/fix": "/xsens/fix",
              "/reference/velocity": "/gnss/vel"}
    renamed = tmp_path / "renamed"
    with open_writer(renamed, compression="none") as w:
        for topic, msgtype, t_ns, msg in read_messages(bag3d, list(rename)):
            w.write(rename[topic], msgtype, msg, t_ns)
    rc, res, _ = _json(capsys, ["analyze", str(renamed), "--model", "ins3d", "--json",
                                "--imu-topic", "/xsens/imu", "--ins-topic", "/xsens/vel",
                                "--fix-topic", "/xsens/fix", "--reference-topic", "/gnss/vel"])
    assert rc == 0
    rc, ref, _ = _json(capsys, ["analyze", str(bag3d), "--model", "ins3d", "--json"])
    assert res["ins3d"] == ref["ins3d"] and res["in_flight"] == ref["in_flight"]
    assert res["source"]["ins_topic"] == "/xsens/vel"
    assert main(["analyze", str(renamed), "--model", "ins3d"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no topic /ins/velocity, /ins/imu, /ins/fix" in err[0]


@pytest.mark.parametrize("argv,needle", [
    (["--model", "ins3d", "--channel", "y"], "--channel applies to the single-axis"),
    (["--grade", "mems"], "--grade applies only to --model ins3d"),
    (["--model", "ins3d", "--reference-topic", "/a", "--reference-topic", "/b"],
     "one --reference-topic"),
])
def test_option_errors_are_one_line(bag3d, capsys, argv, needle):
    assert main(["analyze", str(bag3d), *argv]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0]


def test_bad_bags_are_one_line_errors(bag3d, tmp_path, capsys):
    # a single-axis bag
    assert main(["analyze", "bags/nominal", "--model", "ins3d"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "single-axis bag?" in err[0]
    # a wrong type on a contract topic: the velocity topic named as the IMU
    assert main(["analyze", str(bag3d), "--model", "ins3d", "--imu-topic", "/sim/fault"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "carries std_msgs/msg/String, expected sensor_msgs/msg/Imu" in err[0]
    # missing and corrupt bags
    assert main(["analyze", str(tmp_path / "none"), "--model", "ins3d"]) == 1
    assert "does not exist" in capsys.readouterr().err
    bad = tmp_path / "bad"
    shutil.copytree(bag3d, bad)
    for f in bad.glob("*.mcap"):
        f.write_bytes(f.read_bytes()[:4000])
    assert main(["analyze", str(bad), "--model", "ins3d"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("flight-fdi analyze: error:")


def test_schema_holds_the_ins3d_form(bag3d, capsys):
    import jsonschema

    rc, res, _ = _json(capsys, ["analyze", str(bag3d), "--model", "ins3d", "--json"])
    validate_result(res)
    for change in ({"channel": "x"}, {"ins3d": None}, {"model": "ins3d", "channel": "east"}):
        bad = {k: v for k, v in {**res, **change}.items() if v is not None}
        with pytest.raises(jsonschema.ValidationError):
            validate_result(bad)
    fault = res["post_flight"]["fault"]
    # the simulated fault: gyro x step of 3 deg/h at 150 s
    assert (fault["sensor"], fault["axis"], fault["kind"]) == ("gyro", "x", "step")
    assert abs(fault["onset_s"] - 150.0) < 10.0 and fault["unit_eng"] == "deg/h"
    assert fault["magnitude_eng"] == pytest.approx(3.0, rel=0.1)
    bad = json.loads(json.dumps(res))
    bad["post_flight"]["fault"]["axis"] = "forward"
    with pytest.raises(jsonschema.ValidationError):
        validate_result(bad)
