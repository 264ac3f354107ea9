"""filter_node's ins3d mode (``model: ins3d``): the 3-D INS error model's forward filter in flight.

Inputs, the four topics of the 3-D contract (docs/sim3d.md; names are parameters):
``imu_topic`` (sensor_msgs/Imu: INS attitude, mean body rate and specific force),
``ins_topic`` (geometry_msgs/TwistStamped: INS velocity ENU), ``fix_topic``
(sensor_msgs/NavSatFix: INS latitude, height) and ``reference_topic``
(geometry_msgs/TwistWithCovarianceStamped: reference velocity and its variances); optionally
``ins3d_height_topic`` (``ins3d_height_type``: NavSatFix, FluidPressure or PointStamped, taken
raw and decoded by ``bagio.height_input.decode_height`` as ``analyze`` does), a height reference
as the third row: the assembler interpolates it at the reference stamps with the datum of
``ins3d_height_datum`` (``core.ins3d.stream.HeightRule``; the filter starts once the datum is
known, its prior ``h0_sigma`` from the data) -- docs/ins3d.md, "A height reference".

Per message the core's ``Ins3dAssembler`` builds the propagation steps (the IMU stamps are the
step boundaries) and the reference rows exactly as ``flight-fdi analyze --model ins3d`` reads a
bag, and ``Ins3dStream`` runs the same compiled kernels as the batch filter (equal bit for bit).
A step waits for the samples it needs (the next fix: 0.2 s at 5 Hz) and for the reference
stream to pass it, at most ``ins3d_wait_s`` of IMU time. The filter starts at the first step
(the aligned prior needs its attitude and specific force).

End of input: the last steps and reference rows wait for samples that come only with later
messages. When no message arrived on any of the inputs for ``ins3d_end_idle_s`` (steady
clock: a replay's stopped /clock does not stop it; counted from the end of the node's own
work on the last message, and confirmed by the next timer tick, so that a node that was busy or
starved of CPU first takes the messages queued meanwhile), the node flushes them as at the end of a
bag (``Ins3dAssembler.finish``: the last samples clamp) and ends the record; a message after
that starts a new record (a new filter from its first step, published with ``reset``). The
pipeline (``nodes/ins3d_pipeline.py``) flushes at the end of its bag itself (``finish()``).

Outputs (channel ``ins3d``): ``fdi/state`` (FilterState per step and per update, the layout of
``ins3d_recording``: the smoother re-runs the whole 3-D analysis from a recording),
``fdi/innovation`` (Innovation per update: nu, S, beta^2 over the rows and per row, the gate and
the M-of-N alarm), ``fdi/model`` (ModelInfo once t0 is known, transient local), ``/diagnostics``.
Bad input is dropped and counted (``dropped_<topic key>_<reason>``: non_finite,
duplicate_stamp, out_of_order, invalid_covariance, core_error; the height's also no_fix), never
stopping the node.
"""
from __future__ import annotations

import inspect
import math
import time
from dataclasses import replace
from types import SimpleNamespace
from typing import Any

import numpy as np

from ..core.errors import CoreError
from ..core.gate import ALARM_CLEARED, ALARM_RAISED, GateConfig
from ..core.ins3d.analysis import analyze_ins3d, initial_covariance
from ..core.ins3d.grade_file import is_grade_file, resolve_grade
from ..core.ins3d.grades import GRADES as PRESETS
from ..core.ins3d.model import Ins3dModel
from ..core.ins3d.glr3d import ref_axes
from ..core.ins3d.stream import HEIGHT, Boundary, HeightRule, Ins3dAssembler, Ins3dStream
from . import diagnostics as diag
from .convert import header
from .ins3d_recording import (CHANNEL, grade_params, option_params, pack_step, state_units,
                              t0_params)
from .ins3d_params import (INS3D_ONLY, INS3D_PARAMS, MODEL, USED,  # noqa: F401 (re-exported)
                           refuse_in_other_modes)
from .params import fail

