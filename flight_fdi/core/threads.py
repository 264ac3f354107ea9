"""How many threads one analysis may use in this process (one rule for every analysis).

The post-flight analyses run independent compiled parts side by side (the single-axis GLR's
fault systems, the 3-D backward sweep's combination and fault blocks); that pays only when the
process has cores to itself. A Dask worker of the campaign engine is one core: the engine sets
``FLIGHT_FDI_THREADS=1`` on its workers (as Dask's nanny sets the BLAS pools to one thread).
"""
from __future__ import annotations

import os

from .errors import CoreError

#: environment variable: the threads one analysis may use in this process (an integer >= 1)
ENV = "FLIGHT_FDI_THREADS"


def usable_threads() -> int:
    """``FLIGHT_FDI_THREADS`` when set, else the cores this process may run on."""
    text = os.environ.get(ENV, "").strip()
    if text:
        try:
            n = int(text)
        except ValueError:
            n = 0
        if n < 1:
            raise CoreError(f"{ENV} must be an integer >= 1, got {text!r}")
        return n
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)
