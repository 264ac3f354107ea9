"""Fixtures of the campaign tests: short simulated bags and a real Dask cluster (2 worker
processes, localhost only), always shut down."""
from __future__ import annotations

import pathlib
import shutil
import socket
import sys

import pytest

HERE = pathlib.Path(__file__).resolve().parent
if str(HERE) not in sys.path:  # campaign_tasks, for the workers too (they inherit sys.path)
    sys.path.insert(0, str(HERE))

#: short flights (200 s): name -> simulate options
FLIGHTS = {
    "nominal": ["--seed", "1"],
    "accel": ["--seed", "2", "--fault", "accel:step:t=100,mag=0.015"],
    "gyro": ["--seed", "3", "--fault", "gyro:step:t=100,mag=10deg/h"],
}


@pytest.fixture(scope="session")
def short_bags(tmp_path_factory) -> dict[str, pathlib.Path]:
    """Three 200-s bags made by ``flight-fdi simulate`` (nominal, accelerometer and gyro
    steps at 100 s)."""
    from flight_fdi.cli.main import main

    root = tmp_path_factory.mktemp("bags")
    out = {}
    for name, opts in FLIGHTS.items():
        assert main(["simulate", str(root / name), "--duration", "200", *opts]) == 0
        out[name] = root / name
    return out


def copy_fleet(bags: dict[str, pathlib.Path], dest: pathlib.Path, n: int) -> list[pathlib.Path]:
    """``n`` flights in dest/flight_XX (copies of the short bags, in turn)."""
    kinds = sorted(bags)
    made = []
    for i in range(n):
        target = dest / f"flight_{i:02d}"
        shutil.copytree(bags[kinds[i % len(kinds)]], target)
        made.append(target)
    return made


@pytest.fixture
def free_port():
    return _free_port


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="session")
def dask_cluster():
    """A LocalCluster of 2 worker processes (1 thread each) on 127.0.0.1; yields its
    scheduler address."""
    import logging
    import warnings

    from distributed import Client, LocalCluster

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Port .* is already in use")
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                               host="127.0.0.1", dashboard_address=None,
                               silence_logs=logging.ERROR)
    try:
        with Client(cluster) as client:
            client.wait_for_workers(2, timeout=60)
        yield cluster.scheduler_address
    finally:
        cluster.close()
