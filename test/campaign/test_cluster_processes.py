"""A Dask cluster of separate programs on localhost: ``dask scheduler`` and two ``dask worker``
processes. ``flight-fdi batch`` and ``flight-fdi montecarlo`` run against it with --scheduler;
a worker killed mid-batch loses no flight and duplicates none."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from flight_fdi.campaign.batch import Batch
from flight_fdi.campaign.engine import Engine, EngineSpec
from flight_fdi.cli.main import build_parser
from flight_fdi.eval.montecarlo import StudyConfig, run_study

from conftest import HERE, _free_port, copy_fleet

pytestmark = pytest.mark.slow

DASK = Path(sys.executable).parent / "dask"


def _stop(procs: list[subprocess.Popen]) -> None:
    """The workers (procs[1:]) first, then the scheduler (procs[0]) once they have ended: a
    worker whose scheduler went first waits for it until its nanny kills it after 8 s."""
    for group in (procs[1:], procs[:1]):
        for p in group:
            if p.poll() is None:
                p.terminate()
        for p in group:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=20)


@pytest.fixture(scope="module")
def dask_processes(tmp_path_factory):
    """tcp://127.0.0.1:PORT of a scheduler with two single-threaded workers (with nannies),
    each a program of its own."""
    from distributed import Client

    tmp = tmp_path_factory.mktemp("dask")
    address = f"tcp://127.0.0.1:{_free_port()}"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(HERE)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])}
    log = (tmp / "dask.log").open("w")
    procs: list[subprocess.Popen] = []
    try:
        procs.append(subprocess.Popen(
            [str(DASK), "scheduler", "--host", "127.0.0.1", "--port", address.rsplit(":", 1)[1],
             "--no-dashboard"], stdout=log, stderr=subprocess.STDOUT, env=env))
        for i in range(2):
            procs.append(subprocess.Popen(
                [str(DASK), "worker", address, "--name", f"w{i}", "--nthreads", "1",
                 "--host", "127.0.0.1", "--no-dashboard", "--local-directory", str(tmp)],
                stdout=log, stderr=subprocess.STDOUT, env=env))
        with Client(address, timeout=60) as client:  # retries until the scheduler listens
            client.wait_for_workers(2, timeout=90)
        yield address
    finally:
        _stop(procs)
        log.close()


def run_cli(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "flight_fdi.cli.main", *argv],
                          capture_output=True, text=True, timeout=300)


def test_batch_and_montecarlo_against_the_cluster(dask_processes, short_bags, tmp_path):
    bags = copy_fleet(short_bags, tmp_path / "fleet", 4)
    r = run_cli("batch", str(tmp_path / "fleet"), "--out", str(tmp_path / "out"),
                "--scheduler", dask_processes, "--json", "--no-progress")
    assert r.returncode == 0, r.stderr[-2000:]
    doc = json.loads(r.stdout)
    assert doc["engine"] == f"the Dask cluster at {dask_processes} (2 workers)"
    assert (doc["analysed"], doc["failed"]) == (len(bags), 0)
    assert sorted(f["flight"] for f in doc["flights"]) == [b.name for b in bags]
    sensors = [f["sensor"] for f in sorted(doc["flights"], key=lambda f: f["flight"])]
    assert sensors[0] == sensors[3] == "accelerometer" and sensors[2] is None
    assert "gyro" in sensors[1].split("|")

    records = tmp_path / "records.jsonl"
    full = tmp_path / "study.json"
    r = run_cli("montecarlo", "--nominal", "2", "--per-fault", "2", "--duration", "100",
                "--accel-levels", "5", "--gyro-levels", "10", "--seed", "7",
                "--scheduler", dask_processes, "--records", str(records), "--out", str(full),
                "--json", "--no-progress")
    assert r.returncode == 0, r.stderr[-2000:]
    assert json.loads(r.stdout)["jobs"] == 2
    header, *streamed = [json.loads(line) for line in records.read_text().splitlines()]
    assert header["records"] == "flight_fdi.study/1" and header["study"]["seed"] == 7
    stored = json.loads(full.read_text())["flights"]
    inline = run_study(StudyConfig(nominal=2, per_fault=2, accel_levels_mg=(5.0,),
                                   gyro_levels_deg_h=(10.0,), duration_s=100.0, seed=7), jobs=1)
    assert stored == inline.records  # same study in this process: the same records
    assert sorted(streamed, key=lambda d: d["index"]) == inline.records


def test_worker_killed_mid_batch_loses_and_duplicates_nothing(dask_processes, short_bags,
                                                               tmp_path):
    bags = copy_fleet(short_bags, tmp_path / "fleet", 12)
    args = build_parser("batch").parse_args(["batch", "IN", "--out", "OUT"])
    killed: dict = {}
    with Engine(EngineSpec(scheduler=dask_processes)) as engine:
        client = engine.client

        def kill_a_busy_worker(row: dict) -> None:
            if killed:
                return
            busy = {w: keys for w, keys in client.processing().items() if keys}
            assert busy, "no flight running after the first one finished"
            worker = sorted(busy)[0]
            pid = client.run(os.getpid, workers=[worker])[worker]
            os.kill(pid, signal.SIGKILL)
            killed.update(worker=worker, pid=pid, tasks=len(busy[worker]))

        res = Batch([str(tmp_path / "fleet")], tmp_path / "out", args).run(
            engine, on_flight=kill_a_busy_worker)
        # the nanny restarts the worker; the cluster is whole again
        engine.wait_for_workers(2, timeout=90)
    assert killed["tasks"] >= 1  # the worker died with flights on it
    names = [r["flight"] for r in res.rows]
    assert sorted(names) == sorted(b.name for b in bags)  # none lost, none twice
    assert [r for r in res.rows if r["error"]] == []
    assert (res.analysed, res.failed) == (12, 0)
    assert len(list((tmp_path / "out" / "flights").glob("*.json"))) == 12
    with open(tmp_path / "out" / "summary.csv") as f:
        assert len(f.read().splitlines()) == 1 + 12
