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

Errors: a missing or unreadable bag -> BagError; an invalid ``channel``, ``executor``,
``timeout_s``, ``stall_timeout_s`` or ``teardown_timeout`` -> ParameterError
(flight_fdi.nodes.errors); a node that refuses its configuration (e.g. a model file the filter
cannot use, an output folder holding something that is not a bag), a replay that does not finish
in ``timeout_s``, a stage that stalls (below), a recording that fails or an analysis that fails ->
PipelineError. Each carries one clear sentence.

Bounds (docs/hardening.md, section 5): a stage with work waiting that does none of it for
``stall_timeout_s`` (60 s) -> PipelineError naming it (:class:`StallWatch`). Whatever ends the run,
every node's own work is completed first (the recorder closes its bag), then the middleware
teardown (all nodes, executor, context) is bounded by ``teardown_timeout`` (runner's
TeardownWatchdog, 10 s; None: unbounded): one WARN line naming what blocked, the stacks, and exit
with the pipeline's own status (0 after a result, 1 after an error, 130 after Ctrl-C).
"""
from __future__ import annotations

import math
import os
import signal
import time
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

from flight_fdi.bagio.errors import BagError

from .errors import ParameterError
from .runner import TEARDOWN_TIMEOUT_S, StopSignals, TeardownWatchdog, make_executor

STALL_TIMEOUT_S = 60.0  # a stage with work waiting that does none of it this long: stalled


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
        try:
            if ctx.ok():
                rclpy.shutdown(context=ctx)
            ctx.destroy()  # rcl_context_fini now (inside the pipeline's bounded teardown)
        finally:
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


def seconds(name: str, value: Any, none_ok: bool = False) -> float | None:
    """``value`` as a finite number of seconds > 0 (None when ``none_ok``); ParameterError."""
    if value is None and none_ok:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            not math.isfinite(value) or value <= 0:
        raise ParameterError(f"invalid {name} {value!r}; allowed: a number of seconds > 0"
                             + (" or None (no bound)" if none_ok else ""))
    return float(value)


class StallWatch:
    """Names a stage that has work waiting and did none of it for ``bound_s`` seconds.

    :meth:`check` (called by the spin loop every ~0.1 s) takes ``(stage, done, waiting)``
    triples -- ``done`` a count that grows with the stage's work, ``waiting`` how much work waits
    for it -- and returns the first stage (in pipeline order) whose ``done`` has not changed for
    ``bound_s`` of watching while ``waiting`` > 0, as one sentence; None when every stage moves
    or has nothing to do. The time between two checks counts at most ``max_step_s``: a loop
    held by a long callback (the player's drain) or a process starved of CPU gave no stage a
    chance to progress, so that is no stage's stall."""

    def __init__(self, bound_s: float, clock: Any = time.monotonic,
                 max_step_s: float = 0.25) -> None:
        self.bound_s, self.clock, self.max_step_s = bound_s, clock, max_step_s
        self._seen: dict[str, tuple[int, float]] = {}   # stage -> (done, seconds without)
        self._last: float | None = None

    def check(self, stages: list[tuple[str, int, int]]) -> str | None:
        now = self.clock()
        step = 0.0 if self._last is None else min(now - self._last, self.max_step_s)
        self._last = now
        for name, done, waiting in stages:
            seen = self._seen.get(name)
            if waiting <= 0 or seen is None or seen[0] != done:
                self._seen[name] = (done, 0.0)
                continue
            self._seen[name] = (done, seen[1] + step)
            if seen[1] + step >= self.bound_s:
                return (f"{name} made no progress for {self.bound_s:g} s ({waiting} messages "
                        f"waiting for it, {done} done)")
        return None


def _spin_until(executor: Any, done: Any, deadline: float, what: str,
                stop: StopSignals, tick: Any = None, stalled: Any = None) -> None:
    """Spin until ``done()``; PipelineError at the deadline or when ``stalled()`` (called at
    most every 0.1 s) names a stalled stage, KeyboardInterrupt once Ctrl-C was pressed (raised
    here, between callbacks, never inside a node's callback). ``tick()`` is called between
    spins (progress)."""
    next_check = 0.0
    while not done():
        if tick is not None:
            tick()
        if stop.stop:
            raise KeyboardInterrupt
        now = time.monotonic()
        if stalled is not None and now >= next_check:
            next_check = now + 0.1
            stall = stalled()
            if stall:
                raise PipelineError(f"pipeline stalled while {what}: {stall}")
        left = deadline - now
        if left <= 0:
            raise PipelineError(f"pipeline timed out while {what}")
        executor.spin_once(timeout_sec=min(0.05, left))


class Graph:
    """The pipeline's nodes on one executor in a private context (``with Graph(...) as g``):
    :meth:`build` a node from parameters, :meth:`spin_until` a condition, :meth:`retire` a node
    once its part is over. ``timeout_s`` bounds the whole run, ``stall_timeout_s`` a watched
    stage's stall (:meth:`watch`), both PipelineError; Ctrl-C raises KeyboardInterrupt between
    callbacks. On exit: every node's ``finish_work()``, then the teardown bounded by
    ``teardown_timeout`` (module docstring). The bounds are validated here (ParameterError)."""

    NAME = "flight_fdi_pipeline"

    def __init__(self, executor: str = "events", log_level: str = "warn",
                 timeout_s: float = 600.0, stall_timeout_s: float = STALL_TIMEOUT_S,
                 teardown_timeout: float | None = TEARDOWN_TIMEOUT_S) -> None:
        self.timeout_s = seconds("timeout_s", timeout_s)
        self.stall = StallWatch(seconds("stall_timeout_s", stall_timeout_s))
        self.teardown_timeout = seconds("teardown_timeout", teardown_timeout, none_ok=True)
        self.nodes: list[Any] = []
        self._stages: Any = None   # the watched stages (watch)
        self._kind, self._log_level = executor, log_level
        self._stack = ExitStack()

    def __enter__(self) -> "Graph":
        self.deadline = time.monotonic() + self.timeout_s
        try:
            self.stop = self._stack.enter_context(StopSignals((signal.SIGINT,)))
            self.ctx = self._stack.enter_context(
                _private_context(["--log-level", self._log_level]))
            self.ex = make_executor(self._kind, self.ctx)
        except BaseException:
            self._stack.close()
            raise
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        failure = exc
        try:  # the nodes' own work complete (a recording closed) before anything can block
            for node in self.nodes:
                if hasattr(node, "finish_work"):
                    node.finish_work()
        except BaseException as err:
            failure = failure or err
            raise
        finally:
            status, after = self._outcome(failure)
            with TeardownWatchdog(self.NAME, status, self.teardown_timeout, after) as watchdog:
                self._teardown(watchdog)

    @staticmethod
    def _outcome(failure: BaseException | None) -> tuple[int, str]:
        """The pipeline's own exit status (as ``flight-fdi run`` gives it) and what was complete
        before the teardown, for the watchdog's line."""
        if failure is None:
            return 0, "the pipeline's work was complete (recording closed, result written)"
        if isinstance(failure, KeyboardInterrupt):
            return 130, "the pipeline was interrupted (recording closed)"
        return 1, f"the pipeline failed ({failure}; recording closed)"

    def _teardown(self, watchdog: TeardownWatchdog) -> None:
        for node in list(self.nodes):
            watchdog.stage = f"destroying node {node.get_name()}"
            try:
                self.ex.remove_node(node)
            except Exception:  # (already retired)
                pass
            node.destroy_node()
            self.nodes.remove(node)
        watchdog.stage = "shutting down the executor"
        self.ex.shutdown()
        watchdog.stage = "shutting down the context"
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

    def retire(self, node: Any) -> None:
        """Take ``node`` off the executor once its part is over; its timers are cancelled first
        (the events executor may still run a removed node's due timer, e.g. /diagnostics). It is
        destroyed with the others in the bounded teardown at the end."""
        for timer in list(node.timers):
            timer.cancel()
        self.ex.remove_node(node)

    def watch(self, player: Any, flt: Any, rec: Any, owed: Any) -> None:
        """From now on :meth:`spin_until` watches the replay's stages for a stall
        (:class:`StallWatch`): the player (messages left to play), the filter (played messages
        not taken) and the recorder (``owed(filter counters, recorder counts)``: the filter's
        outputs not recorded yet). A recorder error ends the run at once (PipelineError)."""
        def stages() -> list[tuple[str, int, int]]:
            if rec.error:
                raise PipelineError(f"recording failed: {rec.error}")
            c, n = flt.counters, rec.counts()
            taken = c["received_ins"] + c["received_reference"]
            # the player's work waits for it unless its window is full (then it waits for the
            # filter's acknowledgements, a stall downstream)
            left = (0 if player.done.done() or player.in_flight >= player.params["ack_window"]
                    else player.source.count - player.published)
            return [(player.get_name(), player.published, left),
                    (flt.get_name(), taken, player.published - taken),
                    (rec.get_name(), sum(n.values()), owed(c, n))]

        self._stages = stages

    def settled(self) -> bool:
        """No watched stage has work waiting: the filter took every played message and the
        recorder holds every output the filter published."""
        return all(waiting <= 0 for _, _, waiting in self._stages())

    def _stalled(self) -> str | None:
        return self.stall.check(self._stages())

    def spin_until(self, done: Any, what: str, tick: Any = None) -> None:
        _spin_until(self.ex, done, self.deadline, what, self.stop, tick,
                    None if self._stages is None else self._stalled)

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

    def finish(self, player: Any, flt: Any, rec: Any, config: Any,
               params: dict[str, Any], bag: Path, result_json: Path,
               extra: dict[str, Any]) -> "PipelineRun":
        """The end of every replay: spin until :meth:`settled` (the recorder holds the filter's
        last outputs), close the recording, retire the three nodes, run the smoother on the
        recording with ``params`` (``params['bag']``: the recording) and write its result --
        ``bag`` (the input, as analyze names it) and ``extra`` added -- to ``result_json``."""
        from .smoother_node import write_json

        self.spin_until(self.settled, "recording the filter's last outputs")
        replay_s = time.monotonic() - player.started_at
        recorded = self.close_recording(rec)
        self._stages = None
        played, ack_timeouts = player.published, player.ack_timeouts
        for node in (player, flt, rec):
            self.retire(node)
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
                          spec: Any = None, progress: Any = None,
                          stall_timeout_s: float = STALL_TIMEOUT_S,
                          teardown_timeout: float | None = TEARDOWN_TIMEOUT_S) -> PipelineRun:
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
    ``timeout_s``, ``stall_timeout_s``, ``teardown_timeout``: the bounds of the module
    docstring (validated first: ParameterError).
    """
    from flight_fdi.bagio.inputs import InputSpec
    from flight_fdi.core.analysis import AnalysisConfig

    from .bag_player import BagPlayer
    from .filter_node import FilterNode
    from .recorder_node import RecorderNode

    graph = Graph(executor, log_level, timeout_s, stall_timeout_s, teardown_timeout)
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
    with graph as g:
        flt = g.build(FilterNode, filter_parameters(config, channel, model, spec, flight.topics))
        rec = g.build(RecorderNode, {"output": str(recording), "storage": storage,
                                     "overwrite": overwrite})
        player = g.build(BagPlayer, {"bag": str(bag), "fast": True, "ack_topic": "fdi/state",
                                     "publish_clock": False, "topics": played_topics})
        # the replay is over once the filter has taken every played message and the recorder
        # holds every step the filter published (and its model): exact counts
        topics = [rec.resolve_topic_name(t) for t in ("fdi/state", "fdi/innovation")]
        model_topic = rec.resolve_topic_name("fdi/model")

        def owed(c: Any, n: dict[str, int]) -> int:
            return (sum(max(0, c["published"] - n.get(t, 0)) for t in topics)
                    + max(0, 1 - n.get(model_topic, 0)))

        g.watch(player, flt, rec, owed)
        g.replay(player, tick_progress)
        run = g.finish(player, flt, rec, config, {
            "bag": str(recording), "channel": channel, "output_json": str(result_json),
            # analyze's t0: the earliest usable INS / reference stamp
            "flight_start_s": flight.t0_ns * 1e-9, "publish_smoothed": False},
            bag, result_json, {"input": input_section, "source": spec.describe()})
    return run


def run_pipeline(bag: str | Path, out_dir: str | Path, channel: str = "x", **kwargs: Any) -> dict:
    """``flight-fdi run BAG``: the result dict of :func:`run_pipeline_detailed`."""
    return run_pipeline_detailed(bag, out_dir, channel, **kwargs).result
