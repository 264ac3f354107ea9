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


WARMED: list[int] = []


def warm_here() -> None:
    """A worker's ``warm``: records that it ran in this process."""
    WARMED.append(os.getpid())


def warmed(_x: int) -> list[int]:
    return list(WARMED)


def page_faults_of_big_arrays(_x: int = 0, n: int = 40) -> dict:
    """Minor page faults of allocating, touching and freeing a 1 MB array ``n`` times (what a
    flight's analysis does with its arrays), and the worker's malloc/BLAS environment."""
    import resource

    from flight_fdi.core.threads import usable_threads

    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(n):
        a = np.ones(1 << 17)
        del a
    return {"faults": resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before,
            "trim": os.environ.get("MALLOC_TRIM_THRESHOLD_"),
            "blas": os.environ.get("OPENBLAS_NUM_THREADS"),
            "analysis_threads": usable_threads()}
