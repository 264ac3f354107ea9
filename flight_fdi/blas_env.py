"""The BLAS threading of the project's processes, set before numpy loads.

The estimators' matrices are at most ~20 x 20: OpenBLAS's worker threads never pay there, and
whatever numpy product of a whole flight's arrays slips through to a multithreaded BLAS leaves
them spinning beside the compiled kernels (docs/performance.md). The ``flight-fdi`` command
(``cli/main.py``) and the ROS node executables (``nodes/__init__.py``, which every node module
imports first) therefore call :func:`one_blas_thread` before anything imports numpy; a user's own
``OPENBLAS_NUM_THREADS`` wins. This module imports nothing heavy.
"""
from __future__ import annotations

import os


def one_blas_thread() -> None:
    """OPENBLAS_NUM_THREADS=1 unless it is set (effective only before numpy is imported)."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def openblas_threads() -> int | None:
    """The number of threads numpy's bundled OpenBLAS uses in this process (imports numpy),
    or None when numpy has no bundled OpenBLAS this can ask."""
    import ctypes
    import glob
    from pathlib import Path

    import numpy as np

    for lib in sorted(glob.glob(str(Path(np.__file__).parents[1] / "numpy.libs" / "*openblas*"))):
        for name in ("scipy_openblas_get_num_threads64_", "openblas_get_num_threads"):
            fn = getattr(ctypes.CDLL(lib), name, None)
            if fn is not None:
                return int(fn())
    return None
