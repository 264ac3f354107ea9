"""In-flight fault detection: the forward Kalman filter with the beta^2 gate as a ROS 2 node.

Two modes, selected by the ``model`` parameter:

* the **INS velocity mode** (``ins_channel``, or a model file without control input; the rest of
  this docstring): INS velocity against one or several reference velocities (seeds 000, 001);
* the **attitude mode** (``attitude_axis``, or a model file with a control input B; seed 003):
  per axis x / y / z the attitude filter with the command as control input (``angle_topic``,
  ``rate_topic``, ``control_topic``, geometry_msgs/Vector3Stamped), an observability check at
  start-up (``attitude_measure: rate`` is refused), and the actuator monitor: the mean of the
  estimated disturbance over ``actuator_window_s`` of zero control above
  ``actuator_threshold_urad_s2`` -> "switch to reserve" (ERROR in ``/diagnostics``, latched JSON on
  ``fdi/actuator_event``, re-armed by the service ``~/reset_actuator``). The outputs
  fdi/innovation, fdi/state (with ``u``) and fdi/model are the same. Details:
  ``flight_fdi/nodes/attitude_mode.py``.

A parameter of the other mode changed from its default is refused (it would be ignored).

INS velocity mode
-----------------

Inputs
    ``ins_topic`` (default ``/ins/velocity``, ``ins_type`` geometry_msgs/TwistStamped): INS
    velocity. ``reference_topic`` (default ``/reference/velocity``, ``reference_type``
    geometry_msgs/TwistWithCovarianceStamped): the reference velocity (GNSS, Doppler ...); its
    linear covariance diagonal is R when valid. Either may be TwistStamped,
    TwistWithCovarianceStamped or nav_msgs/Odometry (twist in child_frame_id, rotated into
    header.frame_id by the pose orientation; ``odometry_twist_frame``).
    ``reference_topics``: several redundant references instead (see "Redundant references").
    QoS ``input_qos``: ``auto`` (default: reliable unless a publisher is best effort),
    ``reliable`` or ``sensor_data`` (best effort); ``input_queue_depth`` (nodes/qos.py).

Outputs (one message per channel and reference sample, header stamp = the reference stamp)
    ``fdi/innovation`` (flight_fdi_msgs/Innovation), ``fdi/state`` (flight_fdi_msgs/FilterState),
    ``fdi/model`` (flight_fdi_msgs/ModelInfo, once per channel, reliable + transient local),
    ``/diagnostics`` (diagnostic_msgs/DiagnosticArray every ``diagnostics_period_s``).

Per channel (``channels``: "x" and/or "y") the filter steps at each reference message with
z = V_INS(t_ref) - V_ref on that axis; V_INS(t_ref) is interpolated from a bounded buffer
(core ``StreamingAligner``; a reference sample waits until the INS sample after it arrives).
dt is the difference of reference header stamps.

Bad input never stops the node; every dropped sample is counted by reason and reported in
``/diagnostics`` (status "<node>: inputs" for message-level counts, "<node>: channel <c>" for
per-channel counts; the list is in ``nodes/filter_velocity.py``). Messages are never reordered.

A stamp that goes backwards by more than ``time_jump_reset_s`` or forward by more than
``reset_after_gap_s`` is a time jump (core ``timeline.StampLine``). One wild stamp (a 0 from a
driver, a bit flip) is an outlier: dropped and counted when the next sample continues the old time
line. Only when ``time_jump_confirm`` samples in a row continue the new line (a bag loop, a clock
reset) is it adopted: on the reference it resets the filters (warning; the channel statuses turn
WARN with the reason for ``reset_warn_s``; the next FilterState has ``reset = True`` and
``dt = 0``), on the INS it resets the INS buffer; the samples held meanwhile are then used.

A reference dropout: diagnostics turn WARN once the input is older than ``stale_after_s``
("/reference/velocity stale for 3.2 s"; "no messages on ... yet" when none ever came). On
recovery the filter predicts across the gap in one step (one long dt: the model is exact for
any dt, and the grown covariance lets the filter re-converge without a false alarm) when the gap
is at most ``reset_after_gap_s``; beyond that it restarts from the prior (warning,
``reset = True``), because after a very long blind interval the old estimate says little.

Redundant references (SPEC section 2, seed 001; core ``flight_fdi.core.references``)
    With ``reference_topics`` naming i topics, every reference is one measurement row; samples
    within ``reference_sync_tolerance_s`` are stacked into one i-row update (the grouping rules:
    ``flight_fdi.core.refsync``), each reference has its own gate and is declared failed,
    handled per ``reference_mode`` (exclude, known_anomaly, nominal) and readmitted; the details
    and the outputs are in ``nodes/filter_velocity.py``.

Parameters: ``FILTER_PARAMS`` below (documented in ``config/filter.yaml``). Invalid parameters
stop the node at start-up with a ParameterError naming the parameter.
"""
from __future__ import annotations

