"""The forked worker (``core.forked``, what ``flight-fdi analyze --jobs 2`` reads the bag with):
errors and interruptions handled, no child left behind."""
from __future__ import annotations

import os
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from flight_fdi.core.errors import CoreError
from flight_fdi.core.forked import ForkedCall, can_fork, fork_call

needs_fork = pytest.mark.skipif(not hasattr(os, "fork"), reason="no os.fork")


def _square_sum(a, offset=0.0):
    return float(np.sum(a * a)) + offset, os.getpid()


def _fail(msg):
    raise CoreError(msg)


def _arrays(n):
    """Arrays of several dtypes and odd sizes (their out-of-band buffers' offsets must still
    leave each aligned), a non-contiguous one (pickled in band) and a plain object."""
    rng = np.random.default_rng(7)
    return {"odd": np.arange(3, dtype=np.int8), "x": rng.normal(size=n),
            "ns": np.arange(n, dtype=np.int64) * 20_000_000 + 3, "every_other": np.arange(9.0)[::2],
            "matrix": rng.normal(size=(n // 7, 3)), "empty": np.empty(0), "name": "flight"}


def _die():
    os._exit(3)


def _sleep_forever():
    while True:
        time.sleep(1.0)


def _children_of(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as fh:
            return [int(p) for p in fh.read().split()]
    except OSError:
        return []


def _in_clean_process(code: str) -> str:
    """Run ``code`` in a fresh single-threaded interpreter (pytest's process may hold threads
    left by other tests, and then nothing forks)."""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_runs_inline_when_told_or_when_other_threads_exist():
    job = ForkedCall(_square_sum, (np.arange(4.0),), {"offset": 1.0}, fork=False)
    assert not job.forked and job.result() == (15.0, os.getpid())
    stop = threading.Event()
    th = threading.Thread(target=stop.wait)
    th.start()
    try:
        assert not can_fork()
        with fork_call(_square_sum, np.arange(3.0)) as job:
            assert not job.forked
            assert job.result() == (5.0, os.getpid())
    finally:
        stop.set()
        th.join()


@needs_fork
def test_forked_result_error_death_and_cancel():
    out = _in_clean_process(
        f"import sys; sys.path.insert(0, {os.path.dirname(__file__)!r})\n"
        "import os, time\n"
        "import numpy as np\n"
        "from flight_fdi.core.errors import CoreError\n"
        "from flight_fdi.core.forked import fork_call\n"
        "import test_forked as T\n"
        "a = np.random.default_rng(1).normal(size=100_000)\n"
        "with fork_call(T._square_sum, a, offset=2.0) as job:\n"
        "    assert job.forked\n"
        "    value, pid = job.result()\n"
        "assert pid != os.getpid() and value == float(np.sum(a * a)) + 2.0\n"
        "with fork_call(T._fail, 'bad thing') as job:\n"
        "    try:\n"
        "        job.result()\n"
        "    except CoreError as exc:\n"
        "        assert str(exc) == 'bad thing'\n"
        "    else:\n"
        "        raise AssertionError('no error')\n"
        "with fork_call(T._die) as job:\n"
        "    try:\n"
        "        job.result()\n"
        "    except CoreError as exc:\n"
        "        assert 'without a result' in str(exc)\n"
        "t0 = time.monotonic()\n"
        "with fork_call(T._sleep_forever) as job:\n"
        "    child = job._pid\n"
        "assert time.monotonic() - t0 < 10\n"
        "assert T._children_of(os.getpid()) == []\n"
        "try:\n"
        "    os.kill(child, 0)\n"
        "except ProcessLookupError:\n"
        "    print('reaped')\n")
    assert out.split() == ["reaped"]


@needs_fork
def test_forked_arrays_arrive_equal_aligned_and_writable():
    """The hand-over of a result larger than the pipe (arrays out of band, read into one block):
    every value equal, each array C-contiguous, aligned and writable like the child's (numba
    compiles another signature for an unaligned or read-only array)."""
    out = _in_clean_process(
        f"import sys; sys.path.insert(0, {os.path.dirname(__file__)!r})\n"
        "import numpy as np\n"
        "from flight_fdi.core.forked import fork_call\n"
        "import test_forked as T\n"
        "with fork_call(T._arrays, 1_000_003) as job:\n"
        "    got = job.result()\n"
        "want = T._arrays(1_000_003)\n"
        "assert got.keys() == want.keys() and got['name'] == 'flight'\n"
        "for k, v in want.items():\n"
        "    if isinstance(v, np.ndarray):\n"
        "        g = got[k]\n"
        "        assert g.dtype == v.dtype and g.shape == v.shape and np.array_equal(g, v), k\n"
        "        assert g.flags.c_contiguous and g.flags.aligned and g.flags.writeable, k\n"
        "        assert g.ctypes.data % 64 == 0 or g.size == 0 or k == 'every_other', k\n"
        "got['x'][0] = 1.0\n"
        "print(sum(v.nbytes for v in want.values() if isinstance(v, np.ndarray)) > 2 ** 24)\n")
    assert out.split() == ["True"]


def test_jobs_is_validated():
    from flight_fdi.core.analysis import AnalysisConfig

    for bad in (0, 3, 1.5, True, "2"):
        with pytest.raises(CoreError, match="jobs must be 1 or 2"):
            AnalysisConfig(jobs=bad)
