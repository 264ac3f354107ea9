"""``flight-fdi run --timeout S``: the bound on the whole run (the pipeline's ``timeout_s``, 600 s
by default) on the command line, as ``--stall-timeout`` and ``--teardown-timeout``
(test_run_bounds.py): validated (one line, exit 1, nothing written; a malformed command line exit
2), listed by ``--help``, passed to both models' pipelines, and acted on (one line naming the
bound; the recording closed cleanly)."""
from __future__ import annotations

from pathlib import Path

import harness  # noqa: F401  (private ROS domain)
import pytest
# the 20-s flight of the shutdown tests (module fixture, reused)
from nodes.test_pipeline_shutdown import _assert_closed_cleanly, small_bag  # noqa: F401
from nodes.test_run_bounds import recorder_stops_after_50, run_help  # noqa: F401

from flight_fdi.cli.main import main

REPO = Path(__file__).resolve().parents[2]


def test_help_lists_the_timeout(capsys):
    text = run_help(capsys)
    assert "--timeout S end the run with an error when its work (replay, recording, analysis) " \
           "is not done after S seconds (1 to 86400; default 600)" in text


def test_the_help_default_is_the_pipelines():
    from flight_fdi.nodes.pipeline import TIMEOUT_S, run_pipeline_detailed
    from flight_fdi.nodes.ins3d_pipeline import run_pipeline3d

    assert TIMEOUT_S == 600.0
    for fn in (run_pipeline_detailed, run_pipeline3d):
        assert fn.__kwdefaults__["timeout_s"] == TIMEOUT_S


@pytest.mark.parametrize("value", ["0", "0.5", "86401", "nan", "inf", "-1", "ten", ""])
def test_a_bad_timeout_is_one_line_and_exit_1_before_anything(tmp_path, capsys, value):
    bag = tmp_path / "bag"
    bag.mkdir()
    out = tmp_path / "out"
    code = main(["run", str(bag), "--out", str(out), "--timeout", value])
    assert code == 1
    assert capsys.readouterr().err == ("flight-fdi run: error: --timeout: expected a number of "
                                       f"seconds from 1 to 86400, got {value!r}\n")
    assert not out.exists()


def test_a_timeout_without_its_value_is_a_usage_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["run", str(tmp_path), "--timeout"])
    assert exit_.value.code == 2
    assert capsys.readouterr().err == ("flight-fdi run: error: argument --timeout: expected one "
                                       "argument\n")


def _stop_in(monkeypatch, module, name: str) -> list[dict]:
    """Replace ``module.name`` (a pipeline) by one that records its keywords and fails."""
    from flight_fdi.nodes.pipeline import PipelineError

    calls: list[dict] = []

    def fake(*args, **kwargs):
        calls.append(kwargs)
        raise PipelineError("stopped here")

    monkeypatch.setattr(module, name, fake)
    return calls


def test_the_timeout_reaches_the_single_axis_pipeline(tmp_path, monkeypatch, capsys):
    from flight_fdi.nodes import pipeline

    calls = _stop_in(monkeypatch, pipeline, "run_pipeline_detailed")
    bag = tmp_path / "bag"
    bag.mkdir()
    assert main(["run", str(bag), "--out", str(tmp_path / "out"), "--timeout", "1800"]) == 1
    assert main(["run", str(bag), "--out", str(tmp_path / "out")]) == 1
    given, default = calls
    assert given["timeout_s"] == 1800.0
    assert "timeout_s" not in default   # the pipeline's own default
    assert capsys.readouterr().err.count("flight-fdi run: error: stopped here\n") == 2


def test_the_timeout_reaches_the_ins3d_pipeline(tmp_path, monkeypatch, capsys):
    from flight_fdi.nodes import ins3d_pipeline

    calls = _stop_in(monkeypatch, ins3d_pipeline, "run_pipeline3d")
    bag = REPO / "bags" / "ins3d_nominal"
    assert main(["run", str(bag), "--model", "ins3d", "--out", str(tmp_path / "out"),
                 "--timeout", "7200", "--stall-timeout", "90"]) == 1
    (given,) = calls
    assert (given["timeout_s"], given["stall_timeout_s"]) == (7200.0, 90.0)
    assert capsys.readouterr().err == "flight-fdi run: error: stopped here\n"


def test_the_timeout_option_ends_a_run_that_is_not_done(small_bag, tmp_path,  # noqa: F811
                                                        recorder_stops_after_50,  # noqa: F811
                                                        capfd):
    """The recorder stops after 50 messages; the stall bound is far away: the run's own bound
    ends it, one line naming it; the recording holds what was recorded (the 50 messages, fewer
    when the machine is so loaded that the bound comes first), closed cleanly."""
    code = main(["run", str(small_bag), "--out", str(tmp_path), "--no-report", "--no-progress",
                 "--timeout", "3", "--stall-timeout", "3600"])
    err = capfd.readouterr().err.splitlines()
    assert code == 1
    (line,) = [ln for ln in err if "error" in ln]
    assert line.startswith("flight-fdi run: error: pipeline timed out while ")
    assert line.endswith(" (the run's bound: 3 s)")
    assert _assert_closed_cleanly(tmp_path / "recording") <= 50
    assert not (tmp_path / "result.json").exists()