import math
import sys
from typing import Any

from rclpy.exceptions import NameValidationException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.validate_topic_name import validate_topic_name

from ..core.actuator import MEASUREMENTS, ActuatorConfig
from ..core.errors import CoreError
from ..core.kalman import GateConfig
from ..core.models import BUILTIN_MODELS, LinearModel, get_model
from ..core.timeline import StampLine
from . import attitude_mode, convert, filter_diag, ins3d_params
from .convert import VELOCITY_TYPES
from .filter_parts import Channel as _Channel, reference_topics  # noqa: F401 (re-exported)
from .filter_velocity import VelocityMode
from .qos import INPUT_QOS_CHOICES, input_profile, output_qos
from .clockutil import ClockReader
from .errors import ParameterError
from .params import ParamSpec, declare_parameters, fail
from .setup import destroyed_on_failure

NODE_NAME = "filter_node"
PARAMS_FILE_HEADER = """\
Parameters of filter_node (the in-flight forward Kalman filter with the beta^2 gate).
Use: ros2 run flight_fdi filter_node --ros-args --params-file config/filter.yaml
Every parameter is listed at its default; changes need a restart. An invalid value stops the
node at start-up with a message naming the parameter. use_sim_time (ROS's own) may be added.
Generated by: python -m flight_fdi.nodes.params flight_fdi.nodes.filter_node"""

#: model parameters of the built-in ``ins_channel`` model that the node exposes
INS_MODEL_PARAMS = ("tau_a", "tau_w", "sigma_a", "sigma_w_deg_h", "sigma_v0", "sigma_tilt0")

_ACTUATOR = ActuatorConfig()  # the monitor's defaults

