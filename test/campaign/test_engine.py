"""The campaign engine on a real Dask cluster (2 worker processes), inline, and the Monte Carlo
study on it: the same records whatever the number of workers."""
from __future__ import annotations

import logging
import os

import pytest

from flight_fdi.campaign.engine import Engine, EngineError, EngineSpec, run_tasks
from flight_fdi.eval.montecarlo import StudyConfig, run_study

from campaign_tasks import square_or_fail

def check_outcomes(outcomes, n: int) -> set[int]:
    assert sorted(i for i, _, _ in outcomes) == list(range(n))  # each task once
    pids = set()
    for i, res, err in outcomes:
        if i % 7 == 3:
            assert res is None and isinstance(err, ValueError) and str(i) in str(err)
        else:
            assert err is None and res[:2] == (i, i * i)
            pids.add(res[2])
    return pids


def test_inline_runs_in_this_process_and_reports_errors_per_task():
    with Engine(EngineSpec(workers=1)) as engine:
        assert engine.kind == "inline" and engine.worker_count() == 1
        seen = []
        out = engine.run(square_or_fail, list(range(20)), on_outcome=lambda *o: seen.append(o))
    assert out == seen
    assert [i for i, _, _ in out] == list(range(20))  # inline: in order
    assert check_outcomes(out, 20) == {os.getpid()}


def test_two_worker_processes_share_the_tasks_and_errors_stay_per_task(dask_cluster):
    with Engine(EngineSpec(scheduler=dask_cluster)) as engine:
        assert engine.kind == "cluster" and engine.worker_count() == 2
        out = engine.run(square_or_fail, list(range(40)), window=4)
    pids = check_outcomes(out, 40)
    assert len(pids) == 2 and os.getpid() not in pids


def test_engine_starts_and_stops_its_own_local_cluster():
    with Engine(EngineSpec(workers=2)) as engine:
        assert engine.kind == "local" and engine.worker_count() == 2
        assert "local Dask cluster (2 workers)" in engine.describe()
        out = engine.run(square_or_fail, list(range(6)))
        cluster_client = engine.client
    check_outcomes(out, 6)
    assert engine.client is None and cluster_client.status == "closed"


def test_spec_validation():
    with pytest.raises(EngineError, match="workers"):
        EngineSpec(workers=0)
    with pytest.raises(EngineError, match="tcp://HOST:PORT"):
        EngineSpec(scheduler="localhost:8786")
    with pytest.raises(EngineError, match="exclude"):
        EngineSpec(scheduler="tcp://127.0.0.1:8786", inline=True)
    assert EngineSpec(workers=1).runs_inline and not EngineSpec(workers=2).runs_inline
    assert not EngineSpec(workers=1, inline=False).runs_inline


def test_unreachable_scheduler_is_one_clear_error(monkeypatch, free_port):
    monkeypatch.setenv("FLIGHT_FDI_DASK_TIMEOUT", "2")
    address = f"tcp://127.0.0.1:{free_port()}"
    with pytest.raises(EngineError, match="cannot reach the Dask scheduler"):
        run_tasks(square_or_fail, [1], EngineSpec(scheduler=address))


STUDY = StudyConfig(nominal=3, per_fault=3, accel_levels_mg=(2.0, 10.0),
                    gyro_levels_deg_h=(5.0, 30.0), duration_s=120.0, seed=11)


@pytest.mark.filterwarnings("ignore:Port .* is already in use")
def test_montecarlo_records_do_not_depend_on_the_number_of_workers(dask_cluster):
    from distributed import LocalCluster

    inline = run_study(STUDY, jobs=1)
    assert inline.jobs == 1 and "this process" in inline.engine
    two = run_study(STUDY, jobs=1, scheduler=dask_cluster)
    assert two.jobs == 2
    with LocalCluster(n_workers=1, threads_per_worker=1, host="127.0.0.1",
                      dashboard_address=None, silence_logs=logging.ERROR) as one_cluster:
        one = run_study(STUDY, scheduler=one_cluster.scheduler_address)
    assert one.jobs == 1 and "cluster" in one.engine
    assert len(inline.records) == 9
    assert one.records == inline.records == two.records
    assert one.metrics == inline.metrics == two.metrics
    # not a vacuous equality: the flights differ from each other
    assert len({r["sim_seed"] for r in inline.records}) == 9
    assert {r["kind"] for r in inline.records} == {"nominal", "accel", "gyro"}


def test_montecarlo_stops_on_the_first_failing_flight(dask_cluster):
    from flight_fdi.eval.montecarlo import parallel_map

    with pytest.raises(ValueError, match="task 3 fails"):
        parallel_map(square_or_fail, list(range(10)), scheduler=dask_cluster)
    with pytest.raises(ValueError, match="task 3 fails"):
        parallel_map(square_or_fail, list(range(10)), jobs=1)


def test_a_worker_that_cannot_import_the_task_is_one_clear_error(dask_cluster):
    from campaign_tasks import from_a_module_the_workers_lack

    with Engine(EngineSpec(scheduler=dask_cluster)) as engine:
        with pytest.raises(EngineError, match="2 Dask worker.*cannot import "
                                              "flight_fdi_not_installed_on_workers"):
            engine.run(from_a_module_the_workers_lack, [1, 2])
        # the engine is still usable
        assert [r for _, r, _ in engine.run(square_or_fail, [1])][0][:2] == (1, 1)


def _scheduler_tasks(dask_scheduler=None) -> int:
    return len(dask_scheduler.tasks)


def test_a_raising_callback_cancels_the_remaining_tasks(dask_cluster):
    import time

    def stop(i, res, err):
        raise KeyboardInterrupt  # e.g. Ctrl-C while a result is written

    with Engine(EngineSpec(scheduler=dask_cluster)) as engine:
        with pytest.raises(KeyboardInterrupt):
            engine.run(square_or_fail, list(range(200)), on_outcome=stop)
        deadline = time.monotonic() + 30
        while engine.client.run_on_scheduler(_scheduler_tasks) and time.monotonic() < deadline:
            engine.client.run_on_scheduler(_scheduler_tasks)  # spin on the scheduler's state
        assert engine.client.run_on_scheduler(_scheduler_tasks) == 0


def test_guided_chunks_are_large_first_and_single_at_the_end():
    from flight_fdi.campaign.engine import MAX_CHUNK, guided_chunks

    for n, threads in [(0, 1), (1, 1), (9, 2), (50, 1), (50, 2), (10_000, 2), (777, 64)]:
        sizes = list(guided_chunks(n, threads))
        assert sum(sizes) == n and all(1 <= s <= MAX_CHUNK for s in sizes)
        assert sizes == sorted(sizes, reverse=True)
        assert sizes[-threads:] == [1] * min(threads, n)  # the workers end together
    assert len(list(guided_chunks(50, 1))) == 15 and len(list(guided_chunks(50, 2))) == 25
    assert len(list(guided_chunks(10_000, 2))) < 10_000 / MAX_CHUNK + 20


def test_chunks_of_tasks_give_the_same_outcomes_one_by_one(dask_cluster):
    with Engine(EngineSpec(scheduler=dask_cluster)) as engine:
        out = engine.run(square_or_fail, list(range(40)), chunk=3, window=3)
        guided = engine.run(square_or_fail, list(range(200)))  # chunks of 8 down to 1
    pids = check_outcomes(out, 40)  # errors stay per task inside a chunk
    assert len(pids) == 2
    assert len(check_outcomes(guided, 200)) == 2
