"""What the engine does to its Dask workers: glibc's malloc thresholds (Dask's nanny freezes the
mmap threshold at 128 kB through MALLOC_TRIM_THRESHOLD_, so every large array faults in fresh
pages: +37 % per flight, docs/scaling.md), one BLAS and one analysis thread per worker, and ``warm`` on each."""
from __future__ import annotations

import os

import pytest

from flight_fdi.campaign.engine import Engine, EngineSpec

from campaign_tasks import page_faults_of_big_arrays, warm_here, warmed

#: 40 x 1 MB: ~10 000 page faults when each array is a fresh mmap, a few hundred at most when
#: the heap is reused
FEW = 1000


@pytest.mark.filterwarnings("ignore:Port .* is already in use")
def test_dask_default_workers_get_the_heap_back_once_the_engine_sets_them_up():
    import logging

    from distributed import Client, LocalCluster

    # a cluster of its own with Dask's own worker settings, as `dask worker` has (the session's
    # clusters already had the engine's setup)
    with LocalCluster(n_workers=1, threads_per_worker=1, host="127.0.0.1",
                      dashboard_address=None, silence_logs=logging.ERROR) as cluster:
        with Client(cluster) as client:
            before = client.run(page_faults_of_big_arrays)
        with Engine(EngineSpec(scheduler=cluster.scheduler_address)) as engine:
            after = engine.client.run(page_faults_of_big_arrays)
            on_tasks = [r for _, r, _ in engine.run(page_faults_of_big_arrays, [0, 1, 2])]
    assert len(before) == 1 and all(r["trim"] == "65536" for r in before.values())
    assert all(r["faults"] > 8 * FEW for r in before.values()), before
    assert len(after) == 1 and all(r["faults"] < FEW for r in after.values()), after
    assert all(r["faults"] < FEW for r in on_tasks), on_tasks


def test_the_embedded_cluster_starts_its_workers_without_the_malloc_setting_and_warms_them():
    with Engine(EngineSpec(workers=1, inline=False), warm=warm_here) as engine:
        out = [r for _, r, _ in engine.run(page_faults_of_big_arrays, [0, 1])]
        pids = [r for _, r, _ in engine.run(warmed, [0])][0]
        workers = engine.client.run(os.getpid)
    # the engine does not set MALLOC_TRIM_THRESHOLD_ (a worker inherits this process's: in a
    # test session, the other clusters' nannies have put Dask's value here)
    assert all(r["trim"] == os.environ.get("MALLOC_TRIM_THRESHOLD_") for r in out), out
    assert all(r["blas"] == "1" for r in out), out
    assert all(r["analysis_threads"] == 1 for r in out), out  # one core per worker
    assert all(r["faults"] < FEW for r in out), out
    assert pids == list(workers.values())  # warmed once, in the worker process
