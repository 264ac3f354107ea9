"""``flight-fdi analyze`` on the sample flights, its JSON schema, and its one-line errors."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from flight_fdi.cli.main import main

ELEMENTS = ["velocity_error", "tilt", "accel_bias", "gyro_drift"]


def _analyze(capsys, *args):
    rc = main(["analyze", *map(str, args), "--json"])
    out, err = capsys.readouterr()
    assert rc == 0, err
    return json.loads(out)


def _check_schema(res, bag):
    from flight_fdi.schema import validate_result

    validate_result(res)  # the versioned JSON Schema (flight_fdi/schema/result-v1.schema.json)
    assert res["schema"] == "flight-fdi/result/v1"
    assert res["bag"] == str(bag) and res["channel"] == "x"
    assert 990 < res["duration_s"] < 1001 and res["samples"] > 9000
    for a in res["in_flight"]["alarms"]:
        assert a["start_s"] <= a["end_s"]
    seed = res["post_flight"]["seed_method"]
    assert [e["name"] for e in seed["elements"]] == ELEMENTS
    assert res["post_flight"]["glr"]["threshold"] > 0
    # every input topic with every drop reason (0 on the clean sample bags)
    assert set(res["input"]) == {"/ins/velocity", "/reference/velocity"}
    assert all(n == 0 for e in res["input"].values() for n in e["dropped"].values())
    assert res["input"]["/reference/velocity"]["used"] == res["samples"]


def test_nominal_flight_no_alarm_no_fault(capsys, repo_root):
    bag = repo_root / "bags" / "nominal"
    res = _analyze(capsys, bag)
    _check_schema(res, bag)
    assert res["in_flight"]["first_alarm_s"] is None and res["in_flight"]["alarms"] == []
    assert res["post_flight"]["glr"]["hypothesis"] == "none"
    assert res["post_flight"]["verdict"] == "no_fault"


@pytest.mark.parametrize("bag_name, hypothesis, element, magnitude", [
    ("accel_fault_500s", "accel_bias_step", "accel_bias", 0.015),
    ("gyro_fault_500s", "gyro_drift_step", "gyro_drift", 10.0 * 3.141592653589793 / 180 / 3600),
])
def test_faulty_flights_alarm_after_500s_and_glr_isolates(capsys, repo_root, bag_name, hypothesis,
                                                          element, magnitude):
    bag = repo_root / "bags" / bag_name
    res = _analyze(capsys, bag)
    _check_schema(res, bag)
    first = res["in_flight"]["first_alarm_s"]
    assert first is not None and 500.0 < first < 600.0
    post = res["post_flight"]
    stats = post["glr"]["statistics"]
    assert max(stats, key=stats.get) in (hypothesis, "accel_bias_ramp")
    if element == "accel_bias":
        fault = post["fault"]
        assert post["verdict"] == "failure" and post["element"] == element
        assert post["isolation"] == "single"
    else:
        # a gyro drift step and an accelerometer ramp are the same on one velocity channel:
        # ambiguous, both named, no sensor declared
        assert post["verdict"] == "ambiguous" and post["fault"] is None
        assert {c["hypothesis"] for c in post["candidates"]} == {hypothesis, "accel_bias_ramp"}
        assert "gyro x: drift step" in post["headline"]
        fault = next(c for c in post["candidates"] if c["hypothesis"] == hypothesis)
    assert abs(fault["onset_s"] - 500.0) <= 5.0
    assert fault["magnitude"] == pytest.approx(magnitude, rel=0.15)


def test_text_table(capsys, repo_root):
    assert main(["analyze", str(repo_root / "bags" / "accel_fault_500s")]) == 0
    out = capsys.readouterr().out
    assert "FAILURE: accelerometer x: bias step of +1.5 mg (0.0147 m/s^2) at 499.5 s" in out
    assert "accel_bias_step" in out and "gyro_drift" in out and "methods disagree: " in out


@pytest.mark.parametrize("make_bad, message", [
    (lambda d: d / "missing", "does not exist"),
    (lambda d: (d / "empty").mkdir() or d / "empty", "not a rosbag2 bag"),
    (lambda d: (d / "x.mcap").write_bytes(b"\x89MCAP0\r\n garbage") or d / "x.mcap", ""),
])
@pytest.mark.parametrize("jobs", ["1", "2"])  # with 2 the bag is read in a forked child
def test_bad_bag_is_one_line_and_nonzero_exit(tmp_path, make_bad, message, jobs):
    bag = make_bad(tmp_path)
    proc = subprocess.run([sys.executable, "-m", "flight_fdi.cli.main", "analyze", str(bag),
                           "--jobs", jobs], capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("flight-fdi analyze: error:"), proc.stderr
    assert "Traceback" not in proc.stderr and message in lines[0]


def test_one_and_two_jobs_give_the_same_json(repo_root):
    bag = str(repo_root / "bags" / "accel_fault_500s")
    outs = [subprocess.run([sys.executable, "-m", "flight_fdi.cli.main", "analyze", bag, "--json",
                            "--jobs", jobs], capture_output=True, text=True, timeout=120,
                           check=True).stdout for jobs in ("1", "2")]
    assert json.loads(outs[0]) == json.loads(outs[1])
    assert json.loads(outs[0])["post_flight"]["glr"]["hypothesis"] == "accel_bias_step"


def test_bag_without_the_topics(tmp_path, capsys):
    from flight_fdi.bagio import open_writer

    bag = tmp_path / "other"
    with open_writer(bag) as w:
        from flight_fdi.bagio import get_typestore

        String = get_typestore().types["std_msgs/msg/String"]
        w.write("/chatter", "std_msgs/msg/String", String(data="hi"), 1_700_000_000_000_000_000)
    assert main(["analyze", str(bag)]) == 1
    err = capsys.readouterr().err
    assert "/ins/velocity" in err and len(err.strip().splitlines()) == 1


def test_invalid_option_values(capsys, repo_root):
    bag = str(repo_root / "bags" / "nominal")
    assert main(["analyze", bag, "--gate-probability", "2"]) == 1
    assert "probability" in capsys.readouterr().err
    assert main(["analyze", bag, "--alarm", "banana"]) == 1
    assert "M/N" in capsys.readouterr().err
    assert main(["analyze", bag, "--model", "no_such_model"]) == 1
    assert "unknown model" in capsys.readouterr().err


_FRESH_ANALYZE = """
import contextlib, io, json, sys
from flight_fdi.cli.main import main
out = io.StringIO()  # (the JSON result, and numba's cache messages with NUMBA_DEBUG_CACHE)
with contextlib.redirect_stdout(out):
    rc = main(["analyze", sys.argv[1], "--json", "--jobs", sys.argv[2] if len(sys.argv) > 2 else "1"])
