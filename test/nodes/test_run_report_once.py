"""``flight-fdi run``'s report reads once and analyses once (both models).

The run already has the analysis (the smoother's, of the recording) and the input bag read
before the replay (with the simulator's truth): the report of ``run`` is drawn from them --
before, it read the recording and the input bag again and analysed again (0.5-3 s of CPU).
Checked: one analysis per run+report, one read of the input bag's data before the replay
(single-axis ``read_flight``; 3-D the raw read of the contract topics with the truth) and
the same report, file for file, as ``flight-fdi report RUN_FOLDER`` (the route that rebuilds
it from the recording, which the run used before).
"""
from __future__ import annotations

import functools
from pathlib import Path

import harness  # noqa: F401  (private ROS domain)
import pytest
# the 20-s single-axis and 60-s 3-D flights with a fault (and /sim/truth) of the bounds tests
from nodes.test_run_bounds import faulty_bag as bag2d  # noqa: F401
from nodes.test_run_bounds3d import faulty_bag3d as bag3d  # noqa: F401

from flight_fdi.cli.main import main


def _spy(monkeypatch, module, name: str, calls: list) -> None:
    real = getattr(module, name)

    @functools.wraps(real)      # (its signature too: error_model_used reads analyze_ins3d's)
    def spy(*args, **kwargs):
        calls.append(args[0] if args else None)
        return real(*args, **kwargs)

    monkeypatch.setattr(module, name, spy)


def _same_files(a: Path, b: Path) -> None:
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir()) and "index.html" in names
    for name in names:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name


@pytest.mark.timeout(300)
def test_the_single_axis_run_reports_without_a_second_read_or_analysis(bag2d, tmp_path,
                                                                      monkeypatch, capfd):
    import flight_fdi.bagio
    import flight_fdi.core.analysis

    analyses: list = []
    reads: list = []
    _spy(monkeypatch, flight_fdi.core.analysis, "analyze_forward", analyses)
    _spy(monkeypatch, flight_fdi.bagio, "read_flight", reads)
    out = tmp_path / "run"
    assert main(["run", str(bag2d), "--out", str(out), "--no-progress"]) == 0
    assert "report (figures and verdict):" in capfd.readouterr().out
    assert len(analyses) == 1 and [Path(r) for r in reads] == [bag2d]
    page = (out / "report" / "index.html").read_text()
    assert "Rebuilt from the recording" in page and "true error" in page   # the truth drawn
    # the report of the run folder (recording read and analysed again) is the same, file for file
    assert main(["report", str(out), "--out", str(tmp_path / "again")]) == 0
    assert len(analyses) == 2
    _same_files(out / "report", tmp_path / "again")


@pytest.mark.timeout(300)
def test_the_3d_run_reports_without_a_second_read_or_analysis(bag3d, tmp_path, monkeypatch,
                                                             capfd):
    import flight_fdi.bagio.reader
    import flight_fdi.core.ins3d.analysis
    import flight_fdi.bagio.recording_analysis

    analyses: list = []
    recordings: list = []
    raw_reads: list = []
    _spy(monkeypatch, flight_fdi.core.ins3d.analysis, "analyze_ins3d", analyses)
    _spy(monkeypatch, flight_fdi.bagio.recording_analysis, "read_recording3d", recordings)
    _spy(monkeypatch, flight_fdi.bagio.reader, "read_topics_raw", raw_reads)
    out = tmp_path / "run"
    assert main(["run", str(bag3d), "--model", "ins3d", "--out", str(out),
                 "--no-progress"]) == 0
    assert "report (figures and verdict):" in capfd.readouterr().out
    assert len(analyses) == 1 and len(recordings) == 1
    # the inputs and the truth: one pass; the recording (smoother): one pass
    assert [Path(r) for r in raw_reads] == [bag3d, out / "recording"]
    page = (out / "report" / "index.html").read_text()
    assert "Rebuilt from the recording" in page and "no /sim/truth" not in page
    assert main(["report", str(out), "--out", str(tmp_path / "again")]) == 0
    assert len(analyses) == 2 and len(recordings) == 2
    _same_files(out / "report", tmp_path / "again")


def test_without_a_report_the_truth_is_not_read(bag2d, tmp_path, monkeypatch, capfd):
    """--no-report: the input is read without the truth (as before) and nothing is drawn."""
    import flight_fdi.bagio

    kinds: list = []
    real = flight_fdi.bagio.read_flight

    def spy(*args, **kwargs):
        kinds.append(kwargs.get("with_truth"))
        return real(*args, **kwargs)

    monkeypatch.setattr(flight_fdi.bagio, "read_flight", spy)
    out = tmp_path / "run"
    assert main(["run", str(bag2d), "--out", str(out), "--no-progress", "--no-report"]) == 0
    assert kinds == [False] and not (out / "report").exists()
