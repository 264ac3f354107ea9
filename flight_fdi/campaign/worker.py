"""What every Dask worker of the campaign engine runs when it joins (a worker plugin,
registered by :class:`flight_fdi.campaign.engine.Engine`; a separate module because it
imports ``distributed``, which the inline engine never needs)."""
from __future__ import annotations

import logging
import os
import sys
from typing import Any, Callable

from distributed import WorkerPlugin

from flight_fdi.core.threads import ENV

#: glibc's own limits once its dynamic thresholds have grown (64-bit): arrays up to 32 MB from
#: the heap, the heap's top returned to the system above 64 MB free
MMAP_THRESHOLD = 32 << 20
TRIM_THRESHOLD = 64 << 20


class WorkerSetup(WorkerPlugin):
    """Run on each worker as it joins (a Dask worker plugin, registered by
    :class:`~.engine.Engine`): fix glibc's malloc thresholds (:func:`restore_malloc`: Dask's
    nanny freezes them low), give each analysis one thread (``FLIGHT_FDI_THREADS=1``), then run ``warm``."""

    #: registered once per cluster and name: a later engine on the same cluster (the next
    #: batch) does not set up and warm its workers again
    idempotent = True

    def __init__(self, warm: Callable[[], Any] | None = None) -> None:
        self.warm = warm

    def setup(self, worker: Any) -> None:
        restore_malloc()
        # a worker is one core: one analysis thread (core.threads), as the nanny gives BLAS one
        os.environ[ENV] = "1"
        if self.warm is not None:
            try:
                self.warm()
            except Exception:  # the task itself will say what is wrong, per task
                logging.getLogger(__name__).exception("warming the worker failed")


def restore_malloc() -> bool:
    """Fix glibc's mmap and trim thresholds at the values its dynamic thresholds reach by
    themselves (:data:`MMAP_THRESHOLD`, :data:`TRIM_THRESHOLD`), so that a flight's arrays are
    reused from the heap instead of faulting in fresh pages at every allocation. Needed where the
    nanny set ``MALLOC_TRIM_THRESHOLD_`` (Dask's default for the workers of ``dask worker``:
    ~27 000 page faults per 1000-s flight), and worth it on every worker: with glibc's dynamic
    thresholds a worker still faulted 1 000-1 700 pages per flight (the same analysis in a
    plain loop: ~5; which allocations of the worker keep glibc's thresholds low was not pinned
    down), ~190 with them fixed (docs/scaling.md). The cost: up to 64 MB of
    free heap kept per malloc arena. True when it set them (Linux with glibc)."""
    if not sys.platform.startswith("linux"):  # pragma: no cover - not Linux
        return False
    import ctypes

    try:
        libc = ctypes.CDLL("libc.so.6")
        m_trim_threshold, m_mmap_threshold = -1, -3  # <malloc.h>
        return bool(libc.mallopt(m_mmap_threshold, MMAP_THRESHOLD)
                    and libc.mallopt(m_trim_threshold, TRIM_THRESHOLD))
    except (OSError, AttributeError):  # pragma: no cover - not glibc
        return False


def warm_analysis() -> None:
    """The ``warm`` of the batch and the studies: import the analysis (and the simulator) and
    load its compiled kernels from numba's cache -- ~1.4 s a worker would otherwise spend in its
    first flight (compiling them where the cache is missing)."""
    import flight_fdi.cli.analyze  # noqa: F401
    import flight_fdi.sim  # noqa: F401
    from flight_fdi.core.warmup import warm

    warm()


def warm_analysis3d() -> None:
    """The ``warm`` of ``batch --model ins3d``: import the 3-D analysis and load its compiled
    kernels (``flight_fdi.warmup.warm_ins3d``, what ``make setup`` compiles them with: a short
    simulated 3-D flight analysed both ways; ~2 s from numba's cache), which
    :func:`warm_analysis` (the single-axis kernels) leaves to the worker's first flight."""
    import flight_fdi.cli.ins3d  # noqa: F401
    from flight_fdi.warmup import warm_ins3d

    warm_ins3d()


def warm_for(model: str | None) -> Callable[[], None]:
    """The workers' ``warm`` for a batch of ``model`` (``--model``)."""
    return warm_analysis3d if model == "ins3d" else warm_analysis
