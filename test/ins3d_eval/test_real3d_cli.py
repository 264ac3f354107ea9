"""The real MEMS recording (Xsens DOT unit 1 of straight/path_2, data/mimu_straight_2) analysed
from the command line exactly as from Python: a bag of ``real3d.write_contract_bag`` (its
description's ``error_model`` block: free vertical channel, latency state, no reference Markov
noise, levelled prior) and ``--grade config/grades/xsens_dot_mimu.yaml --rows 2`` (the IMU
values, signature error and seed settings of ``real3d.Settings``) give ``real3d.analyze``'s
verdict and numbers; ``flight-fdi run`` (the node pipeline) gives the same; bad values are one
line (docs/ins3d_real.md, "The bag path")."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from flight_fdi.cli.main import main
from flight_fdi.eval import real3d as R
from flight_fdi.eval.real3d_grade import GRADE_FILE, grade_file_differences, grade_file_text
from flight_fdi.schema import validate_result

DATA = Path(__file__).parent / "data"
NAME = "mimu_straight_2"
FAULTS = {"nominal": None,
          "accel_y": R.Fault("accelerometer", "y", 1.0, 6.0),
          "gyro_y": R.Fault("gyro", "y", math.radians(5.0), 5.0),
          "accel_x": R.Fault("accelerometer", "x", 1.0, 9.0)}   # ambiguous with z (the model)


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    """{case: (bag, the Python analysis of the same recording)}: unit 1 of the excerpt, its
    leave-one-out calibration removed."""
    rec = R.read_recording(DATA, NAME, 1)
    doc = json.loads((DATA / NAME / "calibration.json").read_text())
    cal = np.array(doc["gyro_bias_rad_s"]), np.array(doc["accel_bias_m_s2"])
    root = tmp_path_factory.mktemp("real3d_cli")
    out = {}
    for case, fault in FAULTS.items():
        r = fault.apply(rec) if fault else rec
        R.write_contract_bag(r, *cal, root / case)
        out[case] = (root / case, R.analyze(r, *cal))
    return out


def _cli(capture, *args: str) -> tuple[int, dict]:
    rc = main([*args, "--model", "ins3d", "--grade", str(GRADE_FILE), "--rows", "2", "--json"])
    return rc, json.loads(capture.readouterr().out)


def _assert_close(a, b, where="post_flight", rel=1e-9):
    """Equal structure, strings and flags; numbers to ``rel`` (times: the bag's stamps are whole
    nanoseconds, latitudes go through degrees). The seed method's Fisher ratios amplify that
    rounding (measured: F_peak to 4e-8 relative even with the very same grade object; 2e-6
    after a relinearised pass, core/ins3d/relinearize.py), so its section is compared to 1e-5."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), where
        for k in a:
            _assert_close(a[k], b[k], f"{where}.{k}", 1e-5 if k == "seed_method" else rel)
    elif isinstance(a, (list, tuple)):
        assert isinstance(b, (list, tuple)) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_close(x, y, f"{where}[{i}]", rel)
    elif isinstance(a, float) and not isinstance(b, bool):
        assert b == pytest.approx(a, rel=rel, abs=1e-9), where
    else:
        assert a == b, where


def test_the_grade_file_is_settings():
    """config/grades/xsens_dot_mimu.yaml equals ``real3d.Settings()`` (after a change of the
    defaults: python -m flight_fdi.eval.real3d_grade); a changed setting is found."""
    assert grade_file_differences(GRADE_FILE, R.Settings()) == []
    assert yaml.safe_load(GRADE_FILE.read_text()) == yaml.safe_load(grade_file_text())
    for changed, needle in ((R.Settings(vrw=0.03), "vrw:"),
                            (R.Settings(gyro_bias_deg_h=300.0), "gyro_bias:"),
                            (R.Settings(min_valid_steps=6), "seed method"),
                            (R.Settings(signature_error=0.33), "signature error")):
        diff = grade_file_differences(GRADE_FILE, changed)
        assert len(diff) == 1 and diff[0].startswith(needle), diff


@pytest.mark.parametrize("case", list(FAULTS))
def test_analyze_on_the_bag_is_real3d_analyze(bags, capsys, case):
    """The known answer: the CLI's result is the Python analysis -- verdict, sensor, axis, kind,
    onset, magnitude, every GLR statistic and threshold, the seed method -- to 1e-9."""
    bag, an = bags[case]
    rc, res = _cli(capsys, "analyze", str(bag))
    validate_result(res)
    t0 = float(an.steps.t[0])          # the bag's times start at its first stamp
    py = R.record(an, t0=t0)
    post, f = res["post_flight"], res["post_flight"]["fault"]
    assert rc == 0 and post["verdict"] == py["verdict"]
    if case == "accel_x":
        assert py["verdict"] == "ambiguous"
        assert [f"{c['sensor']} {c['axis']} {c['kind']}" for c in post["candidates"]] \
            == py["candidates"] and len(py["candidates"]) == 2
    elif FAULTS[case] is not None:
        assert R.judge(py, FAULTS[case]) == "right", py
        assert (f["sensor"], f["axis"], f["kind"]) == (py["sensor"], py["axis"], py["kind"])
        for k in ("onset_s", "magnitude", "statistic"):
            assert f[k] == pytest.approx(py[k], rel=1e-9, abs=1e-9), k
    else:
        assert f is None and py["sensor"] is None
    assert post["seed_method"]["verdict"] == py["seed_verdict"] != "insufficient_data"
    assert post["glr"]["thresholds"] == pytest.approx(py["thresholds"], rel=1e-12)
    stats = post["glr"]["statistics"]
    for kind in ("step", "ramp", "jump", "outliers"):
        assert stats[py[f"max_{kind}_hyp"]] == pytest.approx(py[f"max_{kind}"], rel=1e-9)
    _assert_close(an.post_flight_dict(t0=t0), post)
    assert res["ins3d"]["beta2_mean"] == pytest.approx(py["beta2"], rel=1e-9)
    assert res["ins3d"]["final_state"]["latency"] == pytest.approx(py["latency_s"], rel=1e-6,
                                                                   abs=1e-12)


