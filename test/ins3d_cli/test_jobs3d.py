"""``flight-fdi analyze --model ins3d --jobs N`` bounds the 3-D analysis's threads to N cores
(before: --jobs was silently ignored with --model ins3d)."""
from __future__ import annotations

import functools
import json
import os
import time

import pytest

from flight_fdi.cli.main import main
from flight_fdi.core import threads
from flight_fdi.core.ins3d import analysis


def _seen_inside(monkeypatch) -> list[tuple[int, int]]:
    """(cores of the affinity, usable_threads()) as the analysis starts, per call."""
    seen: list[tuple[int, int]] = []
    real = analysis.analyze_ins3d

    @functools.wraps(real)                      # its signature: the recorded error model
    def spy(*a, **k):
        seen.append((len(os.sched_getaffinity(0)), threads.usable_threads()))
        return real(*a, **k)

    monkeypatch.setattr(analysis, "analyze_ins3d", spy)
    return seen


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="needs two cores to bound to one")
def test_jobs_1_runs_the_analysis_on_one_core_with_the_same_result(bag3d, capsys,
                                                                  monkeypatch):
    monkeypatch.delenv(threads.ENV, raising=False)
    seen = _seen_inside(monkeypatch)
    before = os.sched_getaffinity(0)
    cpu0, wall0 = time.process_time(), time.perf_counter()
    assert main(["analyze", str(bag3d), "--model", "ins3d", "--json", "--jobs", "1"]) == 0
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    one = json.loads(capsys.readouterr().out)
    assert seen == [(1, 1)]                     # one core, and the analysis knows it
    # measured: the whole process's CPU time (every thread) is at most the wall time
    assert cpu <= 1.02 * wall + 0.1, (cpu, wall)
    # restored after: the affinity and no FLIGHT_FDI_THREADS left behind
    assert os.sched_getaffinity(0) == before and threads.ENV not in os.environ
    assert main(["analyze", str(bag3d), "--model", "ins3d", "--json", "--jobs", "2"]) == 0
    two = json.loads(capsys.readouterr().out)
    assert seen[1] == (2, 2)
    assert one == two                           # the threads change the time, not the numbers


def test_a_lower_flight_fdi_threads_wins_and_is_kept(monkeypatch):
    from flight_fdi.cli.ins3d import bounded_cores

    monkeypatch.setenv(threads.ENV, "1")
    before = os.sched_getaffinity(0)
    with bounded_cores(2):
        assert threads.usable_threads() == 1 and len(os.sched_getaffinity(0)) == 1
    assert os.environ[threads.ENV] == "1" and os.sched_getaffinity(0) == before
    with bounded_cores(None):                   # no bound asked: nothing changed
        assert os.sched_getaffinity(0) == before
