"""The whole node pipeline in one process: bag_player -> filter_node -> recorder_node ->
smoother_node, on one executor (what ``flight-fdi run BAG`` runs).

    run_pipeline(bag, out_dir, channel="x", *, config=None, model="ins_channel",
                 storage="mcap", overwrite=False, timeout_s=600.0, executor="events") -> dict

returns the result dict of the smoother (the JSON schema of ``flight-fdi analyze --json``: the
in-flight alarms and the localized fault) and leaves in ``out_dir``: ``recording/`` (the bag
recorded by recorder_node: fdi/innovation, fdi/state, fdi/model) and ``result.json``.
:func:`run_pipeline_detailed` returns a :class:`PipelineRun` with the same dict plus the
recording's path, counts and the replay throughput.

* The player replays the bag as fast as possible without loss: it paces itself by the filter's
  ``fdi/state`` messages (an end-to-end acknowledgement, see ``bag_player``), so no subscriber
  queue can overflow.
* The filter runs with the analysis's configuration (model, gate, alarm rule, gate action,
  ``max_gap_s``) on ``channel`` with reliable inputs; the smoother analyses the recording with the
  same AnalysisConfig and the same flight start (the earliest header stamp played), so the result
  agrees with ``flight-fdi analyze`` of the same bag (see test_pipeline.py for the tolerance).
* Isolation: the nodes run in a private rclpy Context created with
  ``ROS_AUTOMATIC_DISCOVERY_RANGE=OFF``: they talk to each other inside this process only, so a
  live ROS system on the same machine and domain neither hears the replay nor feeds it.
* Executor: rclpy's C++ ``EventsExecutor`` (about four times the throughput of the Python
  SingleThreadedExecutor here); ``executor="single"`` selects the latter.

Errors: a missing or unreadable bag -> BagError; an invalid ``channel`` or ``executor`` ->
ParameterError (flight_fdi.nodes.errors); a node that refuses its configuration (e.g. a model file
the filter cannot use, an output folder holding something that is not a bag), a replay that does
not finish in ``timeout_s`` or an analysis that fails -> PipelineError. Each carries one clear
sentence.
"""
from __future__ import annotations

import os
import signal
import time
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

from flight_fdi.bagio.errors import BagError

from .errors import ParameterError
from .runner import StopSignals, make_executor


class PipelineError(RuntimeError):
    """The pipeline did not produce a result (timeout, failed analysis)."""


@dataclass
class PipelineRun:
    """What :func:`run_pipeline_detailed` returns."""

    result: dict                      # JSON schema of flight-fdi analyze --json
    recording: Path                   # the bag written by recorder_node
    result_json: Path                 # the smoother's JSON file
    messages_played: int
    recorded: dict[str, int] = field(default_factory=dict)   # messages per recorded topic
    replay_s: float = 0.0             # wall time from the first message played to the last output
    analysis_s: float = 0.0           # wall time of the smoother's analysis
    ack_timeouts: int = 0             # the player had to continue without acknowledgement

    @property
    def throughput(self) -> float:
        """Input messages per second through player -> filter -> recorder."""
        return self.messages_played / self.replay_s if self.replay_s > 0 else float("nan")


@contextmanager
def _private_context(log_args: list[str]) -> Iterator[Any]:
    """An rclpy Context whose nodes discover nothing outside this process.

    ``log_args`` (e.g. ``--log-level warn``) set rcutils' *process-wide* default logger level;
    it is put back when the context ends, so that nodes created later in the same process (a
    test run, a notebook) log as before."""
    import rclpy
    import rclpy.logging
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    default_level = rclpy.logging.get_logger_effective_level("")
    ctx = Context()
    key = "ROS_AUTOMATIC_DISCOVERY_RANGE"
    saved = os.environ.get(key)
    os.environ[key] = "OFF"  # read by rcl_init: applies to this context only
    try:
        # no rclpy signal handler: Ctrl-C is StopSignals' request, acted on between callbacks
        rclpy.init(context=ctx, args=["flight_fdi_pipeline", "--ros-args", *log_args],
                   signal_handler_options=SignalHandlerOptions.NO)
    finally:
        if saved is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = saved
    try:
        yield ctx
    finally:
        if ctx.ok():
            rclpy.shutdown(context=ctx)
        rclpy.logging.set_logger_level("", default_level)


