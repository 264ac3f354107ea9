"""The whole node pipeline in one process: bag_player -> filter_node -> recorder_node ->
smoother_node, on one executor (what ``flight-fdi run BAG`` runs).

    run_pipeline(bag, out_dir, channel="x", *, config=None, model="ins_channel",
                 storage="mcap", overwrite=False, timeout_s=600.0, executor="events") -> dict

returns the result dict of the smoother (the JSON schema of ``flight-fdi analyze --json``: the
in-flight alarms and the localized fault) and leaves in ``out_dir``: ``recording/`` (the bag
recorded by recorder_node: fdi/innovation, fdi/state, fdi/model) and ``result.json``.
:func:`run_pipeline_detailed` returns a :class:`PipelineRun` with the same dict plus the
recording's path, counts, the replay throughput, the smoother's analysis and the input read
before the replay (``flight-fdi run``'s report is drawn from these: no second read or
analysis).

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
with the pipeline's own status (0 after a result, 1 after an error, 130 after Ctrl-C). After a
result, ``on_teardown_timeout(run)`` (when given; ``run`` the :class:`PipelineRun`) comes first:
what the caller still had to do with it (``flight-fdi run`` prints it and writes the report); its
return value is the status.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from flight_fdi.bagio.errors import BagError

from .errors import ParameterError
# the graph machinery (pipeline_graph), also importable from here as before
from .pipeline_graph import (STALL_TIMEOUT_S, TEARDOWN_TIMEOUT_S, TIMEOUT_S,  # noqa: F401
                             Graph, PipelineError, PipelineRun, Progress, StallWatch,
                             _private_context)


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


def check_inputs(bag: Path, spec: Any, config: Any, with_truth: bool = False
                 ) -> tuple[Any, dict]:
    """Before any ROS graph: read the bag's inputs as ``flight-fdi analyze`` does (BagError,
    one line, for a missing topic, a wrong type, a topic without a usable sample, no reference
    within the INS record) and count every unused message. Returns (FlightData, with the
    simulator's truth when ``with_truth``; ``input`` section)."""
    from flight_fdi.bagio import read_flight
    from flight_fdi.core.align import align_to_reference

    flight = read_flight(bag, spec=spec, with_truth=with_truth)
    aligned, _ = align_to_reference(flight.ins_rel_s, flight.v_ins, flight.ref_rel_s,
                                    max_gap_s=config.max_gap_s)
    if not aligned.any():
        raise BagError(f"bag '{bag}': no reference sample lies within the INS record "
                       f"(max_gap_s = {config.max_gap_s} s)")
    return flight, flight.input_section(aligned)


def run_pipeline_detailed(bag: str | Path, out_dir: str | Path, channel: str = "x", *,
                          config: Any = None, model: str = "ins_channel", storage: str = "mcap",
                          overwrite: bool = False, timeout_s: float = TIMEOUT_S,
                          executor: str = "events", log_level: str = "warn",
                          spec: Any = None, progress: Any = None,
                          stall_timeout_s: float = STALL_TIMEOUT_S,
                          teardown_timeout: float | None = TEARDOWN_TIMEOUT_S,
                          on_teardown_timeout: Any = None,
                          with_truth: bool = False) -> PipelineRun:
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
    docstring (validated first: ParameterError); ``on_teardown_timeout``: called with the
    PipelineRun when the teardown after it times out, returns the exit status (module docstring).
    ``with_truth``: the input read before the replay (the PipelineRun's ``read``, a FlightData)
    holds the simulator's truth (for a report).
    """
    from flight_fdi.bagio.inputs import InputSpec
    from flight_fdi.core.analysis import AnalysisConfig

    from .bag_player import BagPlayer
    from .filter_node import FilterNode
    from .recorder_node import RecorderNode

    graph = Graph(executor, log_level, timeout_s, stall_timeout_s, teardown_timeout,
                  on_teardown_timeout)
    if config is None:
        config = AnalysisConfig()
    if spec is None:
        if channel not in ("x", "y"):
            raise ParameterError(f"invalid channel {channel!r}; allowed: x, y")
        spec = InputSpec(channel=channel)
    channel = spec.component
    bag = Path(bag)
    # the inputs are usable, before anything is created (a graph never waits for bad input)
    flight, input_section = check_inputs(bag, spec, config, with_truth)
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
            bag, result_json, {"input": input_section, "source": spec.describe()}, flight)
    return run


def run_pipeline(bag: str | Path, out_dir: str | Path, channel: str = "x", **kwargs: Any) -> dict:
    """``flight-fdi run BAG``: the result dict of :func:`run_pipeline_detailed`."""
    return run_pipeline_detailed(bag, out_dir, channel, **kwargs).result