FILTER_PARAMS = (
    ParamSpec("model", "string", "ins_channel",
              "Error model, which also selects the mode: ins_channel (INS velocity mode), "
              "attitude_axis (attitude mode, seed 003), ins3d (the 3-D INS error model on the "
              "four 3-D contract topics, nodes/ins3d_mode.py), or the path of a model YAML file "
              "(no control input: INS velocity mode, one measurement row; with a control input "
              "B: attitude mode)", non_empty=True),
    ParamSpec("tau_a", "double", 3600.0, "Accelerometer bias correlation time (ins_channel)",
              "s", min=0.0, min_exclusive=True),
    ParamSpec("tau_w", "double", 3600.0, "Gyro drift correlation time (ins_channel)",
              "s", min=0.0, min_exclusive=True),
    ParamSpec("sigma_a", "double", 1e-3, "Accelerometer bias stationary std (ins_channel)",
              "m/s^2", min=0.0, min_exclusive=True),
    ParamSpec("sigma_w_deg_h", "double", 0.01, "Gyro drift stationary std (ins_channel)",
              "deg/h", min=0.0, min_exclusive=True),
    ParamSpec("sigma_v0", "double", 0.1, "Initial velocity error std (ins_channel)",
              "m/s", min=0.0, min_exclusive=True),
    ParamSpec("sigma_tilt0", "double", 1e-4, "Initial tilt std (ins_channel)",
              "rad", min=0.0, min_exclusive=True),
    ParamSpec("channels", "string_array", ["x", "y"],
              "Axes filtered, one independent channel each: x and/or y in the INS velocity "
              "mode, any of x, y, z in the attitude mode", choices=("x", "y", "z"),
              non_empty=True),
    ParamSpec("ins_topic", "string", "/ins/velocity",
              "INS velocity input (geometry_msgs/TwistStamped)", non_empty=True),
    ParamSpec("reference_topic", "string", "/reference/velocity",
              "Reference velocity input (geometry_msgs/TwistWithCovarianceStamped)",
              non_empty=True),
    ParamSpec("reference_topics", "string_array", [""],
              "Redundant reference topics (geometry_msgs/TwistWithCovarianceStamped), one "
              "measurement row each; when it names any topic it replaces reference_topic. "
              "[\"\"] (the default): the one reference_topic"),
    ParamSpec("ins_type", "string", "geometry_msgs/msg/TwistStamped",
              "Message type of ins_topic", choices=VELOCITY_TYPES),
    ParamSpec("reference_type", "string", "geometry_msgs/msg/TwistWithCovarianceStamped",
              "Message type of the reference topic(s) (TwistStamped has no covariance: "
              "reference_variance is used)", choices=VELOCITY_TYPES),
    ParamSpec("odometry_twist_frame", "string", "child",
              "Odometry inputs: the twist is in child_frame_id (REP 105; rotated into "
              "header.frame_id by the pose orientation) or already in header.frame_id",
              choices=("child", "header")),
    ParamSpec("reference_mode", "string", "exclude",
              "What a failed redundant reference does to the filter: exclude (AF: its row is "
              "struck out), known_anomaly (KF2: its variance grows by anomaly_variance), "
              "nominal (nothing; the failure is only reported)",
              choices=("nominal", "known_anomaly", "exclude")),
    ParamSpec("anomaly_variance", "double", 1.0,
              "Gamma: variance added to a failed reference's row in known_anomaly mode "
              "(a jump of d m/s calls for about d^2)", "m^2/s^2", min=0.0, min_exclusive=True),
    ParamSpec("readmit_after_s", "double", 5.0,
              "A failed reference is readmitted after its own gate has passed for this long "
              "(stamp time); failure needs alarm_m of its last alarm_n samples isolated", "s",
              min=0.0, max=3600.0),
    ParamSpec("reference_sync_tolerance_s", "double", 0.01,
              "Reference samples with stamps this close to the first one of a group form one "
              "multi-row update", "s", min=0.0, max=1.0),
    ParamSpec("reference_sync_wait_s", "double", 0.5,
              "How far (in reference stamps) an update waits for a missing reference before it "
              "goes without it (must be below buffer_s)", "s", min=0.0, max=60.0,
              min_exclusive=True),
    # --- attitude mode (model attitude_axis or a model file with B; see attitude_mode.py)
    ParamSpec("attitude_measure", "string", "angle",
              "Attitude mode: what is measured, angle or angle+rate (rate alone is refused at "
              "start-up: the angle is not observable from it)", choices=MEASUREMENTS),
    ParamSpec("attitude_m_c", "double", 1e-3,
              "Attitude mode (attitude_axis): control torque per unit inertia of one unit of "
              "command", "rad/s^2", min=0.0, min_exclusive=True),
    ParamSpec("attitude_sigma_md_walk_urad_s2", "double", 0.03,
              "Attitude mode (attitude_axis): random walk of the disturbance torque per unit "
              "inertia, in micro-rad/s^2 per sqrt(s)", "urad/s^2/sqrt(s)",
              min=0.0, min_exclusive=True),
    ParamSpec("attitude_sigma_angle_urad", "double", 100.0,
              "Attitude mode (attitude_axis): angle measurement noise std, in micro-rad",
              "urad", min=0.0, min_exclusive=True),
    ParamSpec("attitude_sigma_rate_urad_s", "double", 10.0,
              "Attitude mode (attitude_axis): rate measurement noise std, in micro-rad/s "
              "(attitude_measure angle+rate)", "urad/s", min=0.0, min_exclusive=True),
    ParamSpec("angle_topic", "string", "/attitude/angle",
              "Attitude mode: measured angle per axis (geometry_msgs/Vector3Stamped)",
              non_empty=True),
    ParamSpec("rate_topic", "string", "/attitude/rate",
              "Attitude mode: measured rate per axis (geometry_msgs/Vector3Stamped; "
              "attitude_measure angle+rate)", non_empty=True),
    ParamSpec("control_topic", "string", "/attitude/control",
              "Attitude mode: command per axis (geometry_msgs/Vector3Stamped), stamped when "
              "commanded and in force until the next message", non_empty=True),
    ParamSpec("attitude_wait_s", "double", 0.5,
              "Attitude mode: how long an angle sample waits for the control topic to reach its "
              "stamp (and for its rate sample), in angle stamps or node time", "s",
              min=0.0, max=60.0, min_exclusive=True),
    ParamSpec("rate_sync_tolerance_s", "double", 0.005,
              "Attitude mode: a rate sample this close to an angle stamp is fused with it", "s",
              min=0.0, max=1.0),
    ParamSpec("actuator_window_s", "double", _ACTUATOR.window_s,
              "Actuator monitor: seconds of zero control per window (the time base)", "s",
              min=0.0, max=3600.0, min_exclusive=True),
    ParamSpec("actuator_threshold_urad_s2", "double", round(_ACTUATOR.threshold * 1e6, 9),
              "Actuator monitor: admissible |mean disturbance torque per unit inertia| over a "
              "window, in micro-rad/s^2; above it: actuator fault, switch to reserve (events "
              "report it in rad/s^2)", "urad/s^2", min=0.0, min_exclusive=True),
    ParamSpec("actuator_zero_tolerance", "double", _ACTUATOR.zero_tol,
              "Actuator monitor: |u| at or below this counts as zero control", "", min=0.0),
    ParamSpec("actuator_settle_s", "double", _ACTUATOR.settle_s,
              "Actuator monitor: seconds after the last non-zero command before a window may "
              "open", "s", min=0.0, max=3600.0),
    ParamSpec("actuator_k_sigma", "double", _ACTUATOR.k_sigma,
              "Actuator monitor: a window is evaluated only when the rms std of the disturbance "
              "estimate over it is at most the threshold / actuator_k_sigma", "",
              min=0.0, min_exclusive=True),
    # --- both modes
    ParamSpec("input_qos", "string", "auto",
              "QoS of the inputs: reliable (nothing lost in transport), sensor_data (best "
              "effort), or auto: reliable unless a publisher of the topic is best effort",
              choices=INPUT_QOS_CHOICES),
    ParamSpec("input_queue_depth", "int", 2000,
              "History depth of the input subscriptions: the backlog a stalled node can catch "
              "up (4 s of INS at 10x real time)", "messages", min=1, max=100000),
    ParamSpec("max_gap_s", "double", 0.5,
              "Largest gap between the two INS samples around a reference stamp; a reference "
              "sample inside a larger gap is dropped", "s", min=0.0, max=60.0,
              min_exclusive=True),
    ParamSpec("buffer_s", "double", 2.0,
              "INS buffer length; also how long a reference sample waits for INS data "
              "(must exceed max_gap_s)", "s", min=0.0, max=600.0, min_exclusive=True),
    ParamSpec("gate_rule", "string", "chi2",
              "beta^2 gate: chi2 (chi-square quantile for gate_probability) or seed "
              "(m + 3 sqrt(2m))", choices=("chi2", "seed")),
    ParamSpec("gate_probability", "double", 1e-3,
              "Per-sample false-alarm probability of the chi2 gate", "", min=0.0, max=0.5,
              min_exclusive=True),
    ParamSpec("alarm_m", "int", 3, "Alarm when alarm_m of the last alarm_n samples exceed the "
              "gate (alarm_m <= alarm_n)", "samples", min=1, max=1000),
    ParamSpec("alarm_n", "int", 5, "Window of the M-of-N alarm rule", "samples",
              min=1, max=1000),
    ParamSpec("gate_action", "string", "flag",
              "flag: fuse gated samples anyway (post-flight analysis sees the fault); "
              "reject: do not fuse them", choices=("flag", "reject")),
    ParamSpec("reference_variance", "double", 0.01,
              "Reference velocity variance R used when a message carries no valid covariance "
              "(also the model's default R)", "m^2/s^2", min=0.0, min_exclusive=True),
    ParamSpec("use_reference_covariance", "bool", True,
              "Use the reference message's covariance as R when it is finite and > 0"),
    ParamSpec("time_jump_reset_s", "double", 1.0,
              "A stamp going backwards by more than this is a time jump (smaller steps back "
              "are dropped as out of order)", "s", min=0.0, min_exclusive=True),
    ParamSpec("time_jump_confirm", "int", 3,
              "A time jump (back by more than time_jump_reset_s, or forward by more than "
              "reset_after_gap_s) resets the filter only when this many samples of the input in a "
              "row continue the new time line (held meanwhile, then used); a jump the next "
              "sample does not continue is an outlier, dropped and counted. 1 = reset at once",
              "samples", min=1, max=1000),
    ParamSpec("reset_warn_s", "double", 10.0,
              "After a filter reset the channel's /diagnostics status stays WARN, with the "
              "reason, this long (wall clock)", "s", min=0.0, max=86400.0),
    ParamSpec("frame_id", "string", "nav",
              "header.frame_id of every output (fdi/innovation, fdi/state, fdi/model): the "
              "navigation frame the velocities are expressed in", non_empty=True),
    ParamSpec("reset_after_gap_s", "double", 60.0,
              "After a reference gap up to this long the filter predicts across it; after a "
              "longer gap it restarts from the prior", "s", min=0.0, min_exclusive=True),
    ParamSpec("diagnostics_period_s", "double", 1.0, "Period of /diagnostics", "s",
              min=0.0, max=3600.0, min_exclusive=True),
    ParamSpec("stale_after_s", "double", 1.0,
              "An input with no message for longer than this is reported stale (WARN)", "s",
              min=0.0, min_exclusive=True),
    ParamSpec("rate_window_s", "double", 5.0, "Window of the input rate estimate", "s",
              min=0.0, max=3600.0, min_exclusive=True),
) + ins3d_params.INS3D_PARAMS  # --- the ins3d mode's own (nodes/ins3d_params.py)

