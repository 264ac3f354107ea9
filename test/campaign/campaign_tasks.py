"""Task functions of the engine tests, importable by the Dask workers as ``campaign_tasks``
(conftest puts this folder on sys.path; spawned workers inherit it, ``dask worker`` processes
get it through PYTHONPATH)."""
from __future__ import annotations

import os

import numpy as np


def square_or_fail(x: int) -> tuple[int, int, int]:
    """(x, x^2, worker pid); raises for x = 3 mod 7."""
    if x % 7 == 3:
        raise ValueError(f"task {x} fails on purpose")
    # ~10 ms of work that holds the GIL, so that both workers get tasks
    v = np.random.default_rng(x).standard_normal(200_000).sum()
    return x, x * x, os.getpid() if np.isfinite(v) else -1


def from_a_module_the_workers_lack(x: int) -> int:
    return x


# as if defined in a module that exists only where the batch is started
from_a_module_the_workers_lack.__module__ = "flight_fdi_not_installed_on_workers"
