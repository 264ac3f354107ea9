"""``core.warmup.warm`` (what ``make setup`` compiles into numba's cache) covers the kernels the
smoother node's path runs: the forward pass rebuilt from a recording (``ForwardResult.from_record``)
and the post-flight analysis on it (``analyze_forward``). A kernel it missed was compiled by the
first smoother run after set-up (``discretize._discretize_all``: 8-13 s, paid by the first test
of the suite that rebuilt a record).

Checked in a fresh interpreter, independently of the disk cache's state: after ``warm()``, the
recording path adds no type signature to any compiled kernel of ``flight_fdi.core``.
"""
from __future__ import annotations

import json
import subprocess
import sys

_PROBE = """
import json, sys
import numpy as np
from numba.core.dispatcher import Dispatcher

def signatures():
    out = {}
    for name, mod in list(sys.modules.items()):
        if not name.startswith("flight_fdi.core") or mod is None:
            continue
        for attr, obj in vars(mod).items():
            if isinstance(obj, Dispatcher):
                out[f"{name}.{attr}"] = sorted(str(s) for s in obj.signatures)
    return out

from flight_fdi.core.warmup import warm
warm()
before = signatures()
from flight_fdi.core.analysis import AnalysisConfig, analyze_forward
from flight_fdi.core.kalman import ForwardResult, run_forward
from flight_fdi.core.models import ins_channel
model = ins_channel()
rng = np.random.default_rng(5)
t = np.cumsum(0.1 + rng.normal(0, 1e-3, 400))
f = run_forward(model, t, rng.normal(0, 0.1, t.size))
rec = ForwardResult.from_record(model, f.t, np.array(f.dt), f.z, f.R, f.H, f.fused, f.u, f.x, f.P)
analyze_forward(model, rec, AnalysisConfig(), t0=float(t[0]))
after = signatures()
print(json.dumps({k: v for k, v in after.items() if before.get(k) != v}))
"""


def test_warm_compiles_what_the_recording_path_runs():
    proc = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    new = json.loads(proc.stdout.strip().splitlines()[-1])
    assert new == {}, f"kernels compiled after warm(): {new}"