def filter_parameters(config: Any, channel: str, model: str, spec: Any = None,
                      types: dict[str, str] | None = None) -> dict[str, Any]:
    """filter_node parameters that make the live filter run as the analysis's forward pass;
    ``spec`` (bagio InputSpec) and ``types`` ({topic: message type} of the bag) name the
    inputs."""
    gate = config.gate
    inputs: dict[str, Any] = {}
    if spec is not None:
        refs = list(spec.reference_topics)
        inputs = {"ins_topic": spec.ins_topic, "odometry_twist_frame": spec.odometry_twist_frame}
        if len(refs) == 1:
            inputs["reference_topic"] = refs[0]
        else:
            inputs["reference_topics"] = refs
        if types:
            inputs["ins_type"] = types[spec.ins_topic]
            ref_types = {types[t] for t in refs}
            if len(ref_types) > 1:
                raise PipelineError(f"the reference topics carry different types "
                                    f"({', '.join(sorted(ref_types))}); the filter node reads "
                                    "one type for all of them")
            inputs["reference_type"] = ref_types.pop()
    return {**inputs, "model": model, "channels": [channel], "input_qos": "reliable",
            "gate_rule": gate.rule, "gate_probability": float(gate.probability),
            "alarm_m": int(gate.alarm_m), "alarm_n": int(gate.alarm_n),
            "gate_action": gate.action, "max_gap_s": float(config.max_gap_s),
            "buffer_s": max(2.0, 4.0 * float(config.max_gap_s))}


def check_inputs(bag: Path, spec: Any, config: Any) -> tuple[Any, dict]:
    """Before any ROS graph: read the bag's inputs as ``flight-fdi analyze`` does (BagError,
    one line, for a missing topic, a wrong type, a topic without a usable sample, no reference
    within the INS record) and count every unused message. Returns (FlightData, ``input``
    section)."""
    from flight_fdi.bagio import read_flight
    from flight_fdi.core.align import align_to_reference

    flight = read_flight(bag, spec=spec, with_truth=False)
    aligned, _ = align_to_reference(flight.ins_rel_s, flight.v_ins, flight.ref_rel_s,
                                    max_gap_s=config.max_gap_s)
    if not aligned.any():
        raise BagError(f"bag '{bag}': no reference sample lies within the INS record "
                       f"(max_gap_s = {config.max_gap_s} s)")
    return flight, flight.input_section(aligned)


