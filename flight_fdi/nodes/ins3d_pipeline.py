"""``flight-fdi run BAG --model ins3d``: the node pipeline on a 3-D contract bag, in one process.

bag_player (the four contract topics) -> filter_node (``model: ins3d``) -> recorder_node ->
smoother_node (``channel: ins3d``) on one executor, in the private context of
``pipeline.run_pipeline_detailed`` (nothing outside this process hears the replay). The smoother
rebuilds the 3-D filter's inputs from the recording and runs the analysis of ``flight-fdi
analyze --model ins3d`` (``bagio.recording_analysis``): the same verdict and numbers
(test_ins3d_pipeline.py).

The player paces on ``fdi/state`` with a window of ``ACK_WINDOW`` messages: the ins3d filter
looks ahead (a step waits for the next /ins/fix sample, 0.2 s at 5 Hz), so the window must cover
~15 messages; and it bounds how far one topic's messages can run ahead of another's in the
filter's callbacks (~1.1 s of the sample bags), which must stay below the filter's
``ins3d_wait_s`` (``WAIT_S``) or reference rows would come after their step was taken. A bag with
a sparse reference (e.g. 1 Hz against 40-Hz INS topics: the real recordings of
docs/ins3d_real.md) holds a reference period of INS messages back; its window covers two
periods plus the sample bags' margin (``ack_window``; the sample bags keep ``ACK_WINDOW``). At
the end of the replay the filter is flushed (``Ins3dMode.finish``) before the recording is
closed.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from .pipeline_graph import (STALL_TIMEOUT_S, TEARDOWN_TIMEOUT_S, TIMEOUT_S, Graph, PipelineRun,
                             Progress)

ACK_WINDOW = 60
MARGIN = 45         # a sample bag's ~15 messages of look-ahead, three times
WAIT_S = 5.0


def ack_window(counts: dict[str, int], reference_topic: str) -> int:
    """The player's window (module docstring): ``ACK_WINDOW``, or for a bag with more
    messages per reference period (a sparse reference) two periods' messages plus ``MARGIN``."""
    n_ref = counts.get(reference_topic, 0)
    if n_ref < 1:
        return ACK_WINDOW
    per_period = math.ceil((sum(counts.values()) - n_ref) / n_ref)
    return max(ACK_WINDOW, 2 * per_period + MARGIN)


def filter_parameters3d(names: dict[str, str], grade: str, rows: int, gate: Any,
                        options: dict | None = None, height: Any = None,
                        height_type: str | None = None) -> dict:
    """filter_node parameters of the ins3d mode for a replay (reliable inputs); ``options``: the
    model options of the bag's description (``bagio.ins3d_input.error_model_options``);
    ``height``: a ``bagio.height_input.HeightSpec`` whose topic carries ``height_type``. The
    end-of-input idle flush is off (``ins3d_end_idle_s`` 0): the pipeline flushes at the end of
    its bag itself, and a replay starved of CPU for 2 s must not split the record in two."""
    from .ins3d_mode import height_parameters, option_parameters

    return {**option_parameters(options or {}), "model": "ins3d",
            "imu_topic": names["ins_imu"], "ins_topic": names["ins_velocity"],
            "fix_topic": names["ins_fix"], "reference_topic": names["ref_velocity"],
            "ins3d_grade": grade, "ins3d_rows": int(rows), "ins3d_wait_s": WAIT_S,
            "ins3d_end_idle_s": 0.0,
            "input_qos": "reliable",
            "gate_rule": gate.rule, "gate_probability": float(gate.probability),
            "alarm_m": int(gate.alarm_m), "alarm_n": int(gate.alarm_n),
            "gate_action": gate.action,
            **({} if height is None else height_parameters(height, height_type))}


