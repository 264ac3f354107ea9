"""filter_node loads numba (through ``core.kalman`` -> ``core.filter_kernel``) at its first filter
step, not at import or start-up: ~0.2 s of each filter process's start, which the
multi-process tests and a user's ``run`` pay per filter. The step itself is the same compiled
kernel (results bit-identical to a filter whose kernel was loaded first).

Checked in a fresh interpreter (this one has numba loaded by other tests).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys

import harness  # noqa: F401  (private ROS domain, inherited by the subprocess)

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

_PROBE = """
import json, sys
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter

out = {}
from flight_fdi.nodes.filter_node import FilterNode
out["import"] = "numba" in sys.modules
nodes = []
for model in ("ins_channel", "attitude_axis"):
    ctx = Context()
    rclpy.init(args=[], context=ctx)
    node = FilterNode(context=ctx, parameter_overrides=[Parameter("model", value=model)])
    out[model] = "numba" in sys.modules
    nodes.append((node, ctx))
from flight_fdi.core import kalman
out["proxy"] = type(kalman.fk).__name__
kf = nodes[0][0].channels[0].kf
steps = [kf.step1(0.1, z, 0.01).beta2 for z in (0.3, -0.2, 0.5)]
out["first step"] = "numba" in sys.modules
from flight_fdi.core import filter_kernel
out["module"] = kalman.fk is filter_kernel
ref = kalman.KalmanFilter(kf.model)
out["same"] = [ref.step1(0.1, z, 0.01).beta2 for z in (0.3, -0.2, 0.5)] == steps
for node, ctx in nodes:
    node.destroy_node()
    rclpy.shutdown(context=ctx)
print(json.dumps(out))
"""


def test_the_velocity_and_attitude_modes_load_numba_at_the_first_step():
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [REPO] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
    proc = subprocess.run([sys.executable, "-c", _PROBE], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert got == {"import": False, "ins_channel": False, "attitude_axis": False,
                   "proxy": "_KernelModule", "first step": True, "module": True, "same": True}