#: the grade presets an analysis takes (core/ins3d/grades.py; "perfect" is for tests)
GRADES = tuple(g for g in PRESETS if g != "perfect")
_COUNT = {4: "four", 5: "five"}   # the distinct input topics
#: the defaults of ``analyze_ins3d`` (those of its model options, which are also the node
#: parameters' defaults: ``core.ins3d.defaults.ANALYZE_DEFAULTS``)
_ANALYZE = {k: v.default for k, v in inspect.signature(analyze_ins3d).parameters.items()}


def build_model(values: dict[str, Any], defaults: dict[str, Any]) -> Ins3dModel:
    """The node's Ins3dModel; refuses a changed parameter that the ins3d mode would ignore."""
    for k, v in values.items():
        if k not in USED and k in defaults and v != defaults[k]:
            fail(k, v, f"its default ({defaults[k]!r}): it does not apply to the ins3d mode")
    topics = [values[k] for k in ("imu_topic", "ins_topic", "fix_topic", "reference_topic")]
    if values["ins3d_height_topic"]:
        topics.append(values["ins3d_height_topic"])
    if len(set(topics)) < len(topics):
        fail("imu_topic", values["imu_topic"], f"{_COUNT[len(topics)]} distinct topics "
             "(imu_topic, ins_topic, fix_topic, reference_topic"
             + (", ins3d_height_topic)" if len(topics) == 5 else ")"))
    grade = values["ins3d_grade"]
    if grade not in GRADES and not is_grade_file(grade):
        fail("ins3d_grade", grade, f"a preset ({', '.join(GRADES)}) or a YAML grade file")
    opts = model_options(values)
    try:
        return Ins3dModel.from_grade(resolve_grade(grade),
                                     position=opts.get("position", _ANALYZE["position"]),
                                     rows=values["ins3d_rows"], vertical=opts["vertical"],
                                     latency=opts["latency"], ref_markov=opts["ref_markov"],
                                     height_row=opts.get("height_row", False),
                                     v0_sigma_up=opts.get("v0_sigma_up"))
    except CoreError as exc:   # a bad grade file
        fail("ins3d_grade", grade, f"a valid YAML grade file ({exc})")


def model_options(values: dict[str, Any]) -> dict[str, Any]:
    """The ``analyze_ins3d`` model options of the node parameters (ParameterError for a bad
    ``ins3d_reference_markov``); with a height topic those of its row (``height_spec``,
    ``HeightInput.options`` but the datum's ``h0_sigma``, which the data give)."""
    mk = [float(v) for v in values["ins3d_reference_markov"]]
    if len(mk) != 3 or not (all(v > 0 for v in mk) or not any(mk)):
        fail("ins3d_reference_markov", mk, "[sigma_h, sigma_v, tau], all > 0, or [0, 0, 0]")
    out = {"vertical": values["ins3d_vertical"], "latency": bool(values["ins3d_latency"]),
           "ref_markov": tuple(mk) if any(mk) else None,
           "aligned_prior": bool(values["ins3d_aligned_prior"])}
    spec = height_spec(values)
    if spec is not None:
        out.update(position=True, height_row=True, v0_sigma_up=spec.v0_sigma_up,
                   ref_markov=spec.ref_markov(out["ref_markov"]))
    return out


def height_spec(values: dict[str, Any]) -> Any:
    """The ``bagio.height_input.HeightSpec`` of the height parameters (None: no
    ``ins3d_height_topic``); ParameterError for a bad one."""
    from ..bagio.errors import BagError
    from ..bagio.height_input import HeightSpec

    topic = values["ins3d_height_topic"]
    if not topic:
        return None
    if values["ins3d_rows"] != 3:
        fail("ins3d_rows", values["ins3d_rows"], "3 with ins3d_height_topic (the height is the "
             "third row)")
    mk = [float(v) for v in values["ins3d_height_markov"]]
    if len(mk) != 2 or not (all(v > 0 for v in mk) or not any(mk)):
        fail("ins3d_height_markov", mk, "[sigma m, tau s], both > 0, or [0, 0]")
    try:
        return HeightSpec(topic, sigma=float(values["ins3d_height_sigma"]),
                          markov=tuple(mk) if any(mk) else None,
                          datum=values["ins3d_height_datum"],
                          v0_sigma_up=float(values["ins3d_v0_sigma_up"]))
    except BagError as exc:
        fail("ins3d_height_topic", topic, f"a valid height reference ({exc})")


