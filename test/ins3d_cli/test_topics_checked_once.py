"""``analyze --model ins3d`` and ``run --model ins3d`` check the bag's contract topics once
(before: ``check_topics`` and then the reader's own check of the same topics), with the same
one-line error for a bag without them."""
from __future__ import annotations

import functools

import pytest

from flight_fdi.cli.main import main

BAG = "bags/ins3d_nominal"


@pytest.fixture
def checks(monkeypatch):
    """The calls of the one topic check (``bagio.ins3d_input._check_available``)."""
    from flight_fdi.bagio import ins3d_input

    calls: list = []
    real = ins3d_input._check_available

    @functools.wraps(real)
    def spy(path, names, have):
        calls.append(path)
        return real(path, names, have)

    monkeypatch.setattr(ins3d_input, "_check_available", spy)
    return calls


def _stop(*args, **kwargs):
    from flight_fdi.cli.errors import CliError

    raise CliError("stopped here")


def test_analyze_checks_the_topics_once(checks, monkeypatch, capsys):
    import flight_fdi.core.ins3d.analysis

    monkeypatch.setattr(flight_fdi.core.ins3d.analysis, "analyze_ins3d", _stop)  # after the read
    assert main(["analyze", BAG, "--model", "ins3d"]) == 1
    assert capsys.readouterr().err == "flight-fdi analyze: error: stopped here\n"
    assert [str(p) for p in checks] == [BAG]


def test_run_checks_the_topics_once_before_any_node(checks, monkeypatch, tmp_path, capsys):
    from flight_fdi.nodes import pipeline_graph

    # the inputs are read and checked before the graph: stop there, before any node
    monkeypatch.setattr(pipeline_graph.Graph, "__enter__", _stop)
    out = tmp_path / "o"
    assert main(["run", BAG, "--model", "ins3d", "--out", str(out), "--no-progress"]) == 1
    assert capsys.readouterr().err == "flight-fdi run: error: stopped here\n"
    assert [str(p) for p in checks] == [BAG]


@pytest.mark.parametrize("command", ["analyze", "run"])
def test_a_single_axis_bag_is_one_line(command, checks, tmp_path, capsys):
    extra = ["--out", str(tmp_path / "o")] if command == "run" else []
    assert main([command, "bags/nominal", "--model", "ins3d", *extra]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"flight-fdi {command}: error: bag ")
    assert "no topic /ins/imu" in err and "single-axis bag?" in err
    assert len(checks) == 1 and not (tmp_path / "o").exists()
