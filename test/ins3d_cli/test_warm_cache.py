"""After ``make setup`` the 3-D analysis only loads compiled code: with and without the
observability Gramian (the Monte Carlo engine leaves it out), on two threads (the forward
filter's discretisation then runs ahead on the second one) and on one; the nonlinear check's
exact removal of a large gyro fault and the relinearisation about a large attitude error."""
from __future__ import annotations

import os
import subprocess
import sys

_ANALYZE = """
import sys
from flight_fdi.bagio.ins3d_input import read_ins3d
from flight_fdi.core.ins3d.analysis import analyze_ins3d
from flight_fdi.core.ins3d.model import Ins3dModel
from flight_fdi.core.ins3d.nonlinear import corrected
from flight_fdi.core.ins3d.relinearize import relinearized
import numpy as np
inp = read_ins3d(sys.argv[1])
print('--- analysis', flush=True)
for obs in (True, False):
    analyze_ins3d(inp.steps, inp.refs, with_observability=obs).post_flight_dict()
corrected(Ins3dModel.from_grade("navigation", rows=3, vertical="loop"), inp.steps, inp.refs,
          "gyro", "z", "ramp", 5, 1e-4)       # the nonlinear check's kernel
relinearized(Ins3dModel.from_grade("mems", rows=3, vertical="loop"), inp.steps, inp.refs,
             np.full((inp.refs.t.size, 6), 0.1))  # the relinearisation's kernel
"""


def test_analysis_compiles_nothing_after_setup(bag3d):
    procs = [subprocess.Popen([sys.executable, "-c", _ANALYZE, str(bag3d)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env={**os.environ, "NUMBA_DEBUG_CACHE": "1",
                                   "FLIGHT_FDI_THREADS": threads})
             for threads in ("2", "1")]      # the two processes at once (independent)
    outputs = []
    try:
        for proc in procs:
            outputs.append(proc.communicate(timeout=300))
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    for proc, (out, err) in zip(procs, outputs):
        assert proc.returncode == 0, err[-2000:]
        after = out.split("--- analysis")[1]
        assert "data loaded" in after
        assert "saved" not in after, [ln for ln in after.splitlines() if "saved" in ln]