def test_without_the_description_the_analysis_is_the_one_before(bags, tmp_path, capsys):
    """A bag without the ``error_model`` block (as written before) is analysed as before: the
    vertical channel damped (``Ins3dInput.vertical``) -- a different, here insufficient, seed
    analysis and other GLR statistics than the contract's."""
    bag, _ = bags["accel_y"]
    old = _copy_with_description(bag, tmp_path / "old", drop="error_model")
    from flight_fdi.bagio.ins3d_input import read_ins3d
    inp = read_ins3d(old)
    assert inp.model_options() == inp.vertical() == {"vertical": "damped"}
    _, res_old = _cli(capsys, "analyze", str(old))
    _, res_new = _cli(capsys, "analyze", str(bag))
    assert res_old["post_flight"]["glr"]["statistics"] != pytest.approx(
        res_new["post_flight"]["glr"]["statistics"], rel=1e-3)
    assert res_new["ins3d"]["final_state"].get("latency") is not None


def _copy_with_description(bag: Path, out: Path, drop: str | None = None,
                           error_model: dict | None = None) -> Path:
    """A copy of ``bag`` whose description lacks ``drop`` or has this ``error_model`` block."""
    import shutil

    shutil.copytree(bag, out)
    meta = out / "metadata.yaml"
    doc = yaml.safe_load(meta.read_text())
    custom = doc["rosbag2_bagfile_information"]["custom_data"]
    desc = json.loads(custom["flight_fdi.sim3d"])
    if drop:
        desc.pop(drop)
    if error_model is not None:
        desc["error_model"] = error_model
    custom["flight_fdi.sim3d"] = json.dumps(desc)
    meta.write_text(yaml.safe_dump(doc))
    return out


@pytest.mark.parametrize("block, needle", [
    ({"vertical": "upside"}, "error_model.vertical must be one of damped, free, loop"),
    ({"latency": "yes"}, "error_model.latency must be true or false"),
    ({"reference_markov": [0.02, 0.0, 30.0]}, "error_model.reference_markov must be null or"),
    ({"initial_attitude": "guessed"}, "error_model.initial_attitude must be one of levelled"),
    ({"verticle": "free"}, "unknown key 'verticle'"),
])
def test_a_bad_description_is_one_line(bags, tmp_path, capsys, block, needle):
    bag = _copy_with_description(bags["nominal"][0], tmp_path / "bad", error_model=block)
    for cmd, extra in (("analyze", []), ("run", ["--out", str(tmp_path / "o")])):
        rc = main([cmd, str(bag), "--model", "ins3d", *extra])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 1 and len(err) == 1 and needle in err[0], err
        assert err[0].startswith(f"flight-fdi {cmd}: error: bag ")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("line, needle", [
    ("seed_min_valid_steps: 0", "seed_min_valid_steps must be an integer >= 1, got 0"),
    ("seed_fisher_window: 4", "seed_fisher_window must be an integer >= 5, got 4"),
    ("seed_fisher_window: 5.5", "seed_fisher_window must be an integer >= 5, got 5.5"),
    ("seed_min_valid_steps: true", "seed_min_valid_steps must be an integer >= 1, got True"),
])
def test_a_bad_seed_key_is_one_line(bags, tmp_path, capsys, line, needle):
    path = tmp_path / "g.yaml"
    path.write_text("name: x\nbase: mems\n" + line + "\n")
    assert main(["analyze", str(bags["nominal"][0]), "--model", "ins3d", "--grade",
                 str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0], err


@pytest.mark.timeout(300)
def test_run_equals_analyze_on_the_real_bag(bags, tmp_path, capfd):
    """``flight-fdi run`` (filter_node in its ins3d mode with the description's model options
    -> recorder -> smoother, which reads the options and the grade file's seed settings back
    from the recording) gives ``analyze``'s result, fault isolated."""
    bag, _ = bags["accel_y"]
    _, ref = _cli(capfd, "analyze", str(bag))
    out = tmp_path / "run"
    rc, res = _cli(capfd, "run", str(bag), "--out", str(out), "--no-progress", "--no-report",
                   "--fail-on-fault")
    validate_result(res)
    assert rc == 3 and res["post_flight"]["fault"]["axis"] == "y"
    for k in ("post_flight", "in_flight", "ins3d", "samples", "source"):
        assert res[k] == ref[k], k
    from flight_fdi.nodes.ins3d_recording import read_recording3d
    recd = read_recording3d(out / "recording")
    st = R.Settings()
    assert recd["options"] == {"vertical": st.vertical, "latency": st.latency,
                               "aligned_prior": st.aligned_prior, "ref_markov": None}
    assert (recd["grade"].fisher_window, recd["grade"].min_valid_steps) == (5, 5)
