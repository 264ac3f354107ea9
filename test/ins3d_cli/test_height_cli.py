"""``analyze`` / ``batch`` / ``report`` ``--model ins3d --height-topic T``: simulated flights
written with a barometric height topic (``simulate --baro-topic``: a second barometer with a
turn-on offset, Gauss-Markov error and drift, FluidPressure) analysed with the height as the third
row -- the nominal flight names nothing, a 1-mg vertical accelerometer step that the two
horizontal rows miss is isolated to accelerometer z; the result names the row ``height`` and
records the height options, which ``report RESULT.json`` and ``batch`` use again; every bad
height option is one line."""
from __future__ import annotations

import json

import numpy as np
import pytest

from flight_fdi.cli.main import build_parser, main

BARO = "/reference/baro"


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    """Two 200-s flights with a FluidPressure height topic: nominal, and accelerometer z +1 mg
    from 80 s."""
    root = tmp_path_factory.mktemp("height3d")
    out = {}
    for name, extra in (("nominal", []),
                        ("accel_z", ["--fault", "accel:step:t=80,mag=1mg,axis=z"])):
        assert main(["simulate", str(root / name), "--model", "ins3d", "--duration", "200",
                     "--seed", "4", "--baro-topic", BARO, *extra]) == 0
        out[name] = root / name
    return out


def _analyze(bag, *opts, capsys) -> dict:
    capsys.readouterr()
    main(["analyze", str(bag), "--model", "ins3d", "--json", "--jobs", "1", *opts])
    return json.loads(capsys.readouterr().out)


@pytest.fixture(scope="module")
def results(bags):
    """analyze --json --height-topic of both bags ({name: result})."""
    import contextlib
    import io
    out = {}
    for name, bag in bags.items():
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            main(["analyze", str(bag), "--model", "ins3d", "--json", "--jobs", "1",
                  "--height-topic", BARO])
        out[name] = json.loads(buf.getvalue())
    return out


def test_nominal_names_nothing_and_the_third_row_is_the_height(results):
    res = results["nominal"]
    post = res["post_flight"]
    assert post["verdict"] == "no_fault" and post["fault"] is None
    assert res["channel"] == "en_height"
    assert list(res["ins3d"]["beta2_row_mean"]) == ["east", "north", "height"]
    assert 0.2 < res["ins3d"]["beta2_row_mean"]["height"] < 1.5
    src = res["source"]
    assert src["rows"] == 3 and src["height"] == {
        "topic": BARO, "sigma_m": 0.05, "markov": [0.4, 5.0], "datum": "first",
        "v0_sigma_up": 1.0, "max_gap_s": 2.0}
    # the source keeps the velocity reference's Markov noise (the defaults); the height row has
    # its own sigma and tau (HeightSpec.ref_markov: (0.02, 0.4, 30.0, 5.0) in the model)
    assert src["error_model"]["reference_markov"] == [0.02, 0.03, 30.0]
    entry = res["input"][BARO]
    assert entry["type"] == "sensor_msgs/msg/FluidPressure" and entry["role"] == "height"
    assert entry["messages"] == 2001 and entry["used"] == 2000      # the one at 0 s: before
    assert entry["variance"] == {"message": 2000, "configured": 0}  # the IMU record
    assert abs(entry["offset_m"]) > 0.5                              # the turn-on offset
    assert res["input"]["/reference/velocity"]["dropped"]["no_height"] == 0


def test_a_vertical_accelerometer_step_is_isolated_through_the_height_row(bags, results,
                                                                          capsys):
    without = _analyze(bags["accel_z"], "--rows", "2", capsys=capsys)
    assert without["post_flight"]["verdict"] == "no_fault"      # measured: 2 rows miss it
    fault = results["accel_z"]["post_flight"]["fault"]
    assert results["accel_z"]["post_flight"]["verdict"] == "failure"
    assert (fault["sensor"], fault["axis"], fault["kind"]) == ("accelerometer", "z", "step")
    assert fault["onset_s"] == pytest.approx(80.0, abs=5.0)
    assert fault["magnitude"] == pytest.approx(0.00980665, rel=0.2)
    capsys.readouterr()
    assert main(["analyze", str(bags["accel_z"]), "--model", "ins3d", "--jobs", "1",
                 "--height-topic", BARO]) == 0
    text = capsys.readouterr().out
    assert "rows en_height" in text and "per row east" in text and ", height " in text
    assert f"height reference: {BARO} (FluidPressure), white 0.05 m, Markov 0.4 m over 5 s, " \
           "datum first (offset " in text