_DEFAULTS = {s.name: s.default for s in FILTER_PARAMS}


#: parameters that mean something only in the INS velocity mode
INS_ONLY = INS_MODEL_PARAMS + (
    "ins_topic", "reference_topic", "reference_topics", "ins_type", "reference_type",
    "odometry_twist_frame", "reference_mode", "anomaly_variance",
    "readmit_after_s", "reference_sync_tolerance_s", "reference_sync_wait_s", "max_gap_s",
    "buffer_s", "reference_variance", "use_reference_covariance")


def _only_defaults(values: dict[str, Any], names: tuple[str, ...], other: str) -> None:
    """Refuse a parameter of the other mode that was changed from its default (it would be
    silently ignored)."""
    for k in names:
        if values[k] != _DEFAULTS[k]:
            fail(k, values[k], f"its default ({_DEFAULTS[k]!r}): it applies only to the {other} "
                 f"mode, and model {values['model']!r} runs the "
                 f"{'INS velocity' if other == 'attitude' else 'attitude'} mode")


def build_model(values: dict[str, Any]) -> Any:
    """The channel model from the node parameters (ParameterError when it cannot be built).
    A model with a control input B runs the attitude mode (``attitude_mode``), any other the
    INS velocity mode."""
    name = values["model"]
    if name == ins3d_params.MODEL:  # the 3-D INS error model (nodes/ins3d_mode.py)
        from . import ins3d_mode  # imported only for this mode: the 3-D core, numba, scipy

        return ins3d_mode.build_model(values, _DEFAULTS)
    ins3d_params.refuse_in_other_modes(values, _DEFAULTS)
    if attitude_mode.is_attitude_model(name):
        _only_defaults(values, INS_ONLY, "INS velocity")
        return attitude_mode.build_attitude_model(values, _DEFAULTS)
    overrides = {k: values[k] for k in INS_MODEL_PARAMS}
    try:
        if name == "ins_channel":
            model = get_model(name, sigma_ref=math.sqrt(values["reference_variance"]),
                              **overrides)
        else:
            changed = [k for k in INS_MODEL_PARAMS if values[k] != _DEFAULTS[k]]
            if changed and name not in BUILTIN_MODELS:
                fail(changed[0], values[changed[0]],
                     "its default: model parameters apply only to the built-in ins_channel "
                     "(a model file carries its own)")
            model = get_model(name)
    except CoreError as exc:
        fail("model", name, f"a built-in model ({', '.join(BUILTIN_MODELS)}) or a readable "
             f"model YAML file ({exc})")
    if model.B is not None:
        _only_defaults(values, INS_ONLY, "INS velocity")
        return attitude_mode.build_attitude_model(values, _DEFAULTS, file_model=model)
    _only_defaults(values, attitude_mode.ATTITUDE_ONLY, "attitude")
    if model.m != 1:
        fail("model", name, "a model with one measurement row (the velocity difference) and no "
             f"control input, or one with a control input (attitude mode); {model.name} has "
             f"{model.m} rows")
    if "z" in values["channels"]:
        fail("channels", values["channels"], "x and/or y in the INS velocity mode (z only with "
             "an attitude model)")
    return model.with_R([[values["reference_variance"]]]) if name != "ins_channel" else model