class Progress:
    """Prints "replay NN %" to a stream each time another 10 % of the messages were played."""

    def __init__(self, total: int, stream: Any) -> None:
        self.total, self.stream, self.next = max(int(total), 1), stream, 10

    def __call__(self, played: int) -> None:
        if self.stream is None:
            return
        pct = 100 * played // self.total
        if pct >= self.next:
            self.next = (pct // 10 + 1) * 10
            print(f"replay {min(pct, 100):3d} % ({played} of {self.total} messages)",
                  file=self.stream, flush=True)


def _spin_until(executor: Any, done: Any, deadline: float, what: str,
                stop: StopSignals, tick: Any = None) -> None:
    """Spin until ``done()``; PipelineError at the deadline, KeyboardInterrupt once Ctrl-C was
    pressed (raised here, between callbacks, never inside a node's callback). ``tick()`` is
    called between spins (progress)."""
    while not done():
        if tick is not None:
            tick()
        if stop.stop:
            raise KeyboardInterrupt
        left = deadline - time.monotonic()
        if left <= 0:
            raise PipelineError(f"pipeline timed out while {what}")
        executor.spin_once(timeout_sec=min(0.05, left))


class Graph:
    """The pipeline's nodes on one executor in a private context (``with Graph(...) as g``):
    :meth:`build` a node from parameters, :meth:`spin_until` a condition, :meth:`drop` a node
    once its part is over; on exit every node left is destroyed and the executor shut down.
    ``timeout_s`` bounds the whole run (PipelineError); Ctrl-C raises KeyboardInterrupt between
    callbacks."""

    def __init__(self, executor: str = "events", log_level: str = "warn",
                 timeout_s: float = 600.0) -> None:
        self.deadline = time.monotonic() + timeout_s
        self.nodes: list[Any] = []
        self._kind, self._log_level = executor, log_level
        self._stack = ExitStack()

    def __enter__(self) -> "Graph":
        try:
            self.stop = self._stack.enter_context(StopSignals((signal.SIGINT,)))
            self.ctx = self._stack.enter_context(
                _private_context(["--log-level", self._log_level]))
            self.ex = make_executor(self._kind, self.ctx)
        except BaseException:
            self._stack.close()
            raise
        return self

    def __exit__(self, *exc: Any) -> None:
        try:
            for node in list(self.nodes):
                try:
                    self.ex.remove_node(node)
                except Exception:
                    pass
                node.destroy_node()
            self.ex.shutdown()
        finally:
            self._stack.close()

    def build(self, cls: Any, values: dict[str, Any], **extra: Any) -> Any:
        """A node of class ``cls`` with parameters ``values``, added to the executor
        (PipelineError naming the node when a parameter is refused)."""
        from rclpy.parameter import Parameter

        try:
            node = cls(context=self.ctx, start_parameter_services=False, **extra,
                       parameter_overrides=[Parameter(k, value=v) for k, v in values.items()])
        except ParameterError as exc:
            raise PipelineError(f"{cls.__name__}: {exc}") from None
        self.nodes.append(node)
        self.ex.add_node(node)
        return node

    def drop(self, node: Any) -> None:
        """Remove and destroy ``node``; its timers are cancelled first (the events executor may
        still run a removed node's due timer, e.g. /diagnostics)."""
        for timer in list(node.timers):
            timer.cancel()
        self.ex.remove_node(node)
        node.destroy_node()
        self.nodes.remove(node)

    def spin_until(self, done: Any, what: str, tick: Any = None) -> None:
        _spin_until(self.ex, done, self.deadline, what, self.stop, tick)

    def replay(self, player: Any, progress: "Progress") -> None:
        """Spin until ``player`` has published its whole bag (BagError when it failed)."""
        self.spin_until(player.done.done, "replaying the bag",
                        lambda: progress(player.published))
        progress(player.published)
        if player.error:
            raise BagError(player.error)

    def close_recording(self, rec: Any) -> dict:
        """Close the recording; its message counts per topic."""
        rec.close()
        if rec.error:
            raise PipelineError(f"recording failed: {rec.error}")
        return rec.counts()

    def finish(self, player: Any, flt: Any, rec: Any, settled: Any, config: Any,
               params: dict[str, Any], bag: Path, result_json: Path,
               extra: dict[str, Any]) -> "PipelineRun":
        """The end of every replay: spin until ``settled`` (the recorder holds the filter's last
        outputs), close the recording, drop the three nodes, run the smoother on the recording
        with ``params`` (``params['bag']``: the recording) and write its result -- ``bag`` (the input, as analyze names it) and
        ``extra`` added -- to ``result_json``."""
        from .smoother_node import write_json

        self.spin_until(settled, "recording the filter's last outputs")
        replay_s = time.monotonic() - player.started_at
        recorded = self.close_recording(rec)
        played, ack_timeouts = player.published, player.ack_timeouts
        for node in (player, flt, rec):
            self.drop(node)
        t_analysis = time.monotonic()
        result = self.smoother_result(config, params)
        result["bag"] = str(bag)
        result.update(extra)
        write_json(result, result_json)
        return PipelineRun(result=result, recording=Path(params["bag"]), result_json=result_json,
                           messages_played=played, recorded=recorded, replay_s=replay_s,
                           analysis_s=time.monotonic() - t_analysis, ack_timeouts=ack_timeouts)

    def smoother_result(self, config: Any, params: dict[str, Any]) -> dict:
        """Build the smoother node, spin until its analysis of the recording is done and return
        a copy of its result (PipelineError when it failed)."""
        from .smoother_node import SmootherNode

        smoother = self.build(SmootherNode, params, config=config)
        self.spin_until(smoother.done.done, "analysing the recording")
        run = smoother.last
        if run is None or run.error:
            raise PipelineError(f"analysis of {params['bag']} failed: "
                                f"{run.error if run else 'no result'}")
        return dict(run.result)


def run_pipeline_detailed(bag: str | Path, out_dir: str | Path, channel: str = "x", *,
                          config: Any = None, model: str = "ins_channel", storage: str = "mcap",
                          overwrite: bool = False, timeout_s: float = 600.0,
                          executor: str = "events", log_level: str = "warn",
                          spec: Any = None, progress: Any = None) -> PipelineRun:
    """Replay ``bag`` through the node pipeline; see the module docstring.

    ``config``: the core's AnalysisConfig (default: its defaults), used by the filter (gate,
    alarm rule, gate action, max_gap_s) and by the smoother. ``model``: the filter's ``model``
    parameter (built-in name or model YAML). ``log_level``: of the nodes' loggers (rcutils'
    default level is process-wide). The recording is closed once the filter has received every
    played message and the recorder holds every step the filter published (its ``published``
    counter) and its model -- exact counts, no waiting for quiet.

    ``spec``: the bagio InputSpec (topics, types, frames; default: the sample bags' layout on
    ``channel``). The inputs are checked (:func:`check_inputs`) before any node exists; the
    result carries the same ``input`` and ``source`` as ``flight-fdi analyze``. ``progress``: a
    stream for "replay NN %" lines per 10 % of the messages (None: silent).
    """
    from flight_fdi.bagio.inputs import InputSpec
    from flight_fdi.core.analysis import AnalysisConfig

    from .bag_player import BagPlayer
    from .filter_node import FilterNode
    from .recorder_node import RecorderNode

    if config is None:
        config = AnalysisConfig()
    if spec is None:
        if channel not in ("x", "y"):
            raise ParameterError(f"invalid channel {channel!r}; allowed: x, y")
        spec = InputSpec(channel=channel)
    channel = spec.component
    bag = Path(bag)
    # the inputs are usable, before anything is created (a graph never waits for bad input)
    flight, input_section = check_inputs(bag, spec, config)
    played_topics = [spec.ins_topic, *spec.reference_topics]
    tick_progress = Progress(sum(e["messages"] for e in input_section.values()), progress)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    recording, result_json = out / "recording", out / "result.json"
    with Graph(executor, log_level, timeout_s) as g:
        flt = g.build(FilterNode, filter_parameters(config, channel, model, spec, flight.topics))
        rec = g.build(RecorderNode, {"output": str(recording), "storage": storage,
                                     "overwrite": overwrite})
        player = g.build(BagPlayer, {"bag": str(bag), "fast": True, "ack_topic": "fdi/state",
                                     "publish_clock": False, "topics": played_topics})
        g.replay(player, tick_progress)
        # the replay is over once the filter has taken every played message and the recorder
        # holds every step the filter published (and its model): exact counts
        topics = [rec.resolve_topic_name(t) for t in ("fdi/state", "fdi/innovation")]
        model_topic = rec.resolve_topic_name("fdi/model")

        def settled() -> bool:
            c = flt.counters
            if c["received_ins"] + c["received_reference"] < player.published:
                return False
            counts = rec.counts()
            return (all(counts.get(t, 0) >= c["published"] for t in topics)
                    and counts.get(model_topic, 0) >= 1)

        run = g.finish(player, flt, rec, settled, config, {
            "bag": str(recording), "channel": channel, "output_json": str(result_json),
            # analyze's t0: the earliest usable INS / reference stamp
            "flight_start_s": flight.t0_ns * 1e-9, "publish_smoothed": False},
            bag, result_json, {"input": input_section, "source": spec.describe()})
    return run


def run_pipeline(bag: str | Path, out_dir: str | Path, channel: str = "x", **kwargs: Any) -> dict:
    """``flight-fdi run BAG``: the result dict of :func:`run_pipeline_detailed`."""
    return run_pipeline_detailed(bag, out_dir, channel, **kwargs).result
