"""The machinery of the one-process node pipeline (``pipeline.run_pipeline_detailed``,
``ins3d_pipeline.run_pipeline3d``): the nodes on one executor in a private rclpy context
(:class:`Graph`), the stall watch of its stages (:class:`StallWatch`), the bounds of a run
(``timeout_s``, ``stall_timeout_s``, ``teardown_timeout``, validated by :func:`seconds`), the
replay's progress lines (:class:`Progress`), and what a run returns (:class:`PipelineRun`) or
raises (:class:`PipelineError`). The pipeline's contract -- errors, bounds, what a blocked
teardown does -- is the docstring of ``pipeline``; docs/hardening.md section 5.
"""
from __future__ import annotations

import math
import os
import signal
import time
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

from flight_fdi.bagio.errors import BagError

from .errors import ParameterError
from .runner import (TEARDOWN_TIMEOUT_S, SpinWatchdog, StopSignals, TeardownWatchdog,
                     make_executor)

TIMEOUT_S = 600.0       # the whole run (replay, recording, analysis): its work done by then
STALL_TIMEOUT_S = 60.0  # a stage with work waiting that does none of it this long: stalled
#: past the run's deadline by this much with a node callback still running (the spin loop
#: never got back to check the deadline): ``runner.SpinWatchdog`` ends the process
SPIN_GRACE_S = 10.0


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
    smoother: Any = None              # the smoother's SmootherRun (its analysis, recording)
    read: Any = None                  # what was read of the input bag before the replay

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
                stop: StopSignals, tick: Any = None, stalled: Any = None,
                timeout_s: float | None = None) -> None:
    """Spin until ``done()``; PipelineError at the deadline (naming ``timeout_s``, the run's
    bound, when given) or when ``stalled()`` (called at most every 0.1 s) names a stalled stage,
    KeyboardInterrupt once Ctrl-C was pressed (raised here, between callbacks, never inside a
    node's callback). ``tick()`` is called between spins (progress)."""
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
            bound = "" if timeout_s is None else f" (the run's bound: {timeout_s:g} s)"
            raise PipelineError(f"pipeline timed out while {what}{bound}")
        executor.spin_once(timeout_sec=min(0.05, left))


class Graph:
    """The pipeline's nodes on one executor in a private context (``with Graph(...) as g``):
    :meth:`build` a node from parameters, :meth:`spin_until` a condition, :meth:`retire` a node
    once its part is over. ``timeout_s`` bounds the whole run, ``stall_timeout_s`` a watched
    stage's stall (:meth:`watch`), both PipelineError; Ctrl-C raises KeyboardInterrupt between
    callbacks. On exit: every node's ``finish_work()``, then the teardown bounded by
    ``teardown_timeout`` (``pipeline``'s module docstring). The bounds are validated here
    (ParameterError). ``on_teardown_timeout(result)``: what the caller still does with the
    result (:meth:`finish`'s) should the teardown after it time out -- the watchdog calls it and
    exits with the status it returns (runner.TeardownWatchdog's ``on_timeout``); None: exit
    with status 0 at once. ``result``: the :class:`PipelineRun` of :meth:`finish`."""

    NAME = "flight_fdi_pipeline"

    def __init__(self, executor: str = "events", log_level: str = "warn",
                 timeout_s: float = TIMEOUT_S, stall_timeout_s: float = STALL_TIMEOUT_S,
                 teardown_timeout: float | None = TEARDOWN_TIMEOUT_S,
                 on_teardown_timeout: Callable[["PipelineRun"], int] | None = None) -> None:
        self.timeout_s = seconds("timeout_s", timeout_s)
        self.stall = StallWatch(seconds("stall_timeout_s", stall_timeout_s))
        self.teardown_timeout = seconds("teardown_timeout", teardown_timeout, none_ok=True)
        self.on_teardown_timeout = on_teardown_timeout
        self.result: PipelineRun | None = None   # finish's, once its result is written
        self.nodes: list[Any] = []
        self._stages: Any = None   # the watched stages (watch)
        self._kind, self._log_level = executor, log_level
        self._stack = ExitStack()

    def __enter__(self) -> "Graph":
        self.deadline = time.monotonic() + self.timeout_s
        self.guard = SpinWatchdog(self.NAME, self.timeout_s + SPIN_GRACE_S).__enter__()
        try:
            self.stop = self._stack.enter_context(StopSignals((signal.SIGINT,)))
            self.ctx = self._stack.enter_context(
                _private_context(["--log-level", self._log_level]))
            self.ex = make_executor(self._kind, self.ctx)
        except BaseException:
            self.guard.__exit__(None, None, None)
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
            self.guard.__exit__(None, None, None)   # the spin is over (the teardown's own bound)
            status, after = self._outcome(failure)
            with TeardownWatchdog(self.NAME, status, self.teardown_timeout, after,
                                  self._on_timeout(failure)) as watchdog:
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

    def _on_timeout(self, failure: BaseException | None) -> Callable[[], int] | None:
        """The watchdog's ``on_timeout``: ``on_teardown_timeout`` of the result, when the run
        gave one."""
        then, result = self.on_teardown_timeout, self.result
        if failure is not None or result is None or then is None:
            return None
        return lambda: then(result)

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
        self.guard.stage = what
        _spin_until(self.ex, done, self.deadline, what, self.stop, tick,
                    None if self._stages is None else self._stalled, self.timeout_s)

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
               extra: dict[str, Any], read: Any = None) -> "PipelineRun":
        """The end of every replay: spin until :meth:`settled` (the recorder holds the filter's
        last outputs), close the recording, retire the three nodes, run the smoother on the
        recording with ``params`` (``params['bag']``: the recording) and write its result --
        ``bag`` (the input, as analyze names it) and ``extra`` added -- to ``result_json``.
        The PipelineRun keeps the smoother's run (its analysis: a report needs no second one)
        and ``read``, what the caller read of the input bag."""
        from flight_fdi.core.recording import write_json

        self.spin_until(self.settled, "recording the filter's last outputs")
        replay_s = time.monotonic() - player.started_at
        recorded = self.close_recording(rec)
        self._stages = None
        played, ack_timeouts = player.published, player.ack_timeouts
        for node in (player, flt, rec):
            self.retire(node)
        t_analysis = time.monotonic()
        smoother = self.smoother_run(config, params)
        result = dict(smoother.result)
        result["bag"] = str(bag)
        result.update(extra)
        write_json(result, result_json)
        self.result = PipelineRun(
            result=result, recording=Path(params["bag"]), result_json=result_json,
            messages_played=played, recorded=recorded, replay_s=replay_s,
            analysis_s=time.monotonic() - t_analysis, ack_timeouts=ack_timeouts,
            smoother=smoother, read=read)
        return self.result

    def smoother_run(self, config: Any, params: dict[str, Any]) -> Any:
        """Build the smoother node, spin until its analysis of the recording is done and return
        its SmootherRun (PipelineError when it failed)."""
        from .smoother_node import SmootherNode

        smoother = self.build(SmootherNode, params, config=config)
        self.spin_until(smoother.done.done, "analysing the recording")
        run = smoother.last
        if run is None or run.error:
            raise PipelineError(f"analysis of {params['bag']} failed: "
                                f"{run.error if run else 'no result'}")
        return run


__all__ = ["STALL_TIMEOUT_S", "TEARDOWN_TIMEOUT_S", "TIMEOUT_S", "Graph", "PipelineError",
           "PipelineRun",
           "Progress", "StallWatch", "seconds"]