def height_parameters(spec: Any, msgtype: str) -> dict[str, Any]:
    """The node parameters of a ``HeightSpec`` whose topic carries ``msgtype`` (``run``)."""
    return {"ins3d_height_topic": spec.topic, "ins3d_height_type": msgtype,
            "ins3d_height_sigma": float(spec.sigma),
            "ins3d_height_markov": [0.0, 0.0] if spec.markov is None else list(spec.markov),
            "ins3d_height_datum": spec.datum, "ins3d_v0_sigma_up": float(spec.v0_sigma_up),
            "ins3d_rows": 3}


def option_parameters(options: dict[str, Any]) -> dict[str, Any]:
    """The node parameters of ``analyze_ins3d`` model options (vertical, latency, ref_markov,
    aligned_prior; e.g. a bag description's, ``bagio.ins3d_input.error_model_options``); the
    options not given keep the parameters' defaults."""
    out: dict[str, Any] = {}
    if "vertical" in options:
        out["ins3d_vertical"] = options["vertical"]
    if "latency" in options:
        out["ins3d_latency"] = bool(options["latency"])
    if "ref_markov" in options:
        mk = options["ref_markov"]
        out["ins3d_reference_markov"] = [0.0] * 3 if mk is None else [float(v) for v in mk]
    if "aligned_prior" in options:
        out["ins3d_aligned_prior"] = bool(options["aligned_prior"])
    return out


def is_ins3d(model: Any) -> bool:
    return isinstance(model, Ins3dModel)


def _ns(m: Any) -> int:
    return int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec)


def height_class(msgtype: str) -> Any:
    """The message class of a height type (``core.ins3d.defaults.HEIGHT_TYPES``)."""
    from geometry_msgs.msg import PointStamped
    from sensor_msgs.msg import FluidPressure, NavSatFix

    return {NavSatFix.__name__: NavSatFix, FluidPressure.__name__: FluidPressure,
            PointStamped.__name__: PointStamped}[msgtype.rsplit("/", 1)[-1]]


