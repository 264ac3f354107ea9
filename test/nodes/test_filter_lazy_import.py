"""filter_node imports the ins3d mode (the 3-D core, its numba kernels, scipy.optimize) only when
``model: ins3d`` is selected, yet declares the same parameters in every mode.

The import checks run in a fresh interpreter (a subprocess: this one has the 3-D core loaded by
other tests). The parameter set is the one filter_node declared before the ins3d mode's imports
were made lazy (65 parameters, written out below by type), with the height reference's six
added since (session 18).
"""
from __future__ import annotations

import inspect
import json
import os
import subprocess
import sys

import harness  # noqa: F401  (private ROS domain, inherited by the subprocess)
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter

from flight_fdi.nodes import ins3d_params

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

#: filter_node's declared parameters (with rclpy's own use_sim_time and
#: start_type_description_service) before the change, by ParameterType
DECLARED = {
    "double": (
        "actuator_k_sigma", "actuator_settle_s", "actuator_threshold_urad_s2",
        "actuator_window_s", "actuator_zero_tolerance", "anomaly_variance", "attitude_m_c",
        "attitude_sigma_angle_urad", "attitude_sigma_md_walk_urad_s2",
        "attitude_sigma_rate_urad_s", "attitude_wait_s", "buffer_s", "diagnostics_period_s",
        "gate_probability", "ins3d_end_idle_s", "ins3d_height_sigma", "ins3d_v0_sigma_up",
        "ins3d_wait_s", "max_gap_s",
        "rate_sync_tolerance_s", "rate_window_s", "readmit_after_s", "reference_sync_tolerance_s",
        "reference_sync_wait_s", "reference_variance", "reset_after_gap_s", "reset_warn_s",
        "sigma_a", "sigma_tilt0", "sigma_v0", "sigma_w_deg_h", "stale_after_s", "tau_a", "tau_w",
        "time_jump_reset_s"),
    "integer": ("alarm_m", "alarm_n", "input_queue_depth", "ins3d_rows", "time_jump_confirm"),
    "string": (
        "angle_topic", "attitude_measure", "control_topic", "fix_topic", "frame_id", "gate_action",
        "gate_rule", "imu_topic", "input_qos", "ins3d_grade", "ins3d_height_datum",
        "ins3d_height_topic", "ins3d_height_type", "ins3d_vertical", "ins_topic",
        "ins_type", "model", "odometry_twist_frame", "rate_topic", "reference_mode",
        "reference_topic", "reference_type"),
    "string_array": ("channels", "reference_topics"),
    "bool": ("ins3d_aligned_prior", "ins3d_latency", "start_type_description_service",
             "use_reference_covariance", "use_sim_time"),
    "double_array": ("ins3d_height_markov", "ins3d_reference_markov"),
}
#: the ins3d parameters' defaults before the change
INS3D_DEFAULTS = {
    "imu_topic": "/ins/imu", "fix_topic": "/ins/fix", "ins3d_grade": "navigation",
    "ins3d_rows": 3, "ins3d_vertical": "loop", "ins3d_latency": True,
    "ins3d_reference_markov": [0.02, 0.03, 30.0], "ins3d_aligned_prior": True,
    "ins3d_wait_s": 1.0, "ins3d_end_idle_s": 2.0}

_PROBE = """
import json, sys
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter

#: the 3-D core's light modules (they import nothing)
LIGHT = ("flight_fdi.core.ins3d", "flight_fdi.core.ins3d.defaults")

def heavy():
    return sorted(m for m in sys.modules if m.startswith(("flight_fdi.core.ins3d",
                  "flight_fdi.nodes.ins3d_mode", "scipy.optimize")) and m not in LIGHT)

from flight_fdi.nodes.filter_node import FilterNode
out = {"import": heavy()}
for model in ("ins_channel", "attitude_axis"):
    ctx = Context()
    rclpy.init(args=[], context=ctx)
    node = FilterNode(context=ctx, parameter_overrides=[Parameter("model", value=model)])
    out[model] = heavy()
    node.destroy_node()
    rclpy.shutdown(context=ctx)
print(json.dumps(out))
"""


def _env() -> dict[str, str]:
    """This environment with this worktree first on PYTHONPATH (the subprocess imports it)."""
    return dict(os.environ, PYTHONPATH=os.pathsep.join(
        [REPO] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))


def _declared(node) -> dict[str, tuple[str, ...]]:
    from rcl_interfaces.msg import ParameterType

    by_code = {getattr(ParameterType, k): k[len("PARAMETER_"):].lower()
               for k in dir(ParameterType) if k.startswith("PARAMETER_")}
    out: dict[str, list[str]] = {}
    for name in node._parameters:
        out.setdefault(by_code[node.describe_parameter(name).type], []).append(name)
    return {k: tuple(sorted(v)) for k, v in out.items()}


def test_the_velocity_and_attitude_modes_do_not_import_the_3d_core():
    proc = subprocess.run([sys.executable, "-c", _PROBE], cwd=REPO, env=_env(),
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert got == {"import": [], "ins_channel": [], "attitude_axis": []}


def test_every_mode_declares_the_parameters_it_declared_before():
    for model in ("ins_channel", "ins3d"):
        ctx = Context()
        rclpy.init(args=[], context=ctx)
        try:
            from flight_fdi.nodes.filter_node import FilterNode

            node = FilterNode(context=ctx, parameter_overrides=[Parameter("model", value=model)])
            try:
                assert _declared(node) == DECLARED, model
                values = {k: node.get_parameter(k).value for k in INS3D_DEFAULTS}
                values["ins3d_reference_markov"] = list(values["ins3d_reference_markov"])
                assert values == INS3D_DEFAULTS, model
                vertical = node.describe_parameter("ins3d_vertical").additional_constraints
                assert all(v in vertical for v in ("damped", "free", "loop")), vertical
            finally:
                node.destroy_node()
        finally:
            rclpy.shutdown(context=ctx)


def test_the_core_defaults_have_one_copy():
    """The parameters' defaults that are the 3-D core's own are the core's objects (one copy, in
    ``core.ins3d.defaults``), and that module loads nothing heavy."""
    from flight_fdi.core.ins3d import defaults, model
    from flight_fdi.core.ins3d.analysis import analyze_ins3d
    from flight_fdi.nodes import ins3d_mode

    assert ins3d_params.VERTICAL is defaults.VERTICAL is model.VERTICAL
    assert ins3d_params.ANALYZE_DEFAULTS is defaults.ANALYZE_DEFAULTS
    sig = inspect.signature(analyze_ins3d).parameters
    for k, v in defaults.ANALYZE_DEFAULTS.items():
        assert sig[k].default is v, k
    assert ins3d_mode.INS3D_PARAMS is ins3d_params.INS3D_PARAMS  # one table, re-exported
    by_name = {s.name: s.default for s in ins3d_params.INS3D_PARAMS}
    assert by_name["ins3d_vertical"] is defaults.ANALYZE_DEFAULTS["vertical"]
    assert by_name["ins3d_reference_markov"] == list(defaults.ANALYZE_DEFAULTS["ref_markov"])

    probe = ("import sys; import flight_fdi.core.ins3d.defaults; print(sorted(m for m in "
             "sys.modules if m.startswith(('numba', 'numpy', 'scipy', 'flight_fdi'))))")
    proc = subprocess.run([sys.executable, "-c", probe], cwd=REPO, env=_env(),
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == str(
        ["flight_fdi", "flight_fdi.core", "flight_fdi.core.ins3d", "flight_fdi.core.ins3d.defaults"])