def validate(values: dict[str, Any]) -> None:
    """Cross-field checks of FILTER_PARAMS (ParameterError naming the parameter)."""
    if values["alarm_m"] > values["alarm_n"]:
        fail("alarm_m", values["alarm_m"], f"alarm_m <= alarm_n (= {values['alarm_n']})")
    if values["buffer_s"] <= values["max_gap_s"]:
        fail("buffer_s", values["buffer_s"], f"more than max_gap_s (= {values['max_gap_s']})")
    if values["reference_sync_wait_s"] >= values["buffer_s"]:
        fail("reference_sync_wait_s", values["reference_sync_wait_s"],
             f"less than buffer_s (= {values['buffer_s']})")
    if any(values["reference_topics"]):
        if values["ins_topic"] in values["reference_topics"]:
            fail("reference_topics", values["reference_topics"],
                 "topics other than ins_topic")
    elif values["ins_topic"] == values["reference_topic"]:
        fail("reference_topic", values["reference_topic"], "a topic other than ins_topic")
    build_model(values)


class FilterNode(VelocityMode, Node):
    """The filter node (see the module docstring).

    ``FilterNode(context=..., parameter_overrides=[...])`` builds it in-process (any keyword goes
    to ``rclpy.node.Node``); an invalid parameter raises ParameterError."""

    def __init__(self, node_name: str = NODE_NAME, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        with destroyed_on_failure(self):
            self._setup()

    # ------------------------------------------------------------------ set-up
    def _setup(self) -> None:
        self._clock_reader = ClockReader(self.get_clock())
        p = self.p = declare_parameters(self, FILTER_PARAMS, validator=validate)
        self.model = build_model(p)
        try:
            self.gate = GateConfig(rule=p["gate_rule"], probability=p["gate_probability"],
                                   alarm_m=p["alarm_m"], alarm_n=p["alarm_n"],
                                   action=p["gate_action"])
        except CoreError as exc:  # the table's checks should make this unreachable
            raise ParameterError(f"invalid gate parameters: {exc}") from None
        qos = input_profile(p["input_qos"], p["input_queue_depth"])
        self.ins3d = None
        if p["model"] == ins3d_params.MODEL:  # the ins3d mode (nodes/ins3d_mode.py)
            from . import ins3d_mode  # already imported by build_model

            self.attitude = None
            self.ins3d = ins3d_mode.Ins3dMode(self, self.model, self.gate, qos)
            return
        if self.model.B is not None:  # a model with a control input: the attitude mode
            self.attitude = attitude_mode.AttitudeMode(self, self.model, self.gate, qos)
            return
        self.attitude = None
        self._setup_velocity_mode()

    def _create_outputs(self, n_channels: int) -> None:
        """The publishers of both modes: fdi/innovation, fdi/state, fdi/model (latched)."""
        from flight_fdi_msgs.msg import FilterState, Innovation, ModelInfo

        out_qos = output_qos()
        self.pub_innovation = self.create_publisher(Innovation, "fdi/innovation", out_qos)
        self.pub_state = self.create_publisher(FilterState, "fdi/state", out_qos)
        latched = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(1, n_channels),
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub_model = self.create_publisher(ModelInfo, "fdi/model", latched)

    def _resolve(self, key: str, topic: str) -> str:
        """The fully qualified name of ``topic`` (ParameterError naming ``key`` when invalid)."""
        try:
            validate_topic_name(topic)
            return self.resolve_topic_name(topic)
        except NameValidationException as exc:
            fail(key, self.p[key], f"valid ROS topic names ({str(exc).splitlines()[0]})"
                 if key == "reference_topics" else
                 f"a valid ROS topic name ({str(exc).splitlines()[0]})")
        except RuntimeError as exc:  # rcl's own check of the expanded name (e.g. "/a//b")
            fail(key, self.p[key], f"a valid ROS topic name ({exc})")

    def _stamp_line(self) -> StampLine:
        p = self.p
        return StampLine(p["time_jump_reset_s"], p["time_jump_confirm"], p["reset_after_gap_s"])

    def _now(self) -> float:
        """The node's clock (ROS or simulated time) in seconds."""
        return self._clock_reader.now_s()

    # ------------------------------------------------------------------ drops
    def _drop(self, reason: str, detail: str, channel: _Channel | None = None, n: int = 1) -> None:
        if channel is None:
            self.counters.inc("dropped_" + reason, n)
        else:
            channel.counters.inc("dropped_" + reason, n)
        self.get_logger().warning(f"dropped {detail}", throttle_duration_sec=5.0)

    def _bad_stamp(self, what: str, t: float, sec: int, nanosec: int) -> bool:
        """True (counted ``dropped_<what>_invalid_stamp``) when the message's stamp cannot be
        carried by an output stamp (``convert.stamp_fits``)."""
        if convert.stamp_fits(t):
            return False
        self._drop(f"{what}_invalid_stamp", f"{what} sample with stamp sec={sec} "
                   f"nanosec={nanosec}: after the last time a ROS stamp can hold")
        return True

    # ------------------------------------------------------------------ diagnostics
    def diagnostic_statuses(self) -> list:
        if self.ins3d is not None:
            return self.ins3d.diagnostic_statuses()
        if self.attitude is not None:
            return self.attitude.diagnostic_statuses()
        return filter_diag.statuses(self)


def main(args: list[str] | None = None) -> int:
    """``ros2 run flight_fdi filter_node [--executor {events,single}] [--ros-args ...]``
    (EventsExecutor by default: the latency target); exit 1 on invalid parameters."""
    from .runner import run_node

    return run_node(FilterNode, NODE_NAME, args, default_executor="events")


if __name__ == "__main__":
    sys.exit(main())
