"""How many workers ``flight-fdi batch`` uses when --workers is not given
(``campaign.engine.auto_workers``, ``cli.batch.batch_engine_spec``; docs/scaling.md): one per
core, never more than flights, and this process when the estimated work
(``Batch.estimated_work``) would not pay for the local cluster's start -- a fleet of the three
sample bags ran in 5.6 s (single-axis) and 10-12 s (3-D) on a local cluster of 2 workers, in
1.3 s and 2.9-3.3 s in this process."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from flight_fdi.campaign import batch as batch_mod
from flight_fdi.campaign import engine as engine_mod
from flight_fdi.campaign.batch import Batch
from flight_fdi.campaign.engine import CLUSTER_COST_S, auto_workers
from flight_fdi.cli.main import build_parser, main

REPO = Path(__file__).resolve().parents[2]
BAGS = [str(REPO / "bags" / b) for b in ("nominal", "accel_fault_500s", "gyro_fault_500s")]


def _args(*argv: str):
    return build_parser("batch").parse_args(["batch", *argv])


def test_auto_workers_one_per_core_at_most_one_per_task_none_for_small_work():
    big = 100 * CLUSTER_COST_S
    assert auto_workers(3, big, cores=2) == 2
    assert auto_workers(3, big, cores=8) == 3         # never more workers than tasks
    assert auto_workers(1, big, cores=8) == 1         # one task: this process
    assert auto_workers(0, 0.0, cores=8) == 1
    assert auto_workers(3, big, cores=1) == 1
    # two workers save half the work: the cluster from 2 x its cost on
    assert auto_workers(50, 2 * CLUSTER_COST_S - 0.01, cores=2) == 1
    assert auto_workers(50, 2 * CLUSTER_COST_S + 0.01, cores=2) == 2
    # four workers save three quarters of it
    assert auto_workers(50, 4 / 3 * CLUSTER_COST_S + 0.01, cores=4) == 4


def test_the_estimate_counts_the_flights_to_analyse_and_the_reports(tmp_path):
    out = tmp_path / "fleet"
    batch = Batch(BAGS, out, _args(*BAGS, "--out", str(out)))
    megabytes = sum(batch_mod.bag_megabytes(Path(b)) for b in BAGS)
    assert 7.0 < megabytes < 8.0
    tasks, work = batch.estimated_work()
    assert tasks == 3 and work == pytest.approx(batch_mod.ANALYSIS_S_PER_MB * megabytes)
    tasks, work_all = batch.estimated_work("all")
    assert tasks == 6 and work_all == pytest.approx(2 * work + 3 * batch_mod.REPORT_S)
    assert batch.estimated_work("nominal")[0] == 4
    # summing stops once the estimate is past what was asked
    assert batch.estimated_work("all", enough=0.0)[1] == pytest.approx(work / 3, rel=0.01)


def test_a_small_fleet_runs_in_this_process_by_default(tmp_path, capsys):
    out = tmp_path / "fleet"
    assert main(["batch", *BAGS, "--out", str(out), "--json", "--no-progress"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["engine"] == "this process (no cluster)"
    assert doc["analysed"] == 3
    # up to date: nothing to estimate
    batch = Batch(BAGS, out, _args(*BAGS, "--out", str(out)))
    assert batch.estimated_work() == (0, 0.0)
    assert batch.plan()[1] == [] and len(batch.plan()[0]) == 3


def test_a_large_work_gets_a_worker_per_core_and_per_flight(tmp_path, monkeypatch):
    from flight_fdi.cli.batch import batch_engine_spec

    monkeypatch.setattr(engine_mod, "default_workers", lambda: 8)
    monkeypatch.setattr(batch_mod, "ANALYSIS_S_PER_MB", 100.0)   # as if each bag took minutes
    out = str(tmp_path / "fleet")
    args = _args(*BAGS, "--out", out)
    spec = batch_engine_spec(args, Batch(BAGS, out, args))
    assert (spec.workers, spec.scheduler, spec.runs_inline) == (3, None, False)
    # what the user gives is kept
    args = _args(*BAGS[:1], "--out", out, "--workers", "2")
    assert batch_engine_spec(args, Batch(BAGS[:1], out, args)).workers == 2
    args = _args(*BAGS, "--out", out, "--scheduler", "tcp://127.0.0.1:1")
    spec = batch_engine_spec(args, Batch(BAGS, out, args))
    assert (spec.workers, spec.scheduler) == (None, "tcp://127.0.0.1:1")