class Ins3dMode:
    """The ins3d mode of a FilterNode (module docstring); built by the node after its
    parameters are declared. ``finish()`` flushes the steps that wait for samples that will
    not come (the end of a replay)."""

    def __init__(self, node: Any, model: Ins3dModel, gate: GateConfig, qos: Any) -> None:
        from geometry_msgs.msg import TwistStamped, TwistWithCovarianceStamped
        from sensor_msgs.msg import Imu, NavSatFix

        self.node, self.model, self.gate = node, model, gate
        p = self.p = node.p
        self.names = {"ins_imu": node._resolve("imu_topic", p["imu_topic"]),
                      "ins_velocity": node._resolve("ins_topic", p["ins_topic"]),
                      "ins_fix": node._resolve("fix_topic", p["fix_topic"]),
                      "ref_velocity": node._resolve("reference_topic", p["reference_topic"])}
        self.height = height_spec(p)
        if self.height is not None:
            self.names[HEIGHT] = node._resolve("ins3d_height_topic", self.height.topic)
        if len(set(self.names.values())) < len(self.names):
            fail("imu_topic", p["imu_topic"], f"{_COUNT[len(self.names)]} distinct topics (they "
                 f"resolve to {sorted(self.names.values())})")
        self.row_names = list(ref_axes(model.height_row)[:model.rows])
        self._new_record()
        self.counters = node.counters = diag.Counters(
            ("received_ins", "received_reference", "received_height", "published",
             "published_states", "records_ended"))
        self._last_msg = time.monotonic()
        self._idle_seen: float | None = None      # the _last_msg an idle tick saw (to confirm)
        self._idle_s = float(p["ins3d_end_idle_s"])
        if self._idle_s > 0:
            from rclpy.clock import Clock, ClockType
            self._idle_timer = node.create_timer(min(0.5, self._idle_s / 2.0), self._check_idle,
                                                 clock=Clock(clock_type=ClockType.STEADY_TIME))
        node._create_outputs(1)
        cb = {"ins_imu": (Imu, self._on_imu), "ins_velocity": (TwistStamped, self._on_vel),
              "ins_fix": (NavSatFix, self._on_fix),
              "ref_velocity": (TwistWithCovarianceStamped, self._on_ref)}
        for key, (cls, fn) in cb.items():
            node.create_subscription(cls, self.names[key], fn, qos)
        if self.height is not None:       # raw: decoded by bagio.height_input, as analyze does
            node.create_subscription(height_class(p["ins3d_height_type"]), self.names[HEIGHT],
                                     self._on_height, qos, raw=True)
        self.inputs = node.inputs = diag.InputMonitor(node._now, list(self.names.values()),
                                                      window_s=p["rate_window_s"],
                                                      stale_after_s=p["stale_after_s"])
        node.diagnostics = diag.DiagnosticsTimer(node, p["diagnostics_period_s"],
                                                 self.diagnostic_statuses)
        node.get_logger().info(
            f"ins3d mode: {model.grade.name} grade, {model.n} states, {model.rows} reference "
            f"rows; inputs {', '.join(self.names.values())} (gate {gate.rule}, alarm "
            f"{gate.alarm_m} of {gate.alarm_n}, action {gate.action})")

    def _new_record(self) -> None:
        rule = None if self.height is None else HeightRule(
            self.height.max_gap_s, self.height.datum == "first", self.height.variance())
        self.asm = Ins3dAssembler(wait_s=self.p["ins3d_wait_s"], height=rule)
        self.stream: Ins3dStream | None = None
        self._held: list = []
        self.last: Any = None
        self.last_t: float | None = None
        self.alarm_since: float | None = None

    def _check_idle(self) -> None:
        """The end-of-input timer (module docstring): idle on two ticks in a row, with no message
        between them. After a stall (a long callback, a starved process) the executor may run this
        timer before the messages that arrived meanwhile; the first idle tick only notes it."""
        if self.asm.t0_ns is None or self.asm.finished or \
                time.monotonic() - self._last_msg < self._idle_s:
            self._idle_seen = None
            return
        if self._idle_seen != self._last_msg:
            self._idle_seen = self._last_msg
            return
        self.finish()
        self.counters.inc("records_ended")
        self.node.get_logger().info(
            f"ins3d: no input for {self._idle_s:g} s: flushed the end of the record "
            f"(last step {self.asm.k})")

    # ------------------------------------------------------------------ inputs
    def _on_imu(self, m: Any) -> None:
        o, w, f = m.orientation, m.angular_velocity, m.linear_acceleration
        self._add("ins_imu", "received_ins", _ns(m), np.array([o.w, o.x, o.y, o.z]),
                  np.array([f.x, f.y, f.z]), np.array([w.x, w.y, w.z]))

    def _on_vel(self, m: Any) -> None:
        v = m.twist.linear
        self._add("ins_velocity", "received_ins", _ns(m), np.array([v.x, v.y, v.z]))

    def _on_fix(self, m: Any) -> None:
        self._add("ins_fix", "received_ins", _ns(m), np.radians(np.array([m.latitude]))[0],
                  float(m.altitude))

    def _on_ref(self, m: Any) -> None:
        v = m.twist.twist.linear
        self._add("ref_velocity", "received_reference", _ns(m), np.array([v.x, v.y, v.z]),
                  np.asarray(m.twist.covariance)[[0, 7, 14]])

    def _on_height(self, data: bytes) -> None:
        """A height reference message (raw; counted as a reference and as a height)."""
        from ..bagio.errors import BagError
        from ..bagio.height_input import decode_height

        name = self.names[HEIGHT]
        self.counters.inc("received_height")
        try:
            stamp, h, var, no_fix = decode_height(self.p["ins3d_height_type"], [data], name)
        except BagError as exc:
            stamp, why = None, ("core_error", str(exc))
        else:
            why = ("no_fix", f"{name} message at {stamp[0] * 1e-9:.3f} s: status NO_FIX") \
                if no_fix[0] else None
        if why is not None:
            self.inputs.seen(name)
            self.counters.inc("received_reference")
            self.node._drop(f"{HEIGHT}_{why[0]}", why[1])
            return
        self._add(HEIGHT, "received_reference", int(stamp[0]), float(h[0]), float(var[0]))

    def _add(self, key: str, counter: str, ns: int, *values: Any) -> None:
        name = self.names[key]
        self.inputs.seen(name)
        self.counters.inc(counter)
        self._last_msg = time.monotonic()
        if self.asm.finished:                     # the record ended: this one starts anew
            self._new_record()
        try:
            got = self.asm.add(key, ns, *values)
            if isinstance(got, str):
                self.node._drop(f"{key}_{got}", f"{name} message at {ns * 1e-9:.3f} s: {got}")
                return
            self._process(got)
        except (CoreError, ValueError, np.linalg.LinAlgError) as exc:
            self.node._drop(f"{key}_core_error", f"{name} message at {ns * 1e-9:.3f} s: {exc}")
        finally:
            self._last_msg = time.monotonic()     # idle counts from the end of the work

    def finish(self) -> None:
        """Flush the end of the record (see the class docstring)."""
        self._process(self.asm.finish())

    # ------------------------------------------------------------------ filter
    def _process(self, events: list) -> None:
        for e in events:
            if self.stream is None:
                if not (isinstance(e, Boundary) and e.step is not None):
                    self._held.append(e)
                    continue
                s = e.step
                if self.height is not None:       # the datum's prior, from the data
                    self.model = replace(self.model, h0_sigma=self.asm.h0_sigma)
                P0 = initial_covariance(self.model, s.C[0], s.f_n[0], float(s.lat[0]),
                                        self.p["ins3d_aligned_prior"])
                self.stream = Ins3dStream(self.model, self.gate, P0=P0)
                self._publish_model()
                held, self._held = self._held, []
                for h in held:
                    self._apply(h)
            self._apply(e)

    def _apply(self, e: Any) -> None:
        st = self.stream
        if isinstance(e, Boundary):
            if e.step is not None:
                st.predict(e.step)
            self._publish_state(e.ns, u=() if e.step is None else pack_step(e.step),
                                dt=0.0 if e.step is None else float(e.step.dt[0]),
                                reset=e.step is None)
            return
        res = st.update(e.z, e.r, e.a)
        rows = self.model.rows
        H = self.model.H(e.a)
        self._publish_state(e.ns, z=e.z, r=np.diag(e.r), h=H, u=e.a, fused=res.fused,
                            gated=res.exceeded)
        self._publish_innovation(e.ns, res, rows)
        self.last, self.last_t = res, e.t
        if res.alarm == ALARM_RAISED:
            self.alarm_since = e.t
            self.node.get_logger().warning(
                f"ins3d: innovation alarm at t={e.t:.3f} s (beta2 {res.beta2:.3g} > "
                f"{st.threshold:.3g} in {self.gate.alarm_m} of the last {self.gate.alarm_n})")
        elif res.alarm == ALARM_CLEARED:
            self.alarm_since = None

    # ------------------------------------------------------------------ outputs
    @staticmethod
    def _stamp(ns: int) -> Any:
        from builtin_interfaces.msg import Time

        return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))

    def _publish_state(self, ns: int, z: Any = (), r: Any = (), h: Any = (), u: Any = (),
                       dt: float = 0.0, fused: bool = False, gated: bool = False,
                       reset: bool = False) -> None:
        from .convert import filter_state_msg

        st = self.stream
        self.node.pub_state.publish(filter_state_msg(
            self._stamp(ns), CHANNEL, self.model.names, st.x, st.P, z, r, h, u, dt, fused,
            gated, reset, frame_id=self.p["frame_id"]))
        self.counters.inc("published_states")

    def _publish_innovation(self, ns: int, res: Any, rows: int) -> None:
        from .convert import innovation_msg

        r = SimpleNamespace(nu=res.nu, S=res.S, beta2=res.beta2,
                            threshold=self.stream.threshold, exceeded=res.exceeded,
                            alarm_state=res.alarm)
        self.node.pub_innovation.publish(innovation_msg(
            self._stamp(ns), CHANNEL, self.row_names, r, frame_id=self.p["frame_id"]))
        self.counters.inc("published")

    def _publish_model(self) -> None:
        from flight_fdi_msgs.msg import ModelInfo

        m, g, st = self.model, self.gate, self.stream
        names, values = grade_params(m.grade)
        opt_names, opt_values = option_params({**model_options(self.p),
                                               "h0_sigma": m.h0_sigma})
        flat = lambda a: np.asarray(a, dtype=float).reshape(-1).tolist()
        self.node.pub_model.publish(ModelInfo(
            header=header(self.node.get_clock().now().to_msg(), self.p["frame_id"]),
            channel=CHANNEL, model_name=f"{MODEL}/{m.grade.name}", state_names=list(m.names),
            state_units=state_units(m.names), measurement_names=self.row_names,
            n=m.n, m=m.rows, p=0, a=[], qc=flat(np.diag(m.qc())), h=flat(m.H()), r=[],
            p0=flat(st.P), b=[], scale=flat(st.s),
            param_names=["rows", "t0_sec", "t0_nanosec", *opt_names, *names],
            param_values=[float(m.rows), *t0_params(self.asm.t0_ns), *opt_values, *values],
            gate_rule=g.rule, gate_probability=float(g.probability), alarm_m=g.alarm_m,
            alarm_n=g.alarm_n, gate_action=g.action))

    # ------------------------------------------------------------------ diagnostics
    def diagnostic_statuses(self) -> list:
        name = self.node.get_name()
        problems = self.inputs.problems(self.node.diagnostics.clock_stalled_s())
        values = self.inputs.key_values() + self.counters.key_values()
        values += [("late_reference_rows", str(self.asm.late)),
                   ("reference_outside_imu_record", str(self.asm.outside)),
                   ("waiting_reference_rows", str(len(self.asm.refs)))]
        out = [diag.make_status(f"{name}: inputs", diag.WARN if problems else diag.OK,
                                "; ".join(problems) if problems else "inputs OK", values,
                                hardware_id=self.names["ins_imu"])]
        res = self.last
        vals: list[tuple[str, Any]] = [
            ("beta2", math.nan if res is None else res.beta2),
            ("gate_threshold", self.gate.threshold(self.model.rows)),
            ("alarm_since_s", "" if self.alarm_since is None else f"{self.alarm_since:.3f}"),
            ("last_stamp_s", "" if self.last_t is None else f"{self.last_t:.3f}")]
        if res is not None:
            vals += [(f"beta2_{r}", float(b)) for r, b in zip(self.row_names, res.beta2_row)]
        if self.stream is not None:
            vals += [(n, float(v)) for n, v in zip(self.model.names, self.stream.x)]
        if self.alarm_since is not None:
            level, text = diag.WARN, (f"innovation alarm since t={self.alarm_since:.3f} s (the "
                                      "reference disagrees with the INS error model)")
        elif self.stream is None:
            level, text = diag.OK, "waiting for the first step (all four inputs)"
        else:
            level, text = diag.OK, "filtering"
        out.append(diag.make_status(f"{name}: ins3d", level, text, vals,
                                    hardware_id=self.names["ins_imu"]))
        return out


__all__ = ["INS3D_ONLY", "INS3D_PARAMS", "Ins3dMode", "MODEL", "build_model", "height_class",
           "height_parameters", "height_spec", "is_ins3d", "model_options", "option_parameters",
           "refuse_in_other_modes"]
