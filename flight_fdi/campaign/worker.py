"""What every Dask worker of the campaign engine runs when it joins (a worker plugin,
registered by :class:`flight_fdi.campaign.engine.Engine`; a separate module because it
imports ``distributed``, which the inline engine never needs)."""
from __future__ import annotations

import logging
import os
import sys
from typing import Any, Callable

from distributed import WorkerPlugin

#: glibc's own limits once its dynamic thresholds have grown (64-bit): arrays up to 32 MB from
#: the heap, the heap's top returned to the system above 64 MB free
MMAP_THRESHOLD = 32 << 20
TRIM_THRESHOLD = 64 << 20


class WorkerSetup(WorkerPlugin):
    """Run on each worker as it joins (a Dask worker plugin, registered by
    :class:`~.engine.Engine`): undo the malloc setting of Dask's nanny (:func:`restore_malloc`),
    then run ``warm``."""

    #: registered once per cluster and name: a later engine on the same cluster (the next
    #: batch) does not set up and warm its workers again
    idempotent = True

    def __init__(self, warm: Callable[[], Any] | None = None) -> None:
        self.warm = warm

    def setup(self, worker: Any) -> None:
        restore_malloc()
        if self.warm is not None:
            try:
                self.warm()
            except Exception:  # the task itself will say what is wrong, per task
                logging.getLogger(__name__).exception("warming the worker failed")


def restore_malloc() -> bool:
    """On a worker whose nanny set ``MALLOC_TRIM_THRESHOLD_`` (Dask's default for the workers of
    ``dask worker``; see :data:`WORKER_ENVIRON`): set glibc's mmap and trim thresholds to the
    values its dynamic thresholds reach by themselves, so that a flight's arrays are reused from
    the heap instead of faulting in fresh pages at every allocation. True when it did."""
    if "MALLOC_TRIM_THRESHOLD_" not in os.environ or not sys.platform.startswith("linux"):
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