def test_report_of_the_result_and_batch_analyse_with_its_height_options(bags, results,
                                                                      tmp_path, capsys):
    """``report RESULT.json`` analyses its bag again with the result's ``source.height``
    (``options_of_result``: the same result), and ``batch`` gives analyze's result."""
    from flight_fdi.cli.ins3d import analyze_bag, options_of_result
    doc = results["accel_z"]
    path = tmp_path / "r.json"
    path.write_text(json.dumps(doc))
    args = build_parser("report").parse_args(["report", str(path), "--out", str(tmp_path / "o"),
                                              "--model", "ins3d"])
    options_of_result(args, doc)
    assert (args.height_topic, args.height_markov, args.height_datum) == (BARO, "0.4,5.0",
                                                                          "first")
    args.jobs = 1
    assert analyze_bag(doc["bag"], args)[0] == doc
    out = tmp_path / "fleet"
    capsys.readouterr()
    assert main(["batch", *(str(b) for b in bags.values()), "--out", str(out), "--workers", "1",
                 "--no-progress", "--json", "--model", "ins3d", "--height-topic", BARO]) == 0
    for name in bags:
        assert json.loads((out / "flights" / f"{name}.json").read_text()) == results[name]


@pytest.mark.parametrize("opts, code, needle", [
    (["--height-sigma", "0.1"], 1, "--height-sigma needs --height-topic"),
    (["--v0-sigma-up", "2", "--height-datum", "absolute"], 1,
     "--height-datum, --v0-sigma-up need --height-topic"),
    (["--rows", "2", "--height-topic", BARO], 1,
     "--rows 2 and --height-topic: the height reference is the third row"),
    (["--height-topic", BARO, "--height-markov", "0.4"], 1,
     "--height-markov '0.4': expected SIGMA,TAU (m, s), both > 0, or none"),
    (["--height-topic", BARO, "--height-sigma", "-1"], 1,
     "--height-sigma -1.0: sigma must be a number > 0"),
    (["--height-topic", "/nope"], 1, "no height topic /nope (topics: "),
    (["--height-topic", "/sim/truth"], 1,
     "/sim/truth carries flight_fdi_msgs/msg/FilterState, expected a height"),
    (["--height-topic", "/reference/velocity"], 1, "also a contract topic"),
    (["--height-sigma", "abc"], 2, "argument --height-sigma: invalid float value: 'abc'"),
    (["--height-topic", BARO, "--height-datum", "geoid"], 2,
     "argument --height-datum: invalid choice: 'geoid'"),
])
def test_bad_height_options_are_one_line(bags, capsys, opts, code, needle):
    capsys.readouterr()
    try:
        got = main(["analyze", str(bags["nominal"]), "--model", "ins3d", *opts])
    except SystemExit as exc:
        got = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert got == code and len(err) == 1 and needle in err[0], err
    assert err[0].startswith("flight-fdi analyze: error: ")


def test_the_height_options_belong_to_the_3d_model(bags, capsys):
    capsys.readouterr()
    assert main(["analyze", str(bags["nominal"]), "--height-topic", BARO]) == 1
    assert "--height-topic applies only to --model ins3d" in capsys.readouterr().err


@pytest.mark.timeout(300)
def test_run_equals_analyze_with_the_height_topic(bags, results, tmp_path):
    """``flight-fdi run --height-topic`` (the player plays the height topic, filter_node's ins3d
    mode subscribes to it -- ``ins3d_height_topic`` -- and records the height row and its
    options, the smoother analyses the recording) gives ``analyze``'s result."""
    from .conftest import stdout_of
    out = tmp_path / "run"
    rc, text = stdout_of(["run", str(bags["accel_z"]), "--model", "ins3d", "--height-topic",
                          BARO, "--out", str(out), "--json", "--no-progress", "--no-report",
                          "--fail-on-fault"])
    res = json.loads(text)
    ref = results["accel_z"]
    assert rc == 3 and res["post_flight"]["fault"]["axis"] == "z"
    for k in ("post_flight", "in_flight", "ins3d", "samples", "source", "input"):
        assert res[k] == ref[k], k
    from flight_fdi.bagio.recording3d import read_recording3d
    rec = read_recording3d(out / "recording")
    assert rec["rows"] == 3 and rec["options"]["height_row"] and rec["options"]["position"]
    assert rec["options"]["h0_sigma"] == pytest.approx(np.hypot(0.1, 0.3))  # the first sample