print(*[ln for ln in out.getvalue().splitlines() if ln.startswith("[cache]")], sep="\\n")
print(json.dumps({"rc": rc, "modules": sorted(sys.modules)}))
"""


@pytest.mark.parametrize("jobs", ["1", "2"])  # with 2 the arrays come from the forked read
def test_fresh_analyze_imports_only_what_it_uses(repo_root, jobs):
    """A fresh ``analyze`` imports neither the campaign engine (dask), the JSON Schema checker,
    matplotlib, SciPy's statistics, special functions or root finders (``core/special``
    replaces them), ``scipy.linalg`` (numba's BLAS check finds the one module it needs,
    ``cli.analyze._load_cython_blas``) nor ``coverage`` (which numba would import for its
    coverage hook), and compiles nothing (every kernel comes from the cache ``make setup``
    warms)."""
    env = {**os.environ, "NUMBA_DEBUG_CACHE": "1"}
    env.pop("COVERAGE_PROCESS_START", None)
    proc = subprocess.run([sys.executable, "-c", _FRESH_ANALYZE,
                           str(repo_root / "bags" / "nominal"), jobs], capture_output=True,
                          text=True, timeout=120, env=env)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    out = json.loads(lines[-1])
    assert out["rc"] == 0
    top = {m.split(".")[0] for m in out["modules"]}
    assert not top & {"dask", "distributed", "jsonschema", "matplotlib", "coverage"}, top
    assert not {"scipy.stats", "scipy.special", "scipy.optimize", "scipy.linalg"} \
        & set(out["modules"])
    assert "numba" in top and "scipy.linalg.cython_blas" in out["modules"]
    cache = [ln for ln in lines if ln.startswith("[cache]")]
    assert any("data loaded" in ln for ln in cache)
    assert not [ln for ln in cache if "saved" in ln], cache


def test_blas_module_loaded_alone_serves_numba_and_a_later_scipy_linalg():
    """After ``import_numba`` (SciPy's BLAS module loaded without its package) numba's compiled
    ``np.dot`` works, and so does a later ``import scipy.linalg``, with the same module."""
    code = ("import sys\n"
            "import numpy as np\n"
            "from flight_fdi.cli.analyze import import_numba\n"
            "import_numba()\n"
            "import numba\n"
            "a = np.arange(6.0).reshape(2, 3)\n"
            "dot = numba.njit(lambda x, y: np.dot(x, y))(a, a.T)\n"
            "assert 'scipy.linalg' not in sys.modules\n"
            "assert np.array_equal(dot, a @ a.T), dot\n"
            "blas = sys.modules['scipy.linalg.cython_blas']\n"
            "import scipy.linalg\n"
            "from scipy.linalg import cython_blas\n"
            "assert cython_blas is blas\n"
            "assert np.allclose(scipy.linalg.expm(np.zeros((2, 2))), np.eye(2))\n"
            "print('ok')\n")
    env = {k: v for k, v in os.environ.items() if k != "COVERAGE_PROCESS_START"}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300, env=env)
    assert proc.returncode == 0 and proc.stdout.split() == ["ok"], proc.stderr


def test_preload_loads_every_kernel_the_analysis_uses(repo_root):
    """``analyze --jobs 2`` loads the kernels (``core.warmup.preload``) while its child reads
    the bag: after it, the analysis of a flight loads no more machine code."""
    code = ("import sys\n"
            "from flight_fdi.core.models import ins_channel\n"
            "from flight_fdi.core.warmup import preload\n"
            "preload(ins_channel())\n"
            "print('--- analysis', flush=True)\n" + _FRESH_ANALYZE)
    proc = subprocess.run([sys.executable, "-c", code, str(repo_root / "bags" / "accel_fault_500s")],
                          capture_output=True, text=True, timeout=120, check=True,
                          env={**os.environ, "NUMBA_DEBUG_CACHE": "1"})
    before, after = proc.stdout.split("--- analysis")
    assert before.count("data loaded") >= 3
    assert "data loaded" not in after and "saved" not in after