def run_pipeline3d(bag: str | Path, out_dir: str | Path, *, topics: dict[str, str] | None = None,
                   grade: str = "navigation", rows: int = 2, gate: Any = None,
                   storage: str = "mcap", overwrite: bool = False, timeout_s: float = TIMEOUT_S,
                   executor: str = "events", log_level: str = "warn", source: dict | None = None,
                   progress: Any = None, options: dict | None = None,
                   stall_timeout_s: float = STALL_TIMEOUT_S,
                   teardown_timeout: float | None = TEARDOWN_TIMEOUT_S,
                   on_teardown_timeout: Any = None, with_truth: bool = False,
                   height: Any = None) -> PipelineRun:
    """Replay ``bag`` through the ins3d pipeline (module docstring); the inputs are checked
    before any node exists (BagError: topics, types, and every message read raw by bagio's
    reader -- a corrupt bag is one line, never a replay of what rosbags' iterator makes of it:
    ``bagio.ins3d_input.check_messages``). Leaves ``recording/`` and ``result.json`` in
    ``out_dir``; the result's ``input`` section is the filter's count of the messages it
    received and dropped (``input_section_of_run``: that of ``analyze``, no second read).
    ``options``: the model options (``filter_parameters3d``; the filter records
    them, the smoother analyses with them). ``timeout_s``, ``stall_timeout_s``,
    ``teardown_timeout``: the bounds of ``pipeline`` (its module docstring: a stalled stage
    ends the run with PipelineError; the teardown after the result is bounded), and
    ``on_teardown_timeout`` what is done with the result should that bound be reached.
    ``with_truth``: that read also takes the simulator's truth (the PipelineRun's ``read``:
    ``bagio.ins3d_input.truth_of_raw``'s, or None), for a report. ``height``: a
    ``bagio.height_input.HeightSpec``: its topic is checked, played and filtered as the third
    row (``analyze --height-topic``)."""
    from flight_fdi.bagio.ins3d_input import checked_messages
    from flight_fdi.core.analysis import AnalysisConfig
    from flight_fdi.core.gate import GateConfig

    from .bag_player import BagPlayer
    from .filter_node import FilterNode
    from .recorder_node import RecorderNode

    graph = Graph(executor, log_level, timeout_s, stall_timeout_s, teardown_timeout,
                  on_teardown_timeout)
    gate = gate or GateConfig()
    bag = Path(bag)
    # every message read once before any node (corrupt data: one line now, not garbage
    # played), which gives the counts for the progress and the player's window
    names, counts, truth, height_type = checked_messages(
        bag, topics, with_truth, None if height is None else height.topic)
    played = list(counts)
    tick_progress = Progress(sum(counts.values()) or 1, progress)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    recording, result_json = out / "recording", out / "result.json"
    with graph as g:
        flt = g.build(FilterNode, filter_parameters3d(names, grade, rows, gate, options,
                                                      height, height_type))
        rec = g.build(RecorderNode, {"output": str(recording), "storage": storage,
                                     "overwrite": overwrite})
        player = g.build(BagPlayer, {"bag": str(bag), "fast": True, "ack_topic": "fdi/state",
                                     "ack_window": ack_window(counts, names["ref_velocity"]),
                                     "publish_clock": False,
                                     "topics": played})
        state, innov, model = (rec.resolve_topic_name(t) for t in
                               ("fdi/state", "fdi/innovation", "fdi/model"))

        def owed(c: Any, n: dict[str, int]) -> int:  # the filter's outputs not recorded yet
            return (max(0, c["published_states"] - n.get(state, 0))
                    + max(0, c["published"] - n.get(innov, 0)) + max(0, 1 - n.get(model, 0)))

        g.watch(player, flt, rec, owed)
        g.replay(player, tick_progress)
        c = flt.counters
        g.spin_until(lambda: c["received_ins"] + c["received_reference"] >= player.published,
                     "filtering the last inputs")
        flt.ins3d.finish()
        extra = {"input": input_section_of_run(flt.ins3d, names)}
        run = g.finish(player, flt, rec, AnalysisConfig(gate=gate), {
            "bag": str(recording), "channel": "ins3d", "output_json": str(result_json),
            "publish_smoothed": False}, bag, result_json,
            extra if source is None else {**extra, "source": source}, truth)
    return run


def input_section_of_run(mode: Any, names: dict[str, str]) -> dict:
    """The result's ``input`` section (``bagio.ins3d_input.section3d``, the form of ``analyze
    --model ins3d``'s) from what the filter's ins3d mode (``mode``, flushed) counted -- the bag
    is not read again: the messages it received per topic, those it dropped per topic and
    reason (``dropped_<role>_<reason>``), the references outside the IMU record (always
    given, as analyze does) and those that came late. ``names``: {role: the bag's topic}."""
    from flight_fdi.bagio.ins3d_input import section3d

    counters = dict(mode.counters.items())
    dropped: dict[str, dict[str, int]] = {}
    for role in names:
        head = f"dropped_{role}_"
        dropped[role] = {k[len(head):]: int(n) for k, n in counters.items()
                         if k.startswith(head) and n}
    ref = dropped["ref_velocity"]
    ref["outside_imu_record"] = int(mode.asm.outside)
    if mode.asm.late:
        ref["late"] = int(mode.asm.late)
    height = getattr(mode, "height", None)
    if height is not None:
        ref["no_height"] = int(mode.asm.no_height)
    received = {names[role]: mode.inputs.count(mode.names[role]) for role in names}
    out = section3d(names, received, dropped)
    if height is not None:
        out[mode.height.topic] = height_section_of_run(mode, counters)
    return out


def height_section_of_run(mode: Any, counters: dict[str, int]) -> dict:
    """The height topic's entry (``bagio.height_input.HeightInput.section``'s form) of what the
    filter counted."""
    from flight_fdi.bagio.height_input import HeightInput

    asm, head = mode.asm, "dropped_height_"
    dropped = {k[len(head):]: int(n) for k, n in counters.items() if k.startswith(head)}
    dropped["outside_imu_record"] = int(asm.height_outside)
    return HeightInput(mode.height, mode.p["ins3d_height_type"],
                       mode.inputs.count(mode.names["height"]), dropped, 0, int(asm.no_height),
                       float(asm.offset or 0.0), asm.h0_sigma,
                       int(asm.height_from_message)).section()


__all__ = ["ACK_WINDOW", "ack_window", "filter_parameters3d", "height_section_of_run",
           "input_section_of_run", "run_pipeline3d"]
