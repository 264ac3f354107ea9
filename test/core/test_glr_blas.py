"""GLR does not depend on the BLAS library's threads: no numpy product on the flight's arrays
goes to a multithreaded BLAS (whose worker threads then spin beside the compiled scan, costing a
second core's worth of CPU), and the result is the same on one GLR thread or two."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

#: runs in a fresh process with OPENBLAS_NUM_THREADS=2: the CPU time of numpy's BLAS worker
#: threads (the threads that exist right after ``import numpy``) over GLR calls on a flight
#: as long as the 3-hour flight (OpenBLAS splits a product of its arrays), then over
#: deliberate products of the same size (the probe's positive control)
PROBE = r"""
import glob, json, os, time
import numpy as np

def tids():
    return {int(p.split("/")[-1]) for p in glob.glob(f"/proc/{os.getpid()}/task/*")}

def cpu(ids):
    tot = 0
    for tid in ids:
        fields = open(f"/proc/{os.getpid()}/task/{tid}/stat").read().rsplit(")", 1)[1].split()
        tot += int(fields[11]) + int(fields[12])
    return tot / os.sysconf("SC_CLK_TCK")

workers = tids() - {os.getpid()}
from flight_fdi.core import GlrConfig, ins_channel, isolate
from flight_fdi.core.kalman import run_forward

rng = np.random.default_rng(3)
model = ins_channel()
t = np.arange(108000) * 0.1
fwd = run_forward(model, t, rng.normal(0.0, 0.1, t.size))
one = isolate(model, fwd, GlrConfig(threads=1, curve_points=0))
b0, c0 = cpu(workers), time.process_time()
for _ in range(2):
    isolate(model, fwd, GlrConfig(threads=1, curve_points=0))
glr_blas, glr_cpu = cpu(workers) - b0, time.process_time() - c0
two = isolate(model, fwd, GlrConfig(threads=2, curve_points=0))
H, E = np.ones((t.size, 4)), np.ones((4, 4))
b0, c0 = cpu(workers), time.process_time()
while time.process_time() - c0 < glr_cpu:
    H @ E
control_blas = cpu(workers) - b0
print(json.dumps({"workers": len(workers), "glr_blas": glr_blas, "glr_cpu": glr_cpu,
                  "control_blas": control_blas,
                  "same": [one.statistic == two.statistic, one.threshold == two.threshold,
                           one.onset_index == two.onset_index]}))
"""


def test_glr_leaves_the_blas_threads_idle():
    env = dict(os.environ, OPENBLAS_NUM_THREADS="2", PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True,
                         timeout=300, check=True)
    r = json.loads(out.stdout.strip().splitlines()[-1])
    assert r["same"] == [True, True, True]
    if r["workers"] == 0 or r["control_blas"] < 0.05:
        pytest.skip(f"numpy's BLAS has no worker threads that split these products: {r}")
    # with the flight's product D_k = H_k E in numpy, the workers spun for ~30 % of GLR's CPU
    assert r["glr_blas"] < 0.15 * r["glr_cpu"], r
