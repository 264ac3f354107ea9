"""The node executables run numpy's OpenBLAS on one thread unless the user says otherwise, as
the ``flight-fdi`` command does (flight_fdi/blas_env.py): the setting is made by the nodes
package, which Python imports before any node module and so before numpy."""
from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _node_entry_points() -> dict:
    """setup.py's NODES table (the console scripts ``ros2 run`` starts)."""
    tree = ast.parse((ROOT / "setup.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "NODES":
            return ast.literal_eval(node.value)
    raise AssertionError("setup.py has no NODES table")


def _blas_seen_by(module: str, env: dict) -> list:
    code = (f"import {module}, os, sys\n"
            "from flight_fdi.blas_env import openblas_threads\n"
            "print(os.environ.get('OPENBLAS_NUM_THREADS'), openblas_threads())")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True, timeout=120)
    return out.stdout.split()


def test_every_node_executable_is_in_the_nodes_package():
    nodes = _node_entry_points()
    assert nodes and all(target.startswith("flight_fdi.nodes.") for target in nodes.values())


def test_a_node_runs_openblas_on_one_thread_unless_the_user_says_otherwise():
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    module = _node_entry_points()["filter_node"].split(":")[0]
    assert _blas_seen_by(module, env) == ["1", "1"]
    assert _blas_seen_by(module, env | {"OPENBLAS_NUM_THREADS": "2"}) == ["2", "2"]
